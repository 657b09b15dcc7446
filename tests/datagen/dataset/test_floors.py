"""Split floors from annotations (datagen/dataset/floors.py): known values, the three tracks, refusals."""

import json

import numpy as np
import pytest

from hupbench.core import keypoints as kp
from hupbench.datagen.dataset.floors import SEARCH_BLOCK_BYTES, nearest_frames, split_floors
from hupbench.datagen.dataset.verify import report_lines
from hupbench.evaluation.results import validate_split_floor
from hupbench.core.geometry import axis_angle_to_matrix


def _annotations(frames):
    """Annotation arrays from (grasp_id, view_id, z_ego, (29, 3) keypoints) tuples, each frame twice (two
    backgrounds show the same keypoints)."""
    frames = [f for f in frames for _ in range(2)]
    return {"grasp_id": np.array([f[0] for f in frames], np.int64), "view_id": np.array([f[1] for f in frames], np.int64),
            "z_ego": np.array([f[2] for f in frames]), "keypoints_3d_cam": np.stack([f[3] for f in frames]).astype(np.float32)}


def _grasp(seed):
    return np.random.default_rng(seed).normal(scale=0.05, size=(kp.NUM_KEYPOINTS, 3))


def _view(points, view):
    """The grasp seen in view ``view``: one rotation per view, the same for every grasp (the protocol)."""
    return points @ axis_angle_to_matrix(np.array([0.3 * view, 0.1, 0.0])).T + np.array([0, 0, 0.5])


def test_nearest_training_grasp_known_values():
    a, b, c = _grasp(0), _grasp(1), _grasp(2)
    moved = a.copy()
    moved[:kp.NUM_HAND] += [0.004, 0.0, 0.003]  # 5 mm on every hand keypoint
    moved[kp.NUM_HAND:] += [0.0, 0.012, 0.0]    # 12 mm on every corner
    ann = {"train": _annotations([(g, v, 0.5, _view(p, v)) for g, p in ((10, a), (11, b)) for v in range(3)]),
           "test": _annotations([(20, v, 0.5, _view(moved, v)) for v in range(3)]
                                + [(21, v, 0.5, _view(c, v)) for v in range(3)])}
    floors = split_floors(ann, "unseen_grasps")
    assert set(floors) == {"test"}
    test = floors["test"]
    assert test["floor_kind"] == "nearest_train_grasp" and test["nearest_train_view_mm"] is None
    near = test["per_grasp"]["20"]
    assert near["nearest_train_grasp_id"] == 10 and near["frames"] == 6
    np.testing.assert_allclose([near["floor_mm"][k] for k in ("hand", "probe", "all")],
                               [5.0, 12.0, (21 * 5 + 8 * 12) / 29], rtol=1e-5)
    # the distance to the mean training grasp, worked out by hand
    mean = (a + b) / 2
    to_mean = np.linalg.norm(mean - moved, axis=1) * 1000
    assert near["train_mean_mm"]["all"] == pytest.approx(to_mean.mean(), rel=1e-5)
    # the split's floor is the frame-weighted mean of its grasps'
    far = test["per_grasp"]["21"]
    assert test["floor_mm"]["probe"] == pytest.approx((near["floor_mm"]["probe"] + far["floor_mm"]["probe"]) / 2)


def test_unseen_views_floor_is_the_nearest_training_view_of_the_same_grasp():
    a = _grasp(0)
    train = [(5, v, 0.5, _view(a, v)) for v in (0, 1, 3)]
    test = [(5, 2, 0.5, _view(a, 2))]
    floors = split_floors({"train": _annotations(train), "test": _annotations(test)}, "unseen_views")["test"]
    assert floors["floor_kind"] == "nearest_train_view"
    assert floors["nearest_train_grasp_mm"] == {"hand": 0.0, "probe": 0.0, "all": 0.0}  # the grasp is in training
    expected = min(np.linalg.norm(_view(a, v) - _view(a, 2), axis=1).mean() for v in (0, 1, 3)) * 1000
    assert floors["floor_mm"]["all"] == pytest.approx(expected, rel=1e-5)
    assert floors["per_grasp"]["5"]["nearest_train_grasp_id"] == 5


def test_floors_refuse_what_cannot_be_measured():
    a = _grasp(0)
    # grasp 2 is seen only in view 1, no training grasp is
    with pytest.raises(ValueError, match="grasp 2 is seen in no view"):
        split_floors({"train": _annotations([(1, 0, 0.5, a)]), "test": _annotations([(2, 1, 0.5, a)])},
                     "unseen_grasps")


def _clinic(seed, frames, grasps, repeats=2):
    """Clinic-like annotations: ``frames`` random camera-frame poses of ``grasps`` grasps, each shown
    ``repeats`` times (backgrounds and gloves), rows shuffled."""
    rng = np.random.default_rng(seed)
    poses = rng.normal(scale=0.05, size=(frames, kp.NUM_KEYPOINTS, 3)) + [0.0, 0.0, 0.5]
    grasp = rng.integers(0, grasps, size=frames) + 100 * seed
    order = rng.permutation(frames * repeats)
    return {"keypoints_3d_cam": np.repeat(poses, repeats, axis=0)[order].astype(np.float32),
            "grasp_id": np.repeat(grasp, repeats)[order], "view_id": np.zeros(frames * repeats, np.int64),
            "z_ego": np.zeros(frames * repeats)}


def _brute_force_mm(train, frames):
    """(N, 29) mm from each frame to the training frame of least mean keypoint distance, one frame at a time."""
    train = train.astype(np.float64)
    out = []
    for frame in frames.astype(np.float64):
        d = np.linalg.norm(train - frame, axis=-1)  # (T, 29)
        out.append(d[np.argmin(d.mean(axis=1))] * 1000)
    return np.stack(out)


def test_clinic_floor_is_the_nearest_training_frame_of_any_grasp_and_view():
    train, test = _clinic(1, 60, 5), _clinic(2, 25, 3)
    floors = split_floors({"train": train, "val": _clinic(3, 0, 1), "test": test}, "clinic")
    assert set(floors) == {"test"}
    entry = floors["test"]
    assert entry["floor_kind"] == "nearest_train_frame"
    assert entry["nearest_train_grasp_mm"] is None and entry["nearest_train_view_mm"] is None
    expected = _brute_force_mm(train["keypoints_3d_cam"], test["keypoints_3d_cam"])
    for part, columns in (("hand", slice(0, kp.NUM_HAND)), ("probe", slice(kp.NUM_HAND, None)), ("all", slice(None))):
        assert entry["floor_mm"][part] == pytest.approx(expected[:, columns].mean(), rel=1e-9)
        assert entry["nearest_train_frame_mm"][part] == entry["floor_mm"][part]
    to_mean = np.linalg.norm(test["keypoints_3d_cam"] - train["keypoints_3d_cam"].astype(np.float64).mean(axis=0),
                             axis=-1) * 1000
    assert entry["train_mean_mm"]["all"] == pytest.approx(to_mean.mean(), rel=1e-9)
    assert sum(e["frames"] for e in entry["per_grasp"].values()) == len(test["grasp_id"])
    for grasp, per in entry["per_grasp"].items():
        mine = test["grasp_id"] == int(grasp)
        assert per["frames"] == int(mine.sum()) and per["nearest_train_grasp_id"] is None
        assert per["floor_mm"]["probe"] == pytest.approx(expected[mine, kp.NUM_HAND:].mean(), rel=1e-9)


def test_clinic_floor_is_zero_for_a_frame_seen_in_training():
    train, test = _clinic(4, 30, 4), _clinic(5, 10, 2)
    test["keypoints_3d_cam"][:2] = train["keypoints_3d_cam"][7]  # grasp of the first rows: one training pose
    test["grasp_id"][:2] = 999
    floors = split_floors({"train": train, "test": test}, "clinic")["test"]["per_grasp"]
    assert floors["999"]["floor_mm"] == {"hand": 0.0, "probe": 0.0, "all": 0.0}
    assert floors["999"]["frames"] == 2
    assert all(f["floor_mm"]["all"] > 1.0 for g, f in floors.items() if g != "999")


def test_nearest_frames_blocks_agree_with_one_block(monkeypatch):
    rng = np.random.default_rng(6)
    train = rng.normal(scale=0.05, size=(40, kp.NUM_KEYPOINTS, 3))
    poses = rng.normal(scale=0.05, size=(9, kp.NUM_KEYPOINTS, 3))
    whole = nearest_frames(poses, train)
    monkeypatch.setattr("hupbench.datagen.dataset.floors.SEARCH_BLOCK_BYTES", 1)  # one pose per block
    blocked = nearest_frames(poses, train)
    np.testing.assert_array_equal(whole[0], blocked[0])
    np.testing.assert_array_equal(whole[1], blocked[1])
    brute = np.argmin(np.linalg.norm(poses[:, None] - train[None], axis=-1).mean(axis=-1), axis=1)
    np.testing.assert_array_equal(whole[0], brute)
    assert SEARCH_BLOCK_BYTES >= 2**20


def test_verify_prints_the_clinic_floor():
    floors = split_floors({"train": _clinic(7, 20, 3), "test": _clinic(8, 5, 2)}, "clinic")
    result = {"problems": [], "image_shift": None, "grasps_sha256": None, "split_floors": floors, "ok": True,
              "frames": 50}
    line = next(x for x in report_lines(result, 5) if x.startswith("  floor of test"))
    mm = floors["test"]["floor_mm"]
    assert (f"nearest training frame of any grasp and view hand {mm['hand']:.1f} / probe {mm['probe']:.1f} / all "
            f"{mm['all']:.1f} mm; mean training frame") in line
    assert "nearest training grasp under" not in line and line.endswith("than the nearest_train_frame one)")


def test_the_clinic_floor_reads_as_a_results_split_floor():
    floors = split_floors({"train": _clinic(9, 20, 3), "test": _clinic(10, 6, 2)}, "clinic")["test"]
    assert validate_split_floor(json.loads(json.dumps(floors))) == floors
