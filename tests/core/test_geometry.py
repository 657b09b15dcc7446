import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from hupbench.core.geometry import (
    axis_angle_to_matrix,
    euler_to_matrix,
    invert_transform,
    make_transform,
    matrix_to_axis_angle,
    matrix_to_euler_xyz,
    transform_points,
)


def _random_axis_angles(rng, n, angles):
    axes = rng.normal(size=(n, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    return axes * np.asarray(angles)[:, None]


@pytest.mark.parametrize("batch", [(), (5,), (2, 3)])
def test_axis_angle_matches_scipy(batch):
    rng = np.random.default_rng(0)
    r = rng.normal(size=batch + (3,))
    R = axis_angle_to_matrix(r)
    assert R.shape == batch + (3, 3)
    expected = Rotation.from_rotvec(r.reshape(-1, 3)).as_matrix().reshape(batch + (3, 3))
    np.testing.assert_allclose(R, expected, atol=1e-12)


def test_known_rotation():
    R = axis_angle_to_matrix(np.array([0.0, 0.0, np.pi / 2]))
    np.testing.assert_allclose(R @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], atol=1e-15)


@pytest.mark.parametrize(
    "angle", [0.0, 1e-12, 1e-8, 1e-6, 1e-4, 0.5, 2.0, np.pi - 1e-2, np.pi - 1e-4, np.pi - 1e-7, np.pi]
)
def test_round_trip_near_zero_and_pi(angle):
    rng = np.random.default_rng(1)
    r = _random_axis_angles(rng, 64, np.full(64, angle))
    R = axis_angle_to_matrix(r)
    back = matrix_to_axis_angle(R)
    assert np.all(np.isfinite(back))
    np.testing.assert_allclose(axis_angle_to_matrix(back), R, atol=1e-9)
    if angle < np.pi - 1e-3:
        # away from pi the axis-angle vector itself is unique
        np.testing.assert_allclose(back, r, atol=1e-7)
    else:
        # at pi, r and -r are the same rotation
        err = np.minimum(np.linalg.norm(back - r, axis=1), np.linalg.norm(back + r, axis=1))
        assert err.max() < 1e-6


def test_matrix_to_axis_angle_matches_scipy_in_angle():
    rng = np.random.default_rng(2)
    R = Rotation.random(200, random_state=3).as_matrix()
    ours = matrix_to_axis_angle(R)
    np.testing.assert_allclose(np.linalg.norm(ours, axis=1), Rotation.from_matrix(R).magnitude(), atol=1e-9)
    del rng


def test_axis_angle_rejects_bad_input():
    with pytest.raises(ValueError, match=r"must be \(\.\.\., 3\)"):
        axis_angle_to_matrix(np.zeros(4))
    with pytest.raises(ValueError, match="NaN"):
        axis_angle_to_matrix(np.array([np.nan, 0, 0]))


def test_euler_xyz_matches_scipy_and_round_trips():
    rng = np.random.default_rng(4)
    angles = rng.uniform(-1.4, 1.4, size=(100, 3))
    R = euler_to_matrix(angles, "xyz")
    np.testing.assert_allclose(R, Rotation.from_euler("XYZ", angles).as_matrix(), atol=1e-12)
    np.testing.assert_allclose(matrix_to_euler_xyz(R), angles, atol=1e-10)
    # gimbal lock still returns a rotation that reproduces R
    locked = euler_to_matrix(np.array([0.3, np.pi / 2, -0.2]), "xyz")
    np.testing.assert_allclose(euler_to_matrix(matrix_to_euler_xyz(locked), "xyz"), locked, atol=1e-9)


def test_transforms_invert_and_apply():
    rng = np.random.default_rng(5)
    R = Rotation.random(4, random_state=6).as_matrix()
    t = rng.normal(size=(4, 3))
    T_a_b = make_transform(R, t)
    T_b_a = invert_transform(T_a_b)
    np.testing.assert_allclose(T_a_b @ T_b_a, np.broadcast_to(np.eye(4), (4, 4, 4)), atol=1e-12)
    points_b = rng.normal(size=(4, 7, 3))
    points_a = transform_points(T_a_b, points_b)
    np.testing.assert_allclose(points_a, np.einsum("bij,bnj->bni", R, points_b) + t[:, None], atol=1e-12)
    np.testing.assert_allclose(transform_points(T_b_a, points_a), points_b, atol=1e-12)
