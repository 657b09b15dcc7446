"""Split floors from annotations (datagen/dataset/floors.py): known values, the two tracks, refusals."""

import numpy as np
import pytest

from hupbench.core import keypoints as kp
from hupbench.datagen.dataset.floors import split_floors
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
    floors = split_floors(ann)
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
    floors = split_floors({"train": _annotations(train), "test": _annotations(test)})["test"]
    assert floors["floor_kind"] == "nearest_train_view"
    assert floors["nearest_train_grasp_mm"] == {"hand": 0.0, "probe": 0.0, "all": 0.0}  # the grasp is in training
    expected = min(np.linalg.norm(_view(a, v) - _view(a, 2), axis=1).mean() for v in (0, 1, 3)) * 1000
    assert floors["floor_mm"]["all"] == pytest.approx(expected, rel=1e-5)
    assert floors["per_grasp"]["5"]["nearest_train_grasp_id"] == 5


def test_floors_refuse_what_cannot_be_measured():
    a = _grasp(0)
    # grasp 2 is seen only in view 1, no training grasp is
    with pytest.raises(ValueError, match="grasp 2 is seen in no view"):
        split_floors({"train": _annotations([(1, 0, 0.5, a)]), "test": _annotations([(2, 1, 0.5, a)])})
