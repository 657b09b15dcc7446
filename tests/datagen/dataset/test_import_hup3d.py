"""hupbench import-hup3d on a fixture in the published HUP-3D layout (tests/helpers/hup3d.py): known camera-frame
geometry in, the same geometry out of the hupbench dataset, and verify passing with its skips named."""

from __future__ import annotations

import csv
import json
import pickle

import cv2
import numpy as np
import pytest
import trimesh
from helpers.cli import assert_clean_error, run_cli
from helpers.hup3d import FRAMES, SIZE, write_published
from scipy.spatial.transform import Rotation

from hupbench.core import keypoints as kp
from hupbench.datagen.dataset import import_hup3d as H
from hupbench.core.contract import (
    DEPTH_SCALE_M,
    frame_path,
    read_annotations,
    read_manifest,
)
from hupbench.datagen.dataset.verify import IMPORTED_SKIPS, verify


@pytest.fixture(scope="module")
def published(tmp_path_factory):
    """A published-layout folder (split folders train/, test/), its probe PLY and the truth of every frame."""
    root = tmp_path_factory.mktemp("hup3d")
    bounds, truths = write_published(root)
    return root, bounds, truths


@pytest.fixture(scope="module")
def imported(published, tmp_path_factory):
    """The import of ``published``, which builds no Probe: nothing of it needs the probe's signed distance (seconds
    to minutes for a mesh of thousands of triangles)."""
    root, _, _ = published
    out = tmp_path_factory.mktemp("imported") / "ds"

    def no_probe(*args, **kwargs):
        raise AssertionError("import-hup3d built a Probe (its signed distance) that nothing of the import reads")

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr("hupbench.datagen.assets.probe.probe_from_geometry", no_probe)
        result = H.run_import_hup3d(root / "HUP-3D", root / "probe.ply", out, log=lambda line: None)
    return out, result


def test_published_joint_order_is_hupbench_order():
    # the renderer reorders SMPL-H's MANO-ordered joints into OpenPose order: hupbench's
    assert H.PUBLISHED_HAND_NAMES == kp.HAND_NAMES
    assert H.PUBLISHED_TO_HUPBENCH == tuple(range(21))


def test_view_rotations_are_the_published_sphere():
    rotations = H.view_rotations()
    assert rotations.shape == (92, 3, 3)
    # camera_sphere.py's north pole is Euler (90, 360, 0) degrees; the two views grasp_renderer.py drops are
    # (10, 270) and (350, 270): hupbench's excluded ids 34 and 50
    for view, euler in ((0, (90, 360)), (34, (10, 270)), (50, (350, 270)), (91, (270, 360))):
        rotvec = Rotation.from_euler("XYZ", np.radians([*euler, 0])).as_rotvec()
        assert H.view_of(rotvec, rotations) == view


def test_import_round_trip(published, imported):
    _, bounds, truths = published
    out, result = imported
    assert result["counts"] == {"train": 2, "test": 3} and result["depth_from"] == {"exr": 0, "png": 5}
    manifest = read_manifest(out)
    assert manifest["imported"]["format"] == "HUP-3D" and manifest["imported"]["depth"]["approximate"] is True
    assert manifest["imported"]["split_from"] == "the published split folders"
    K = np.asarray(manifest["K"])
    np.testing.assert_allclose(K, [[120, 0, SIZE / 2 - 0.5], [0, 120, SIZE / 2 - 0.5], [0, 0, 1]])
    corners_probe = np.array([[bounds[b][axis] for axis, b in enumerate(bits)] for bits in kp.CORNER_BITS])
    rows = {s: read_annotations(out, s) for s in ("train", "test")}
    ann = {k: np.concatenate([rows["train"][k], rows["test"][k]]) for k in rows["train"]}
    np.testing.assert_array_equal(ann["frame_id"], np.arange(5))
    for i, truth in enumerate(truths):
        corners = corners_probe @ truth["T_cam_probe"][:3, :3].T + truth["T_cam_probe"][:3, 3]
        np.testing.assert_allclose(ann["keypoints_3d_cam"][i, :21], truth["hand_cv"], atol=1e-6)
        np.testing.assert_allclose(ann["keypoints_3d_cam"][i, 21:], corners, atol=1e-6)
        np.testing.assert_allclose(ann["T_cam_world"][i], truth["T_cam_probe"], atol=1e-6)
        # the published coords_2d, moved to integer pixel centres
        uv = truth["hand_cv"][:, :2] / truth["hand_cv"][:, 2:] * 120 + SIZE / 2 - 0.5
        np.testing.assert_allclose(ann["keypoints_2d"][i, :21], uv, atol=1e-3)
        assert ann["view_id"][i] == truth["view"] and ann["grasp_id"][i] == truth["grasp"]
        assert ann["z_ego"][i] == truth["z"] and ann["glove_id"][i] == -1
        split = FRAMES[i][0]
        depth = cv2.imread(str(frame_path(out, split, "depth", i)), cv2.IMREAD_UNCHANGED) * DEPTH_SCALE_M
        fg = truth["scene"] > 0
        bound = (truth["far"] - truth["near"]) / 508 + DEPTH_SCALE_M / 2
        err = np.abs(depth[fg] - truth["planar"][fg])
        assert err.max() <= bound + 1e-9 and err.max() > DEPTH_SCALE_M, (err.max(), bound)
        assert (depth[~fg] == 0).all()
        seg = cv2.imread(str(frame_path(out, split, "seg", i)), cv2.IMREAD_UNCHANGED)
        np.testing.assert_array_equal(seg, np.select([truth["scene"] == 100, np.isin(truth["scene"], (16, 17)),
                                                      truth["scene"] == 15], [3, 1, 2], 0))
    np.testing.assert_allclose(ann["theta"][[0, 1]], np.radians([20, 80]))
    np.testing.assert_allclose(ann["phi"][[0, 1]], np.radians([0, 90]), atol=1e-12)
    assert ann["view_id"][4] == -1 and manifest["imported"]["views_unknown"] == 1
    with open(out / "imported_frames.csv") as f:
        listing = list(csv.reader(f))
    assert listing[1] == ["0", "train", "train/meta/img_meta_1.pkl", "png8"]
    assert listing[5] == ["4", "test", "test/meta/img_meta_3.pkl", "png8"]


def test_verify_passes_and_names_its_skips(imported):
    out, _ = imported
    lines = []
    result = verify(out, workers=1, log=lines.append, progress=False)
    assert result["ok"], result["problems"]
    assert result["frames"] == 5
    assert all(f"not checked: {note}" in lines for note in IMPORTED_SKIPS), lines
    assert any(line.startswith("imported (HUP-3D): visibility checked with the depth's precision") for line in lines)


def test_verify_reports_a_swapped_depth(imported, tmp_path):
    """The checks that still run find what they exist for: another frame's depth file."""
    out, _ = imported
    import shutil

    copy = tmp_path / "ds"
    shutil.copytree(out, copy)
    shutil.copy(frame_path(copy, "test", "depth", 2), frame_path(copy, "test", "depth", 4))
    result = verify(copy, workers=1, log=lambda line: None, progress=False)
    assert not result["ok"] and result["by_kind"]["reprojection"] == 0
    assert {p["frame_id"] for p in result["problems"]} == {4}


def test_flat_folder_takes_the_split_option(published, tmp_path):
    root, _, _ = published
    result = H.run_import_hup3d(root / "HUP-3D" / "test", root / "probe.ply", tmp_path / "ds", split="val",
                                depth="png", log=lambda line: None)
    assert result["counts"] == {"val": 3}
    assert json.loads((tmp_path / "ds" / "manifest.json").read_text())["imported"]["split_from"] == \
        "--split val (a folder without split folders)"


def test_radial_to_planar_on_the_optical_axis_and_off_it():
    K = np.array([[100.0, 0, 1.0], [0, 100.0, 1.0], [0, 0, 1]])
    radial = np.full((3, 3), 2.0)
    planar = H.planar_depth(radial, K)
    assert planar[1, 1] == 2.0
    np.testing.assert_allclose(planar[0, 0], 2.0 / np.sqrt(1 + 2 * 0.01 ** 2))


def test_png_levels_decode_to_the_swapped_range():
    levels = np.array([[0, 1, 128, 255]], np.uint8)
    np.testing.assert_allclose(H.radial_from_png(levels, far_m=0.9, near_m=0.4), [[0, 0.9, 0.9 - 127 * 0.5 / 254, 0.4]])


# --- bad input: one line each -----------------------------------------------------------------


def _cli(capsys, *args):
    return run_cli(capsys, "import-hup3d", *map(str, args))


def test_missing_dir(capsys, published, tmp_path):
    root, _, _ = published
    assert_clean_error(_cli(capsys, tmp_path / "nope", "--probe-mesh", root / "probe.ply", tmp_path / "o"),
                       "nope", "does not exist")


def test_no_meta_files(capsys, published, tmp_path):
    root, _, _ = published
    (tmp_path / "src" / "meta").mkdir(parents=True)
    assert_clean_error(_cli(capsys, tmp_path / "src", "--probe-mesh", root / "probe.ply", tmp_path / "o"),
                       "no img_meta_N.pkl files")


def test_meta_without_coords_3d(capsys, published, tmp_path):
    root, _, _ = published
    import shutil

    shutil.copytree(root / "HUP-3D" / "test", tmp_path / "src")
    path = tmp_path / "src" / "meta" / "img_meta_2.pkl"
    meta = pickle.loads(path.read_bytes())
    del meta["coords_3d"]
    path.write_bytes(pickle.dumps(meta))
    assert_clean_error(_cli(capsys, tmp_path / "src", "--probe-mesh", root / "probe.ply", tmp_path / "o"),
                       "img_meta_2.pkl lacks coords_3d")


def test_missing_probe_mesh_option(capsys, published, tmp_path):
    root, _, _ = published
    assert_clean_error(_cli(capsys, root / "HUP-3D", tmp_path / "o"), "--probe-mesh")


def test_ply_that_is_not_a_mesh(capsys, published, tmp_path):
    root, _, _ = published
    trimesh.PointCloud(np.random.default_rng(0).normal(size=(20, 3))).export(tmp_path / "points.ply")
    assert_clean_error(_cli(capsys, root / "HUP-3D", "--probe-mesh", tmp_path / "points.ply", tmp_path / "o"),
                       "points.ply", "not a triangle mesh")


def test_out_not_empty(capsys, published, tmp_path):
    root, _, _ = published
    (tmp_path / "o").mkdir()
    (tmp_path / "o" / "keep.txt").write_text("mine")
    assert_clean_error(_cli(capsys, root / "HUP-3D", "--probe-mesh", root / "probe.ply", tmp_path / "o"),
                       "is not empty")
    assert sorted(p.name for p in (tmp_path / "o").iterdir()) == ["keep.txt"]


# --- the imported dataset describes its probe as a generated one does ---------------------------


def test_imported_dataset_records_its_probe_and_grasps(published, imported):
    """The manifest's probe record and grasps.npz are those of a mesh probe made by ``hupbench generate``:
    probe_of_dataset rebuilds the PLY's probe, whose box is the corners the keypoints hold."""
    from hupbench.core.io import file_sha256
    from hupbench.datagen.dataset.grasps_file import probe_of_dataset, read_grasps

    root, bounds, truths = published
    out, _ = imported
    manifest = read_manifest(out)
    record = manifest["probe"]
    assert record["kind"] == "mesh" and record["path"] == str((root / "probe.ply").resolve())
    assert record["sha256"] == file_sha256(root / "probe.ply") and record["unit"] == "m" and record["align"] is False
    assert manifest["grasps_sha256"] == file_sha256(out / "grasps.npz")
    probe = probe_of_dataset(out)
    assert probe.record == record
    np.testing.assert_allclose(probe.corners_probe[[0, -1]], bounds)
    grasps = read_grasps(out / "grasps.npz")
    np.testing.assert_array_equal(grasps["grasp_id"], [0, 1])
    np.testing.assert_allclose(grasps["hand_pose"], [np.full(48, 0.1 * (g + 1)) for g in (0, 1)])


def test_bop_export_and_probe_pose_metrics_work_on_imported_data(imported, tmp_path):
    """The imported dataset's probe is the PLY's (not the procedural one): the BOP export takes it, its model is
    the PLY's box, and eval's probe-pose metrics score the annotated corners against it."""
    from hupbench.datagen.dataset.export_bop_coco import ExportOptions, run_export_dataset
    from hupbench.evaluation.probe_pose import dataset_probe, probe_pose_scores

    out, _ = imported
    result = run_export_dataset(ExportOptions(out, tmp_path / "bop", "bop"), log=lambda *_: None)
    assert result["frames"] == {"train": 2, "test": 3}
    info = json.loads((tmp_path / "bop" / "models" / "models_info.json").read_text())["1"]
    assert info["size_z"] == pytest.approx(160.0)  # the PLY's box, in mm
    ann = read_annotations(out, "test")
    corners = ann["keypoints_3d_cam"][:, kp.CORNER_SLICE].astype(np.float64)
    scores, line = probe_pose_scores(corners, corners, ann["K"], SIZE, dataset_probe(out))
    assert scores is not None, line
    assert scores["add_mm"] == pytest.approx(0.0, abs=1e-3) and scores["model_points"] == 8


def test_verify_checks_the_imported_grasps_file(imported, tmp_path):
    import shutil

    out, _ = imported
    copy = tmp_path / "ds"
    shutil.copytree(out, copy)
    with np.load(copy / "grasps.npz") as data:
        arrays = {k: data[k] for k in data.files}
    arrays["hand_pose"] = arrays["hand_pose"][::-1].copy()
    np.savez(copy / "grasps.npz", **arrays)
    result = verify(copy, workers=1, log=lambda line: None, progress=False)
    details = [p["detail"] for p in result["problems"] if p["kind"] == "grasps_file"]
    assert any("not the manifest's grasps_sha256" in d for d in details), details
    assert any("not the grasps the frames were rendered with" in d for d in details), details


def test_the_probe_of_a_dataset_without_its_grasps_file_is_one_line(imported, tmp_path):
    """A mesh probe's dataset rebuilds its probe from grasps.npz: missing or damaged, the error names the file."""
    import shutil

    from hupbench.core.errors import MissingFileError
    from hupbench.datagen.dataset.grasps_file import probe_of_dataset

    out, _ = imported
    copy = tmp_path / "ds"
    shutil.copytree(out, copy)
    (copy / "grasps.npz").write_bytes(b"not an npz")
    with pytest.raises(ValueError, match=r"grasps file .*grasps.npz is not an .npz archive \(10 bytes"):
        probe_of_dataset(copy)
    (copy / "grasps.npz").unlink()
    with pytest.raises(MissingFileError, match=r"grasps file .*grasps.npz not found"):
        probe_of_dataset(copy)
