"""The two tracks (what the evaluation splits hold out), the split floors in the manifest, and verify's
check that the images sit on the labels."""

import json

import numpy as np
import pytest

import hupbench.datagen.render.renderer as renderer_module
from hupbench.datagen.dataset.spec import DatasetSpec, Layout, chunk_plan, split_of_grasps, split_of_views
from hupbench.datagen.dataset.sphere import viewpoints
from hupbench.datagen.dataset.verify import verify
from hupbench.datagen.dataset.writer import GenerateRun, generate

from helpers.datasets import TINY_SPEC as TINY, annotations, write_grasps  # noqa: E402  (tests/ is on sys.path)

VIEWS = TINY | dict(splits=None, track="unseen_views", view_stride=3, n_backgrounds=1)


def _quiet(*_):
    pass


def test_unseen_views_split_every_ring_and_nothing_twice():
    spec = DatasetSpec(splits=None, track="unseen_views")
    ids, angles = viewpoints(spec.sphere)
    views = split_of_views(spec, len(ids))
    assert sorted(sum(views.values(), [])) == list(range(90))
    assert [len(views[s]) for s in ("train", "val", "test")] == [54, 18, 18]
    rings = np.round(np.degrees(angles[:, 0]))
    for split in ("val", "test"):
        held = set(rings[views[split]])
        for ring, size in zip(*np.unique(rings, return_counts=True)):
            if size >= spec.view_stride:
                assert ring in held, (split, ring)
    assert split_of_grasps(spec, 11) == {s: list(range(11)) for s in ("train", "val", "test")}
    # every frame in exactly one chunk, of the split holding its view
    layout = Layout(11, 2, 8, 2, 90)
    plan = chunk_plan(layout, split_of_grasps(spec, 11), views)
    frames = np.concatenate([f for _, f in plan])
    assert len(frames) == layout.size and len(np.unique(frames)) == layout.size
    for split, chunk in plan:
        assert {i % 90 for i in chunk} <= set(views[split])
    # the paper's track: one chunk per (grasp, z_ego, background) block, as before
    paper = DatasetSpec()
    plan = chunk_plan(layout, split_of_grasps(paper, 11), split_of_views(paper, 90))
    assert [f for _, f in plan] == [tuple(layout.chunk_frames(c)) for c in range(layout.n_chunks)]
    assert [s for s, _ in plan][:: 2 * 8] == ["train"] * 7 + ["val"] * 2 + ["test"] * 2


@pytest.mark.parametrize("kwargs, message", [
    (dict(track="unseen_views"), "set dataset.splits=null, as `hupbench generate +track=unseen_views` does"),
    (dict(splits=None), "dataset.splits must map"),
    (dict(track="unseen_objects"), "dataset.track must be one of unseen_grasps, unseen_views"),
    (dict(splits=None, track="unseen_views", view_stride=2), "dataset.view_stride"),
])
def test_track_config_refused(kwargs, message):
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace(")", r"\)").replace("+", r"\+")):
        DatasetSpec(**kwargs)


@pytest.fixture(scope="module")
def views_dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("views")
    grasps = write_grasps(root / "grasps.npz", n=2)
    generate(GenerateRun(DatasetSpec(**VIEWS), root / "ds", grasps, progress=False), {"test": "views"}, log=_quiet)
    return root / "ds"


def test_unseen_views_dataset_generates_verifies_and_records_its_split(views_dataset):
    manifest = json.loads((views_dataset / "manifest.json").read_text())
    assert manifest["protocol"]["track"] == "unseen_views" and manifest["protocol"]["view_stride"] == 3
    held = manifest["viewpoints"]["split_view_ids"]
    assert not set(held["test"]) & set(held["train"]) and not set(held["val"]) & set(held["train"])
    ann = annotations(views_dataset, ("train", "val", "test"))
    for split in ("train", "val", "test"):
        assert set(ann[split]["view_id"].tolist()) == set(held[split])
        assert set(ann[split]["grasp_id"].tolist()) == {0, 1}  # every grasp in every split
    assert manifest["counts"] == {"train": 2 * 4, "val": 2 * 3, "test": 2 * 3}  # 2 grasps; 10 views dealt 4 / 3 / 3
    result = verify(views_dataset, workers=1, log=_quiet)
    assert result["ok"], result["problems"][:3]
    floors = manifest["split_floors"]["splits"]
    assert floors["test"]["floor_kind"] == "nearest_train_view"
    assert floors["test"]["nearest_train_grasp_mm"]["all"] == 0.0
    for split in ("val", "test"):
        for part in ("hand", "probe", "all"):
            assert result["split_floors"][split]["floor_mm"][part] == pytest.approx(floors[split]["floor_mm"][part])
    assert abs(np.array(result["image_shift"]["median_px"])).max() < 0.1


def test_verify_finds_a_floor_the_manifest_misstates(views_dataset, tmp_path):
    import shutil

    copy = tmp_path / "ds"
    shutil.copytree(views_dataset, copy)
    manifest = json.loads((copy / "manifest.json").read_text())
    manifest["split_floors"]["splits"]["test"]["floor_mm"]["probe"] += 1.0
    (copy / "manifest.json").write_text(json.dumps(manifest))
    result = verify(copy, workers=1, log=_quiet)
    assert [p["kind"] for p in result["problems"]] == ["split_floors"]
    assert "the manifest's floor of test" in result["problems"][0]["detail"]


def test_verify_finds_images_half_a_pixel_off_their_labels(tmp_path, monkeypatch):
    grasps = write_grasps(tmp_path / "grasps.npz", n=2)
    spec = DatasetSpec(**(TINY | dict(width=128, height=128, fx=240.0, fy=240.0, cx=64.0, cy=64.0, n_backgrounds=1)))
    generate(GenerateRun(spec, tmp_path / "good", grasps, progress=False), {"test": "shift"}, log=_quiet)
    # the renderer as it was: GL's pixel centres taken for the contract's
    monkeypatch.setattr(renderer_module, "GL_PIXEL_CENTRE_OFFSET", 0.0)
    generate(GenerateRun(spec, tmp_path / "shifted", grasps, progress=False), {"test": "shift"}, log=_quiet)
    good, shifted = verify(tmp_path / "good", workers=1, log=_quiet), verify(tmp_path / "shifted", workers=1, log=_quiet)
    assert good["ok"] and abs(np.array(good["image_shift"]["median_px"])).max() < 0.1
    np.testing.assert_allclose(shifted["image_shift"]["median_px"], [-0.5, -0.5], atol=0.1)
    assert shifted["by_kind"]["image_shift"] >= 0.9 * shifted["image_shift"]["frames"]


def test_visibility_is_decided_on_the_keypoints_as_stored():
    from hupbench.core import keypoints as kp
    from hupbench.datagen.dataset.chunks import stored_visibility, visibility

    # a hand keypoint whose row is 139.49999391 in float64 and 139.5 in float32: verify, reading the
    # float32 annotations, rounds it to row 140, where the hand is; row 139 shows a finger 5 cm nearer
    keypoints_2d = np.full((kp.NUM_KEYPOINTS, 2), -10.0)  # every other keypoint outside the image
    keypoints_2d[13] = (106.049, 139.49999391243827)
    keypoints_cam = np.ones((kp.NUM_KEYPOINTS, 3))
    keypoints_cam[13, 2] = 0.8154
    depth, seg = np.zeros((256, 256)), np.zeros((256, 256), np.uint8)
    depth[139, 106], seg[139, 106] = 0.7679, 1
    depth[140, 106], seg[140, 106] = 0.8150, 1
    cam = {"keypoints_cam": keypoints_cam, "keypoints_2d": keypoints_2d}
    assert not visibility(keypoints_cam, keypoints_2d, depth, seg)[13]  # the float64 point: row 139, occluded
    assert stored_visibility(cam, depth, seg)[13]
    stored = keypoints_2d.astype(np.float32).astype(np.float64)
    np.testing.assert_array_equal(stored_visibility(cam, depth, seg), visibility(keypoints_cam, stored, depth, seg))
