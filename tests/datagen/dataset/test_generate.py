"""Dataset generation and verification on a tiny dataset (2 grasps x 2 backgrounds x 10 views, 64 x 64)."""

import json
import os
import shutil
import textwrap

import cv2
import numpy as np
import pytest

from hupbench.datagen.dataset.spec import DatasetSpec
from hupbench.datagen.dataset.writer import GenerateRun, generate
from hupbench.core.geometry import axis_angle_to_matrix, invert_transform, transform_points
from hupbench.core.io import save_npz
from hupbench.datagen.dataset.verify import verify

from helpers import REPO
from helpers.datasets import (TINY_SPEC as TINY, annotations, kill_after_first_chunk,  # noqa: E402  (tests/ on sys.path)
                              write_grasps)


def run(out, grasps, spec=(), **job):
    spec = DatasetSpec(**{**TINY, **dict(spec)})
    return generate(GenerateRun(spec, out, grasps, progress=False, **job), {"test": "tiny"}, log=lambda *_: None)


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    root = tmp_path_factory.mktemp("tiny")
    grasps = write_grasps(root / "grasps_in.npz")
    result = run(root / "ds", grasps)
    return root, grasps, result


def test_tiny_dataset_follows_the_contract_and_verifies(tiny):
    root, _, result = tiny
    ds = root / "ds"
    assert result["complete"] and result["counts"] == {"train": 20, "val": 0, "test": 20}
    manifest = json.loads((ds / "manifest.json").read_text())
    for key in ("schema_version", "generator", "config", "counts", "grasp_ids", "image_size", "K", "keypoint_names",
                "skeleton_edges", "seg_labels", "depth_scale_m", "viewpoints"):
        assert key in manifest, key
    assert manifest["seg_labels"] == {"background": 0, "hand": 1, "arm": 2, "probe": 3}
    ann = annotations(ds)["train"]
    assert ann["keypoints_3d_cam"].shape == (20, 29, 3) and ann["keypoints_3d_cam"].dtype == np.float32
    assert ann["keypoints_2d"].shape == (20, 29, 2) and ann["visible"].dtype == bool
    assert ann["K"].shape == (20, 3, 3) and ann["T_cam_world"].shape == (20, 4, 4)
    assert ann["hand_pose"].shape == (20, 48)
    depth = cv2.imread(str(ds / "train" / "depth" / f"{ann['frame_id'][0]:06d}.png"), cv2.IMREAD_UNCHANGED)
    assert depth.dtype == np.uint16
    assert (ds / "grasps.npz").is_file()
    assert not list(ds.glob("*/.chunks")) and not (ds / ".progress.json").exists()
    assert verify(ds, workers=1, log=lambda *_: None)["ok"]


def test_same_config_same_annotations_and_images(tiny):
    root, grasps, _ = tiny
    run(root / "again", grasps)
    a, b = annotations(root / "ds"), annotations(root / "again")
    for split in a:
        for key in a[split]:
            np.testing.assert_array_equal(a[split][key], b[split][key], err_msg=key)
    for path in (root / "ds").glob("*/*/*.*"):
        assert path.read_bytes() == (root / "again" / path.relative_to(root / "ds")).read_bytes(), path


def test_shards_render_the_same_frames_as_the_full_run(tiny):
    root, grasps, _ = tiny
    first = run(root / "sharded", grasps, shard="0/2")
    assert not first["complete"] and not (root / "sharded" / "manifest.json").exists()
    second = run(root / "sharded", grasps, shard="1/2")
    assert second["complete"]
    a, b = annotations(root / "ds"), annotations(root / "sharded")
    for split in a:
        for key in a[split]:
            np.testing.assert_array_equal(a[split][key], b[split][key], err_msg=key)
    for path in (root / "ds").glob("*/*/*.*"):
        assert path.read_bytes() == (root / "sharded" / path.relative_to(root / "ds")).read_bytes(), path


def test_sigkill_then_resume_loses_and_duplicates_nothing(tiny, tmp_path):
    root, grasps, _ = tiny
    out = tmp_path / "killed"
    code = textwrap.dedent(f"""
        import sys
        sys.path[:0] = [{os.path.dirname(__file__)!r}, {str(REPO / "tests")!r}]
        from test_generate import run
        run({str(out)!r}, {str(grasps)!r}, spec=dict(n_backgrounds=4, splits={{"train": 1, "val": 0, "test": 1}}))
    """)
    kill_after_first_chunk(code, out, 120)
    assert not (out / "manifest.json").exists()
    result = run(out, grasps, spec=dict(n_backgrounds=4))
    assert result["complete"] and 0 < result["frames_rendered"] < 80
    assert verify(out, workers=1, log=lambda *_: None)["ok"]
    reference = tmp_path / "reference"
    run(reference, grasps, spec=dict(n_backgrounds=4))
    a, b = annotations(out), annotations(reference)
    for split in a:
        for key in a[split]:
            np.testing.assert_array_equal(a[split][key], b[split][key], err_msg=key)
    assert not list(out.glob("*/*/.*.tmp*"))


def _broken_copy(tiny, tmp_path):
    root, _, _ = tiny
    broken = tmp_path / "broken"
    shutil.copytree(root / "ds", broken)
    return broken


def _kinds(path):
    return {p["kind"] for p in verify(path, workers=1, log=lambda *_: None)["problems"]}


def _edit_annotations(path, split, edit):
    ann_path = path / split / "annotations.npz"
    with np.load(ann_path) as data:
        ann = {k: data[k].copy() for k in data.files}
    edit(ann)
    save_npz(ann_path, ann)
    return int(ann["frame_id"][0])


def test_verify_missing_and_undecodable_files(tiny, tmp_path):
    broken = _broken_copy(tiny, tmp_path)
    ann = annotations(broken)["train"]
    (broken / "train" / "rgb" / f"{ann['frame_id'][0]:06d}.jpg").unlink()
    (broken / "train" / "depth" / f"{ann['frame_id'][1]:06d}.png").write_bytes(b"not a png")
    problems = verify(broken, workers=1, log=lambda *_: None)["problems"]
    named = {(p["kind"], p["frame_id"]) for p in problems}
    assert ("missing_file", ann["frame_id"][0]) in named and ("undecodable_file", ann["frame_id"][1]) in named


def test_verify_counts_and_frame_ids(tiny, tmp_path):
    broken = _broken_copy(tiny, tmp_path)
    manifest = json.loads((broken / "manifest.json").read_text())
    manifest["counts"]["train"] = 21
    (broken / "manifest.json").write_text(json.dumps(manifest))
    assert "count_mismatch" in _kinds(broken)
    broken2 = tmp_path / "broken2"
    shutil.copytree(tiny[0] / "ds", broken2)
    _edit_annotations(broken2, "test", lambda a: a["frame_id"].__setitem__(1, a["frame_id"][0]))
    assert "frame_ids" in _kinds(broken2)


def test_verify_reprojection_and_pose(tiny, tmp_path):
    broken = _broken_copy(tiny, tmp_path)
    fid = _edit_annotations(broken, "train", lambda a: a["keypoints_2d"].__setitem__((0, 5, 0), a["keypoints_2d"][0, 5, 0] + 0.05))
    fid2 = _edit_annotations(broken, "test", lambda a: a["hand_trans"].__setitem__((0, 2), a["hand_trans"][0, 2] + 0.01))
    problems = verify(broken, workers=1, log=lambda *_: None)["problems"]
    named = {(p["kind"], p["frame_id"]) for p in problems}
    assert ("reprojection", fid) in named and ("pose_mismatch", fid2) in named


def test_verify_mask_and_depth_consistency(tiny, tmp_path):
    broken = _broken_copy(tiny, tmp_path)
    ann = annotations(broken)["train"]
    k = int(np.flatnonzero(ann["visible"][:, :21].sum(axis=1) > 0)[0])
    fid = int(ann["frame_id"][k])
    seg_path = broken / "train" / "seg" / f"{fid:06d}.png"
    cv2.imwrite(str(seg_path), np.zeros((64, 64), np.uint8))  # the mask lost the hand
    # a probe frame whose depth was scaled: the probe pixels no longer lie on the probe
    j = next(i for i in range(len(ann["frame_id"])) if i != k)
    depth_path = broken / "train" / "depth" / f"{int(ann['frame_id'][j]):06d}.png"
    depth = cv2.imread(str(depth_path), cv2.IMREAD_UNCHANGED)
    cv2.imwrite(str(depth_path), (depth.astype(np.float64) * 1.05).astype(np.uint16))
    problems = verify(broken, workers=1, log=lambda *_: None)["problems"]
    named = {(p["kind"], p["frame_id"]) for p in problems}
    assert ("visible_not_on_hand", fid) in named
    assert ("probe_depth", int(ann["frame_id"][j])) in named


def _arm_frames(hand_pose):
    """(N, 3, 3) columns hand -> elbow, dorsal, thumb side of each row's grasp, world frame."""
    R = axis_angle_to_matrix(hand_pose[:, :3])
    elbow, dorsal = -R[:, :, 0], R[:, :, 1]
    return np.stack([elbow, dorsal, np.cross(elbow, dorsal)], axis=2)


def test_paper_protocol_puts_the_middle_mcp_at_the_principal_point(tiny):
    """The default aim (the published renderer's): keypoint 9 at (0, 0, z_ego) in every frame."""
    root, _, _ = tiny
    ds = root / "ds"
    manifest = json.loads((ds / "manifest.json").read_text())
    protocol = manifest["protocol"]
    assert protocol["sphere_axis"] == "body" and protocol["look_at"] == "middle_mcp"
    assert protocol["look_at_index"] == 9 and protocol["excluded_view_ids"] == [0, 11]
    assert protocol["name"] == "custom"  # the tiny sphere is not the paper's
    assert manifest["viewpoints"]["sphere"]["axis"] == "body"
    directions = np.array(manifest["viewpoints"]["direction_arm"])
    view_index = {v: i for i, v in enumerate(manifest["viewpoints"]["ids"])}
    for split, ann in annotations(ds).items():
        n = len(ann["frame_id"])
        expected = np.zeros((n, 3))
        expected[:, 2] = ann["z_ego"]
        np.testing.assert_allclose(ann["keypoints_3d_cam"][:, 9], expected, atol=1e-6, rtol=0, err_msg=split)
        np.testing.assert_allclose(ann["keypoints_2d"][:, 9], np.full((n, 2), 32.0), atol=1e-4, err_msg=split)
        # the manifest's per-view direction is where each frame's camera stands, seen from the arm
        T_world_cam = invert_transform(ann["T_cam_world"])
        eye = T_world_cam[:, :3, 3]
        kp9_world = transform_points(T_world_cam, ann["keypoints_3d_cam"][:, 9:10].astype(np.float64))[:, 0]
        seen = np.einsum("nji,nj->ni", _arm_frames(ann["hand_pose"]), (eye - kp9_world) / ann["z_ego"][:, None])
        want = directions[[view_index[v] for v in ann["view_id"]]]
        np.testing.assert_allclose(seen, want, atol=1e-5, err_msg=split)
        # the back of the hand is up in every image: the 2D dorsal direction from keypoint 9 points to -v
        dorsal_cam = np.einsum("nij,nj->ni", ann["T_cam_world"][:, :3, :3], _arm_frames(ann["hand_pose"])[:, :, 1])
        assert np.all(np.abs(dorsal_cam[:, 0]) < 1e-9) and np.all(dorsal_cam[:, 1] < 0), split


def test_earlier_protocol_is_an_option_and_verifies(tiny, tmp_path):
    """axis=forearm + look_at=box_centre: the cameras hupbench made before issue 13."""
    from hupbench.core.camera import look_at
    from hupbench.datagen.dataset.sphere import SphereSpec

    _, grasps, _ = tiny
    out = tmp_path / "earlier"
    run(out, grasps, spec=dict(sphere=SphereSpec(r_circ_m=0.4, axis="forearm", exclude=("poles",)),
                               look_at="box_centre"))
    assert verify(out, workers=1, log=lambda *_: None)["ok"]
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["protocol"]["look_at"] == "box_centre" and manifest["protocol"]["look_at_index"] is None
    assert manifest["protocol"]["sphere_axis"] == "forearm"
    ann = annotations(out)["train"]
    arm = _arm_frames(ann["hand_pose"])
    kp_world = transform_points(invert_transform(ann["T_cam_world"]), ann["keypoints_3d_cam"].astype(np.float64))
    centre = 0.5 * (kp_world.min(axis=1) + kp_world.max(axis=1))
    for i in range(len(ann["frame_id"])):
        elbow, dorsal, radial = arm[i].T
        theta, phi = ann["theta"][i], ann["phi"][i]
        direction = (np.sin(theta) * np.cos(phi) * dorsal + np.sin(theta) * np.sin(phi) * radial
                     + np.cos(theta) * elbow)
        T = look_at(centre[i] + ann["z_ego"][i] * direction, centre[i], up_world=-elbow)
        np.testing.assert_allclose(ann["T_cam_world"][i], T, atol=1e-6)
    # keypoint 9 is off the optical axis here
    assert np.abs(ann["keypoints_3d_cam"][:, 9, :2]).max() > 0.005


def test_verify_checks_the_protocols_look_at(tiny, tmp_path):
    broken = _broken_copy(tiny, tmp_path)
    manifest = json.loads((broken / "manifest.json").read_text())
    manifest["protocol"]["look_at"] = "wrist"
    (broken / "manifest.json").write_text(json.dumps(manifest))
    problems = verify(broken, workers=1, log=lambda *_: None)["problems"]
    flagged = {p["frame_id"] for p in problems if p["kind"] == "look_at"}
    ann = annotations(broken)
    assert flagged == {int(f) for a in ann.values() for f in a["frame_id"]}
    assert "wrist at" in next(p["detail"] for p in problems if p["kind"] == "look_at")


def test_the_config_hash_leaves_out_what_does_not_change_a_frame():
    """The hash is the sha256 of the config's JSON without the run-only keys, nested targets as written."""
    import hashlib

    from hupbench.datagen.dataset.writer import config_hash

    now = {"seed": 3, "workers": 2, "spec": {"_target_": "hupbench.datagen.dataset.spec.DatasetSpec", "size": 64}}
    kept = {"seed": 3, "spec": {"_target_": "hupbench.datagen.dataset.spec.DatasetSpec", "size": 64}}
    assert config_hash(now) == hashlib.sha256(json.dumps(kept, sort_keys=True).encode()).hexdigest()
    assert config_hash(now) == config_hash({**now, "workers": 1, "out_dir": "elsewhere"})
    assert config_hash(now) != config_hash({**now, "seed": 4})


def test_the_camera_is_built_once_per_dataset(tmp_path, monkeypatch):
    """DatasetSpec builds (and checks) its Intrinsics; rendering and writing a dataset never builds another."""
    from hupbench.core.camera import Intrinsics

    spec = DatasetSpec(**TINY)
    grasps = write_grasps(tmp_path / "grasps.npz")

    def built_again(self):
        raise AssertionError("an Intrinsics was built while the dataset was generated")

    monkeypatch.setattr(Intrinsics, "__post_init__", built_again)
    result = generate(GenerateRun(spec, tmp_path / "ds", grasps, progress=False), {"test": "camera"},
                      log=lambda *_: None)
    assert result["complete"]
    assert json.loads((tmp_path / "ds" / "manifest.json").read_text())["K"] == spec.intrinsics.K.tolist()
