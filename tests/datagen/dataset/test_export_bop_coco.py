"""hupbench export-dataset: the BOP and COCO exports of the tiny dataset read back by independent readers (plain
json, trimesh, OpenCV's projectPoints, pycocotools), and the verb's answers to bad input."""

from __future__ import annotations

import json
import os

import cv2
import numpy as np
import pytest
import trimesh
from helpers.cli import assert_clean_error, run_cli
from helpers.datasets import annotations
from helpers.faults import run_in_namespace
from pycocotools import mask as mask_utils
from pycocotools.coco import COCO
from pycocotools.cocoeval import COCOeval
from scipy.spatial.distance import cdist

from hupbench.core import keypoints as kp
from hupbench.datagen.assets.probe import build_probe
from hupbench.core.errors import BadValueError
from hupbench.datagen.dataset import export_bop_coco
from hupbench.datagen.dataset.export_bop_coco import ExportOptions, run_export_dataset

# pycocotools' mask decoding under numpy 2 (its own code, harmless here)
pytestmark = pytest.mark.filterwarnings("ignore:__array__ implementation doesn't accept a copy keyword:DeprecationWarning")

SPLITS = ("train", "val", "test")
#: a model vertex is on the visible surface when the depth map at its pixel is this close to its depth, mm
SURFACE_DEPTH_MM = 2.0


#: what the caller says made the export (the CLI passes hupbench.provenance.run_info's)
PROVENANCE = {"git_commit": "0123abc", "packages": {"numpy": "2.0"}}


def _quiet(*_):
    pass


@pytest.fixture(scope="module")
def bop(tmp_path_factory, tiny_dataset):
    out = tmp_path_factory.mktemp("export") / "bop"
    return out, run_export_dataset(ExportOptions(tiny_dataset, out, "bop"), PROVENANCE, log=_quiet)


@pytest.fixture(scope="module")
def coco(tmp_path_factory, tiny_dataset):
    out = tmp_path_factory.mktemp("export") / "coco"
    return out, run_export_dataset(ExportOptions(tiny_dataset, out, "coco", images="copy"), log=_quiet)


@pytest.fixture(scope="module")
def truth(tiny_dataset):
    return annotations(tiny_dataset, SPLITS), json.loads((tiny_dataset / "manifest.json").read_text())


def _read(path, flags=cv2.IMREAD_UNCHANGED):
    image = cv2.imread(str(path), flags)
    assert image is not None, path
    return image


def _frames(scene):
    """(image id, camera, ground truth, gt info) of a BOP scene folder, read with plain json."""
    cams, gts, infos = (json.loads((scene / f"{name}.json").read_text())
                        for name in ("scene_camera", "scene_gt", "scene_gt_info"))
    assert set(cams) == set(gts) == set(infos)
    for im in sorted(cams, key=int):
        assert len(gts[im]) == 1 and len(infos[im]) == 1
        yield int(im), cams[im], gts[im][0], infos[im][0]


def _pose(cam, gt):
    K = np.array(cam["cam_K"], np.float64).reshape(3, 3)
    R = np.array(gt["cam_R_m2c"], np.float64).reshape(3, 3)
    t_mm = np.array(gt["cam_t_m2c"], np.float64)
    return K, R, t_mm


def _reprojection(vertices_mm, K, R, t_mm, mask, mask_visib, depth_mm):
    """(share of the in-image projected vertices inside the 1-px grown whole mask, share of the visible-surface
    vertices (depth map within SURFACE_DEPTH_MM at their pixel) inside the visible mask, number of those), by
    cv2.projectPoints."""
    uv = cv2.projectPoints(vertices_mm, cv2.Rodrigues(R)[0], t_mm, K, None)[0][:, 0]
    z_mm = (vertices_mm @ R.T + t_mm)[:, 2]
    h, w = mask.shape
    px = np.round(uv).astype(np.int64)
    inside = (px[:, 0] >= 0) & (px[:, 0] < w) & (px[:, 1] >= 0) & (px[:, 1] < h)
    px, z_mm = px[inside], z_mm[inside]
    grown = cv2.dilate(mask.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    surface = np.abs(depth_mm[px[:, 1], px[:, 0]] - z_mm) < SURFACE_DEPTH_MM
    return grown[px[:, 1], px[:, 0]].mean(), mask_visib[px[surface, 1], px[surface, 0]].mean(), int(surface.sum())


def test_bop_layout_counts_and_links(bop, truth, tiny_dataset):
    out, result = bop
    ann, manifest = truth
    assert result["frames"] == manifest["counts"] and result["scenes"] == 3
    assert result["linked"] == 2 * sum(manifest["counts"].values()) and result["copied"] == 0
    for split in SPLITS:
        scenes = sorted(p.name for p in (out / split).iterdir())
        assert scenes == [f"{g:06d}" for g in np.unique(ann[split]["grasp_id"])]
        for scene in scenes:
            ids = [im for im, *_ in _frames(out / split / scene)]
            assert ids == ann[split]["frame_id"][ann[split]["grasp_id"] == int(scene)].tolist()
            for im in ids:
                for sub, name in (("rgb", f"{im:06d}.jpg"), ("depth", f"{im:06d}.png"),
                                  ("mask", f"{im:06d}_000000.png"), ("mask_visib", f"{im:06d}_000000.png")):
                    assert (out / split / scene / sub / name).is_file(), (split, scene, sub, name)
            # the default hard links share the dataset's file
            assert os.stat(out / split / scene / "rgb" / f"{ids[0]:06d}.jpg").st_ino == \
                os.stat(tiny_dataset / split / "rgb" / f"{ids[0]:06d}.jpg").st_ino
    record = json.loads((out / "hupbench_export.json").read_text())
    assert record["config"]["format"] == "bop" and record["config"]["frames"] == {s: 20 for s in SPLITS}
    assert {k: record[k] for k in PROVENANCE} == PROVENANCE


def test_bop_model_is_the_probe_in_mm_with_its_box_and_diameter(bop):
    out, _ = bop
    mesh = trimesh.load(out / "models" / "obj_000001.ply", process=False)
    probe_m = build_probe().mesh
    np.testing.assert_allclose(mesh.vertices, probe_m.vertices * 1000.0, atol=1e-5)
    np.testing.assert_array_equal(mesh.faces, probe_m.faces)
    info = json.loads((out / "models" / "models_info.json").read_text())["1"]
    lo, hi = mesh.bounds
    np.testing.assert_allclose([info["min_x"], info["min_y"], info["min_z"]], lo, atol=1e-5)
    np.testing.assert_allclose([info["size_x"], info["size_y"], info["size_z"]], hi - lo, atol=1e-5)
    diameter = max(cdist(chunk, mesh.vertices).max() for chunk in np.array_split(mesh.vertices, 20))
    assert info["diameter"] == pytest.approx(diameter, abs=1e-4)
    # the half turn about the long axis: a proper rotation mapping the model's box onto itself
    (sym,) = info["symmetries_discrete"]
    T = np.array(sym).reshape(4, 4)
    np.testing.assert_allclose(T, np.diag([-1.0, -1.0, 1.0, 1.0]))
    corners = trimesh.bounds.corners(mesh.bounds)
    assert cdist(corners @ T[:3, :3].T + T[:3, 3], corners).min(axis=1).max() < 1e-4


def test_bop_without_symmetry(tmp_path, tiny_dataset):
    out = tmp_path / "bop"
    run_export_dataset(ExportOptions(tiny_dataset, out, "bop", symmetry=False), log=_quiet)
    info = json.loads((out / "models" / "models_info.json").read_text())["1"]
    assert "symmetries_discrete" not in info and info["size_z"] == pytest.approx(165.0)


def test_bop_poses_put_the_box_on_the_corner_keypoints(bop, truth):
    out, _ = bop
    ann, _ = truth
    info = json.loads((out / "models" / "models_info.json").read_text())["1"]
    lo = np.array([info["min_x"], info["min_y"], info["min_z"]])
    hi = lo + np.array([info["size_x"], info["size_y"], info["size_z"]])
    # the corner order of hupbench.core.keypoints: itertools.product((min, max), repeat=3) over x, y, z
    corners_mm = np.array([[(lo, hi)[b][a] for a, b in enumerate(bits)] for bits in kp.CORNER_BITS])
    for split in SPLITS:
        row = {f: i for i, f in enumerate(ann[split]["frame_id"].tolist())}
        for scene in (out / split).iterdir():
            for im, cam, gt, _ in _frames(scene):
                K, R, t_mm = _pose(cam, gt)
                np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-9)
                assert np.linalg.det(R) == pytest.approx(1.0)
                np.testing.assert_allclose(K, ann[split]["K"][row[im]])
                np.testing.assert_allclose(corners_mm @ R.T + t_mm,
                                           ann[split]["keypoints_3d_cam"][row[im], kp.CORNER_SLICE] * 1000.0,
                                           atol=0.01)


def test_bop_vertices_reproject_onto_the_masks(bop, truth, tiny_dataset):
    out, _ = bop
    vertices_mm = np.asarray(trimesh.load(out / "models" / "obj_000001.ply", process=False).vertices)
    whole, visible, shifted = [], [], []
    for split in SPLITS:
        for scene in (out / split).iterdir():
            for im, cam, gt, info in _frames(scene):
                K, R, t_mm = _pose(cam, gt)
                name = f"{im:06d}_000000.png"
                mask, mask_visib = (_read(scene / sub / name) > 0 for sub in ("mask", "mask_visib"))
                depth_mm = _read(scene / "depth" / f"{im:06d}.png").astype(np.float64) * cam["depth_scale"]
                whole_share, visible_share, n = _reprojection(vertices_mm, K, R, t_mm, mask, mask_visib, depth_mm)
                assert n >= 50, "too few visible vertices to judge the pose"
                whole.append(whole_share)
                visible.append(visible_share)
                # the same check, the pose moved 3 px sideways: it must notice
                t_off = t_mm + np.array([3.0 * t_mm[2] / K[0, 0], 0.0, 0.0])
                shifted.append(_reprojection(vertices_mm, K, R, t_off, mask, mask_visib, depth_mm)[:2])
                # the visible mask is the dataset's probe label, inside the whole silhouette
                seg = _read(tiny_dataset / split / "seg" / f"{im:06d}.png")
                np.testing.assert_array_equal(mask_visib, seg == 3)
                assert not (mask_visib & ~mask).any()
                ys, xs = np.nonzero(mask_visib)
                assert info["px_count_visib"] == len(xs) > 0
                assert info["bbox_visib"] == [xs.min(), ys.min(), xs.max() - xs.min(), ys.max() - ys.min()]
                assert info["px_count_all"] >= mask.sum() and info["px_count_valid"] == mask.sum()
                assert info["visib_fract"] == pytest.approx(info["px_count_visib"] / info["px_count_all"])
                ys, xs = np.nonzero(mask)
                if xs.min() > 0 and ys.min() > 0 and xs.max() < mask.shape[1] - 1 and ys.max() < mask.shape[0] - 1:
                    assert info["bbox_obj"] == [xs.min(), ys.min(), xs.max() - xs.min(), ys.max() - ys.min()]
                    assert info["px_count_all"] == mask.sum()
    assert min(whole) == 1.0, "a projected vertex fell off the whole silhouette"
    assert min(visible) >= 0.9 and np.mean(visible) >= 0.95, (min(visible), np.mean(visible))
    shifted = np.array(shifted)
    assert shifted[:, 0].min() < 0.95 and shifted[:, 1].mean() < 0.95, "the check cannot see a 3 px error"


def test_bop_depth_times_scale_is_the_dataset_depth_in_mm(bop, truth, tiny_dataset):
    out, _ = bop
    _, manifest = truth
    camera = json.loads((out / "camera.json").read_text())
    K = np.array(manifest["K"])
    assert [camera[k] for k in ("fx", "fy", "cx", "cy")] == [K[0, 0], K[1, 1], K[0, 2], K[1, 2]]
    assert [camera["width"], camera["height"]] == manifest["image_size"]
    for split in SPLITS:
        for scene in (out / split).iterdir():
            for im, cam, _, _ in _frames(scene):
                assert cam["depth_scale"] == camera["depth_scale"] == pytest.approx(manifest["depth_scale_m"] * 1000)
                exported = _read(scene / "depth" / f"{im:06d}.png")
                assert exported.dtype == np.uint16
                dataset_m = _read(tiny_dataset / split / "depth" / f"{im:06d}.png") * manifest["depth_scale_m"]
                np.testing.assert_allclose(exported * cam["depth_scale"], dataset_m * 1000.0, rtol=1e-12)


def test_coco_keypoints_read_back_with_pycocotools(coco, truth, tiny_dataset):
    out, result = coco
    ann, manifest = truth
    assert result["copied"] == sum(manifest["counts"].values()) and result["linked"] == 0
    labels = {1: 1, 2: 3}  # category -> seg label
    slices = {1: kp.HAND_SLICE, 2: kp.CORNER_SLICE}
    w, h = manifest["image_size"]
    seen = {0: 0, 1: 0, 2: 0}
    for split in SPLITS:
        gt = COCO(str(out / "annotations" / f"keypoints_{split}.json"))
        cats = {c["id"]: c for c in gt.loadCats(gt.getCatIds())}
        assert [cats[1]["name"], cats[2]["name"]] == ["hand", "probe"]
        assert cats[1]["keypoints"] == list(kp.HAND_NAMES) and cats[2]["keypoints"] == list(kp.CORNER_NAMES)
        assert [tuple(e) for e in cats[1]["skeleton"]] == [(a + 1, b + 1) for a, b in kp.HAND_EDGES]
        assert len(cats[2]["skeleton"]) == 12
        assert sorted(gt.getImgIds()) == ann[split]["frame_id"].tolist()
        for row, frame in enumerate(ann[split]["frame_id"].tolist()):
            (image,) = gt.loadImgs([frame])
            copied = out / "images" / image["file_name"]
            assert copied.read_bytes() == (tiny_dataset / split / "rgb" / f"{frame:06d}.jpg").read_bytes()
            assert os.stat(copied).st_ino != os.stat(tiny_dataset / split / "rgb" / f"{frame:06d}.jpg").st_ino
            np.testing.assert_allclose(image["cam_K"], ann[split]["K"][row])
            seg = _read(tiny_dataset / split / "seg" / f"{frame:06d}.png")
            anns = gt.loadAnns(gt.getAnnIds(imgIds=[frame]))
            assert sorted(a["category_id"] for a in anns) == [1, 2]
            for a in anns:
                sl = slices[a["category_id"]]
                points = np.array(a["keypoints"], np.float64).reshape(-1, 3)
                v = points[:, 2].astype(int)
                truth2d = ann[split]["keypoints_2d"][row, sl]
                inside = ((np.round(truth2d) >= 0) & (np.round(truth2d) < [w, h])).all(axis=1)
                np.testing.assert_array_equal(v == 2, ann[split]["visible"][row, sl])
                np.testing.assert_array_equal(v > 0, inside)
                np.testing.assert_allclose(points[v > 0, :2], truth2d[v > 0], atol=1e-4)
                assert (points[v == 0, :2] == 0).all() and a["num_keypoints"] == int((v > 0).sum())
                for value in (0, 1, 2):
                    seen[value] += int((v == value).sum())
                np.testing.assert_allclose(a["keypoints_3d"], ann[split]["keypoints_3d_cam"][row, sl] * 1000.0,
                                           rtol=1e-6)
                mask = gt.annToMask(a).astype(bool)
                np.testing.assert_array_equal(mask, seg == labels[a["category_id"]])
                rle = gt.annToRLE(a)
                assert a["area"] == int(mask_utils.area(rle)) == mask.sum()
                np.testing.assert_allclose(a["bbox"], mask_utils.toBbox(rle))
    assert seen[1] > 0 and seen[2] > 0, f"the tiny dataset should have hidden and visible keypoints: {seen}"


@pytest.mark.parametrize("category, sigmas", [(1, 21), (2, 8)])
def test_coco_eval_scores_the_labels_themselves_perfectly(coco, category, sigmas):
    """COCOeval (OKS, keypoints) accepts the export: its own labels as detections score AP 1, moved ones less."""
    out, _ = coco
    gt = COCO(str(out / "annotations" / "keypoints_test.json"))
    anns = gt.loadAnns(gt.getAnnIds(catIds=[category]))

    def ap(offset_px):
        dets = []
        for a in anns:
            points = np.array(a["keypoints"], np.float64).reshape(-1, 3)
            points[:, :2] += offset_px
            dets.append({"image_id": a["image_id"], "category_id": category, "keypoints": points.ravel().tolist(),
                         "score": 1.0})
        evaluator = COCOeval(gt, gt.loadRes(dets), "keypoints")
        evaluator.params.catIds = [category]
        evaluator.params.kpt_oks_sigmas = np.full(sigmas, 0.05)
        evaluator.evaluate()
        evaluator.accumulate()
        evaluator.summarize()
        return evaluator.stats[0]

    assert ap(0.0) == pytest.approx(1.0)
    assert ap(4.0) < 0.9


def test_export_refuses_a_mesh_that_is_not_the_dataset_probe(tmp_path, tiny_dataset, monkeypatch):
    def wrong_probe(root, manifest):
        mesh = build_probe().mesh.copy()
        mesh.apply_scale(1.1)
        return mesh

    monkeypatch.setattr(export_bop_coco, "dataset_probe_mesh", wrong_probe)
    with pytest.raises(BadValueError, match=r"annotated probe corners: the mesh is not the probe"):
        run_export_dataset(ExportOptions(tiny_dataset, tmp_path / "bop", "bop"), log=_quiet)
    assert list(tmp_path.iterdir()) == [], "a failed export left files"


def test_force_replaces_only_an_earlier_export(tmp_path, capsys, tiny_dataset):
    out = tmp_path / "coco"
    assert run_cli(capsys, "export-dataset", tiny_dataset, "--format", "coco", out).rc == 0
    (out / "stray.txt").write_text("left from before")
    line = assert_clean_error(run_cli(capsys, "export-dataset", tiny_dataset, "--format", "coco", out),
                              str(out), "is not empty (4 entries)", "--force")
    assert line.startswith("hupbench export-dataset: error:")
    answer = run_cli(capsys, "export-dataset", tiny_dataset, "--format", "coco", out, "--force")
    assert answer.rc == 0 and "60 image files linked" in answer.out, answer
    assert sorted(p.name for p in out.iterdir()) == ["annotations", "hupbench_export.json", "images"]
    record = json.loads((out / "hupbench_export.json").read_text())
    assert record["config"]["format"] == "coco" and record["git_commit"] and record["packages"]["numpy"]
    other = tmp_path / "mine"
    other.mkdir()
    (other / "thesis.tex").write_text("x")
    assert_clean_error(run_cli(capsys, "export-dataset", tiny_dataset, "--format", "bop", other, "--force"),
                       "not an earlier export", "hupbench_export.json")
    assert (other / "thesis.tex").read_text() == "x"


def test_bad_input_answers_one_line(tmp_path, capsys, tiny_dataset):
    out = tmp_path / "out"
    assert_clean_error(run_cli(capsys, "export-dataset", tmp_path / "nowhere", "--format", "bop", out),
                       "nowhere does not exist")
    (tmp_path / "empty").mkdir()
    assert_clean_error(run_cli(capsys, "export-dataset", tmp_path / "empty", "--format", "coco", out),
                       "has no manifest.json", "not a finished hupbench dataset")
    assert_clean_error(run_cli(capsys, "export-dataset", tiny_dataset, "--format", "yolo", out),
                       "invalid choice: 'yolo'", "bop", "coco")
    (tmp_path / "file").write_text("x")
    assert_clean_error(run_cli(capsys, "export-dataset", tiny_dataset, "--format", "coco", tmp_path / "file"),
                       "is not a folder")
    assert not out.exists()
    with pytest.raises(BadValueError, match="unknown format 'yolo': choose one of bop, coco"):
        ExportOptions(tiny_dataset, out, "yolo")


def test_unwritable_out_answers_one_line(tmp_path, tiny_dataset):
    mount = tmp_path / "ro"
    mount.mkdir()
    answer = run_in_namespace(["export-dataset", tiny_dataset, "--format", "coco", mount / "coco"], read_only=(mount,))
    assert_clean_error(answer, f"cannot write OUT {mount / 'coco'}", "read-only file system")
