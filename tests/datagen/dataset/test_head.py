"""Head cameras (datagen/dataset/head.py): aim, distance, elevation, roll, clearance, refusals, OpenCV."""

import math

import cv2
import numpy as np
import pytest
from hydra.utils import instantiate
from omegaconf import OmegaConf

from hupbench.core.camera import Intrinsics, project_points
from hupbench.core.errors import BadValueError, RunFailedError
from hupbench.core.geometry import matrix_to_axis_angle
from hupbench.datagen.dataset.head import HeadSpec, head_cameras, head_poses, horizontal_axes

INTRINSICS = Intrinsics(480.0, 470.0, 130.0, 120.0, 256, 240)
TARGET = np.array([0.02, -0.01, 0.03])
#: a tilted room vertical: nothing may rely on the world's z being up
VERTICAL = np.array([0.3, -0.2, 0.9])


def _all_clear(points):
    return np.ones(len(points), dtype=bool)


def _cameras(spec=HeadSpec(), seed=0, clear=_all_clear, vertical=VERTICAL):
    return head_cameras(spec, INTRINSICS, TARGET, vertical, clear, np.random.default_rng(seed))


def _centres(T_cam_world):
    """(V, 3) camera centres in the world frame."""
    return -np.einsum("vji,vj->vi", T_cam_world[:, :3, :3], T_cam_world[:, :3, 3])


def _target_cam(T_cam_world):
    return np.einsum("vij,j->vi", T_cam_world[:, :3, :3], TARGET) + T_cam_world[:, :3, 3]


def _elevation_deg(centres, vertical=VERTICAL):
    up = vertical / np.linalg.norm(vertical)
    d = centres - TARGET
    return np.degrees(np.arcsin((d @ up) / np.linalg.norm(d, axis=1)))


def _roll_deg(T_cam_world, vertical=VERTICAL):
    """Angle of the projected vertical from the image's up (-y), camera x towards y positive."""
    u = np.einsum("vij,j->vi", T_cam_world[:, :3, :3], vertical)
    return np.degrees(np.arctan2(-u[:, 0], -u[:, 1]))


def test_target_lands_on_the_drawn_pixel_inside_the_box():
    cams = _cameras(HeadSpec(views_per_grasp=400))
    uv = project_points(_target_cam(cams["T_cam_world"])[:, None], INTRINSICS.K)[:, 0]
    np.testing.assert_allclose(uv, cams["aim_px"], atol=1e-6)
    offset = (cams["aim_px"] - [INTRINSICS.cx, INTRINSICS.cy]) / [INTRINSICS.width, INTRINSICS.height]
    assert np.all(np.abs(offset) <= 0.15)
    # the box is used, not only its centre: both sides of both axes within 2 % of its edge
    assert np.all(offset.max(axis=0) > 0.13) and np.all(offset.min(axis=0) < -0.13)


def test_distance_elevation_roll_and_rotation():
    spec = HeadSpec(views_per_grasp=500)
    cams = _cameras(spec, seed=1)
    T = cams["T_cam_world"]
    assert T.shape == (500, 4, 4) and np.all(T[:, 3] == [0, 0, 0, 1])
    R = T[:, :3, :3]
    np.testing.assert_allclose(R @ np.swapaxes(R, 1, 2), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
    distance = np.linalg.norm(_centres(T) - TARGET, axis=1)
    np.testing.assert_allclose(distance, cams["distance_m"], atol=1e-12)
    assert np.all((distance >= 0.35) & (distance <= 0.8))
    assert distance.max() - distance.min() > 0.4  # drawn over the range, not at two distances
    assert len(np.unique(distance.round(4))) > 450  # continuous
    elevation = _elevation_deg(_centres(T))
    np.testing.assert_allclose(elevation, cams["elevation_deg"], atol=1e-9)
    assert elevation.min() >= 25.0 - 1e-9 and elevation.max() > 85.0
    # uniform on the cap: sin(elevation) uniform in [sin 25 deg, 1], so its mean is the midpoint
    assert np.sin(np.radians(elevation)).mean() == pytest.approx((math.sin(math.radians(25)) + 1) / 2, abs=0.03)
    assert np.all(np.abs(cams["roll_deg"]) <= 15.0)
    assert (cams["roll_deg"] > 5).sum() > 100 and (cams["roll_deg"] < -5).sum() > 100
    assert np.all((cams["azimuth_deg"] >= 0) & (cams["azimuth_deg"] < 360))


def test_roll_is_the_angle_of_the_vertical_in_the_image_without_aim_jitter():
    cams = _cameras(HeadSpec(aim_jitter=0.0, views_per_grasp=50), seed=2)
    np.testing.assert_allclose(_roll_deg(cams["T_cam_world"]), cams["roll_deg"], atol=1e-9)
    np.testing.assert_allclose(cams["aim_px"], np.tile([INTRINSICS.cx, INTRINSICS.cy], (50, 1)))
    # no roll and no jitter: the vertical points straight up the image
    level = _cameras(HeadSpec(aim_jitter=0.0, roll_deg=0.0, views_per_grasp=20), seed=3)
    np.testing.assert_allclose(_roll_deg(level["T_cam_world"]), 0.0, atol=1e-9)


def test_azimuth_is_measured_from_the_fixed_horizontal_axis():
    h0, h1, up = horizontal_axes(VERTICAL)
    np.testing.assert_allclose(np.stack([h0, h1, up]) @ np.stack([h0, h1, up]).T, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(np.cross(h0, h1), up, atol=1e-12)
    cams = _cameras(HeadSpec(views_per_grasp=30), seed=4)
    d = _centres(cams["T_cam_world"]) - TARGET
    np.testing.assert_allclose(np.degrees(np.arctan2(d @ h1, d @ h0)) % 360, cams["azimuth_deg"], atol=1e-9)


def _zenith_draws(elevation, azimuth=0.7, roll=0.1):
    n = len(elevation)
    return {"distance_m": np.full(n, 0.5), "elevation": np.asarray(elevation, float), "azimuth": np.full(n, azimuth),
            "roll": np.full(n, roll), "aim_px": np.tile([150.0, 100.0], (n, 1))}


def test_cameras_at_and_near_the_zenith_are_finite_and_continuous():
    below = math.pi / 2 - np.array([1e-3, 1e-6, 1e-9, 1e-12, 0.0])
    T, centre = head_poses(_zenith_draws(below), INTRINSICS, TARGET, VERTICAL)
    assert np.all(np.isfinite(T))
    R = T[:, :3, :3]
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
    # the pose moves smoothly into the zenith: the turn from each pose to the zenith's shrinks with the angle
    gap = np.linalg.norm(matrix_to_axis_angle(R[-1] @ np.swapaxes(R[:-1], 1, 2)), axis=1)
    assert np.all(gap <= 2.0 * (math.pi / 2 - below[:-1]) + 1e-12)
    uv = project_points(_target_cam(T)[:, None], INTRINSICS.K)[:, 0]
    np.testing.assert_allclose(uv, np.tile([150.0, 100.0], (5, 1)), atol=1e-6)
    # a spec whose cap is a sliver at the zenith draws only finite cameras
    cams = _cameras(HeadSpec(elevation_min_deg=89.999999, views_per_grasp=50), seed=5)
    assert np.all(np.isfinite(cams["T_cam_world"])) and np.all(cams["elevation_deg"] >= 89.999999 - 1e-9)


def test_clear_is_honoured_and_refused_cameras_are_redrawn():
    calls = []

    def upper_half(points):
        calls.append(len(points))
        return points[:, 2] >= 0.0

    # vertical along x: half of the cap lies at z < 0
    cams = _cameras(HeadSpec(views_per_grasp=60), seed=6, clear=upper_half, vertical=np.array([1.0, 0.0, 0.0]))
    assert len(cams["T_cam_world"]) == 60 and np.all(_centres(cams["T_cam_world"])[:, 2] >= 0.0)
    assert len(calls) > 1 and calls[0] == 60  # refused cameras were redrawn in further rounds
    with pytest.raises(RunFailedError, match="60 of 60 head cameras are still inside the patient"):
        _cameras(HeadSpec(views_per_grasp=60), clear=lambda p: np.zeros(len(p), dtype=bool))


def test_seeded_cameras_are_identical():
    a, b = _cameras(seed=7), _cameras(seed=7)
    assert all(np.array_equal(a[k], b[k]) for k in a)
    c = _cameras(seed=8)
    assert not np.array_equal(a["T_cam_world"], c["T_cam_world"])


def test_against_opencv_project_points():
    cams = _cameras(HeadSpec(views_per_grasp=5), seed=9)
    points = TARGET + np.random.default_rng(0).normal(scale=0.05, size=(29, 3))
    for T in cams["T_cam_world"]:
        rvec, _ = cv2.Rodrigues(T[:3, :3])
        expected, _ = cv2.projectPoints(points, rvec, T[:3, 3], INTRINSICS.K, None)
        ours = project_points(points @ T[:3, :3].T + T[:3, 3], INTRINSICS.K)
        np.testing.assert_allclose(ours, expected[:, 0], atol=1e-6)
        target_px, _ = cv2.projectPoints(TARGET[None], rvec, T[:3, 3], INTRINSICS.K, None)
    np.testing.assert_allclose(target_px[0, 0], cams["aim_px"][-1], atol=1e-6)


@pytest.mark.parametrize("overrides, message", [
    ({"elevation_min_deg": 90.0}, r"dataset.head.elevation_min_deg must be a finite number in \[0, 90\)"),
    ({"elevation_min_deg": -1.0}, "elevation_min_deg must be a finite number in"),
    ({"distance_m": (0.05, 0.8)},
     r"dataset.head.distance_m must be two numbers \[low, high\], low <= high, from 0.1 to 10 m, got \[0.05, 0.8\]"),
    ({"distance_m": (0.8, 0.35)}, "distance_m must be"),
    ({"distance_m": (0.35, 11.0)}, "distance_m must be"),
    ({"distance_m": 0.5}, "distance_m must be"),
    ({"views_per_grasp": 0}, "dataset.head.views_per_grasp must be a whole number >= 1"),
    ({"aim_jitter": -0.1}, r"aim_jitter must be a finite number in \[0, 0.5\)"),
    ({"aim_jitter": 0.5}, "aim_jitter must be"),
    ({"roll_deg": -5.0}, r"dataset.head.roll_deg must be a finite number in \[0, 180\]"),
    ({"roll_deg": float("nan")}, "roll_deg must be"),
])
def test_bad_values_are_refused_naming_the_key(overrides, message):
    with pytest.raises(BadValueError, match=message):
        HeadSpec(**overrides)


def test_defaults():
    spec = HeadSpec()
    assert (spec.distance_m, spec.elevation_min_deg, spec.aim_jitter, spec.roll_deg, spec.views_per_grasp) == \
        ((0.35, 0.8), 25.0, 0.15, 15.0, 33)
    assert HeadSpec(distance_m=[0.5, 0.5]).distance_m == (0.5, 0.5)
    # as the config hands it over
    node = OmegaConf.create({"_target_": "hupbench.datagen.dataset.head.HeadSpec", "distance_m": [0.4, 0.7]})
    assert instantiate(node).distance_m == (0.4, 0.7)
