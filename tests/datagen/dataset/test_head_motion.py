"""A wearer's head over a clip: it starts at the drawn camera, keeps the hand where it was in the image but for
the gaze's lag, and sways and turns by the spec's amounts."""

import numpy as np
import pytest

from hupbench.core.camera import Intrinsics, look_at, project_points
from hupbench.core.errors import BadValueError
from hupbench.core.geometry import invert_transform, transform_points
from hupbench.datagen.dataset.head_motion import HeadMotionSpec, head_track

K = Intrinsics(300.0, 300.0, 128.0, 128.0, 256, 256).K
FPS = 30.0


def _clip(seconds=6.0):
    """The first camera 0.5 m above and beside a target that sweeps 6 cm and back over the clip."""
    t = np.arange(int(seconds * FPS) + 1) / FPS
    target = np.stack([0.06 * np.sin(2 * np.pi * t / seconds), 0.02 * np.sin(4 * np.pi * t / seconds),
                       0.3 + 0.0 * t], axis=1)
    T_cam_body0 = look_at(np.array([-0.3, 0.1, 0.7]), target[0], up_world=(0.0, 0.0, 1.0))
    return t, target, T_cam_body0


def _pixels(T_cam_body, points_body):
    cam = np.stack([transform_points(T, p[None])[0] for T, p in zip(T_cam_body, points_body)])
    return project_points(cam, K)


def test_the_first_frame_is_the_drawn_camera_and_every_pose_is_rigid():
    t, target, T0 = _clip()
    track = head_track(T0, target, t, HeadMotionSpec(), np.random.default_rng(0))
    assert track.shape == (len(t), 4, 4)
    np.testing.assert_allclose(track[0], T0, atol=1e-12)
    R = track[:, :3, :3]
    np.testing.assert_allclose(R @ np.swapaxes(R, 1, 2), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    assert np.all(np.linalg.det(R) > 0)


def test_without_sway_turns_or_lag_the_hand_keeps_its_pixel():
    t, target, T0 = _clip()
    spec = HeadMotionSpec(drift_m=0.0, turn_deg=0.0, follow_s=1e-9)
    uv = _pixels(head_track(T0, target, t, spec, np.random.default_rng(1)), target)
    np.testing.assert_allclose(uv, np.broadcast_to(uv[0], uv.shape), atol=1e-6)
    still = _pixels(np.broadcast_to(T0, (len(t), 4, 4)), target)
    assert np.abs(still - still[0]).max() > 20  # a still head would lose it by tens of pixels


def test_the_gaze_lags_a_moving_hand_and_catches_up_when_it_stops():
    t = np.arange(int(4 * FPS) + 1) / FPS
    target = np.zeros((len(t), 3)) + [0.0, 0.0, 0.3]
    moving = t < 1.0
    target[moving, 0] = 0.05 * t[moving]
    target[~moving, 0] = 0.05
    T0 = look_at(np.array([-0.3, 0.1, 0.7]), target[0], up_world=(0.0, 0.0, 1.0))
    spec = HeadMotionSpec(drift_m=0.0, turn_deg=0.0, follow_s=0.3)
    uv = _pixels(head_track(T0, target, t, spec, np.random.default_rng(2)), target)
    offset = np.linalg.norm(uv - uv[0], axis=1)
    at_stop = int(FPS)
    assert offset[at_stop] > 1.0  # behind while the hand moves
    assert offset[-1] < offset[at_stop] * np.exp(-2.5 / 0.3) * 1.5 + 1e-6  # caught up after 10 lags


def test_the_sway_and_the_turns_have_the_spec_s_size():
    t = np.arange(0.0, 600.0, 0.2)
    target = np.zeros((len(t), 3)) + [0.0, 0.0, 0.3]
    T0 = look_at(np.array([-0.3, 0.1, 0.7]), target[0], up_world=(0.0, 0.0, 1.0))
    track = head_track(T0, target, t, HeadMotionSpec(drift_m=0.03, turn_deg=0.0), np.random.default_rng(3))
    centres = invert_transform(track)[:, :3, 3]
    np.testing.assert_allclose(centres.std(axis=0), 0.03, rtol=0.2)
    # own turns alone: the line of sight swings about the camera's x and y by turn_deg each about their mean, so its
    # angle from the first frame has an RMS between sqrt(2) turn_deg and 2 turn_deg (the first frame's own
    # offset from that mean adds as much again, on average)
    still = HeadMotionSpec(drift_m=0.0, turn_deg=3.0, follow_s=1e-9)
    for seed in (4, 5):
        R = head_track(T0, target, t, still, np.random.default_rng(seed))[:, :3, :3]
        sight = R[:, 2, :]  # the camera's z axis in the body frame
        rms = np.sqrt(np.mean(np.degrees(np.arccos(np.clip(sight @ sight[0], -1.0, 1.0))) ** 2))
        assert 0.9 * np.sqrt(2) * 3.0 < rms < 1.1 * 2 * 3.0, rms


@pytest.mark.parametrize("field, value, message", [
    ("drift_m", -0.01, "dataset.head_motion.drift_m must be a finite number"),
    ("turn_deg", 45, "dataset.head_motion.turn_deg must be a finite number"),
    ("follow_s", 0, "dataset.head_motion.follow_s must be a finite number"),
    ("band_hz", (1.0, 0.5), "dataset.head_motion.band_hz must be two numbers"),
])
def test_bad_spec_values_are_refused_naming_the_key(field, value, message):
    with pytest.raises(BadValueError, match=message):
        HeadMotionSpec(**{field: value})
