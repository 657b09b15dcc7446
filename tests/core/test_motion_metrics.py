"""Motion metrics against hand computations and analytic motions."""

import numpy as np
import pytest

from hupbench.core.motion_metrics import (KINEMATICS_KEYS, acceleration_error_mm_per_frame2, jitter_mm_per_s3,
                                     point_kinematics, time_derivatives)


def _track(frames=30, keypoints=29, seed=0):
    return np.random.default_rng(seed).normal(scale=0.1, size=(frames, keypoints, 3))


@pytest.mark.parametrize("keypoints", [None, 1, 29])
def test_the_truth_against_itself_has_no_acceleration_error(keypoints):
    track = _track(keypoints=keypoints or 1)
    track = track[:, 0] if keypoints is None else track
    assert acceleration_error_mm_per_frame2(track, track) == 0.0


def test_a_constant_velocity_drift_has_no_acceleration_error():
    truth = _track()
    drift = np.arange(30)[:, None, None] * np.array([0.002, -0.001, 0.003])
    assert acceleration_error_mm_per_frame2(truth + drift + 0.05, truth) == pytest.approx(0.0, abs=1e-9)


def test_one_displaced_frame_matches_the_hand_computation():
    """A keypoint moved by 1 mm at frame 4 of 10 changes the second differences at frames 3, 4 and 5 by 1, 2
    and 1 mm: 4 mm over 8 second differences of 1 keypoint, 0.5 mm/frame^2; with 2 keypoints, 0.25."""
    truth = _track(frames=10, keypoints=2)
    pred = truth.copy()
    pred[4, 0] += np.array([0.0, 0.0006, 0.0008])  # 1 mm
    assert acceleration_error_mm_per_frame2(pred[:, :1], truth[:, :1]) == pytest.approx(0.5)
    assert acceleration_error_mm_per_frame2(pred, truth) == pytest.approx(0.25)


def test_a_constant_velocity_point_has_its_speed_and_no_acceleration_or_jerk():
    fps, velocity = 30.0, np.array([0.003, 0.004, 0.0])  # 5 mm/s
    track = np.arange(20)[:, None] / fps * velocity
    for window in (None, 7):
        got = point_kinematics(track, fps, window)
        assert list(got) == list(KINEMATICS_KEYS)
        assert got["speed_mm_per_s"] == pytest.approx(5.0)
        assert got["acceleration_mm_per_s2"] == pytest.approx(0.0, abs=1e-9)
        assert got["jerk_mm_per_s3"] == pytest.approx(0.0, abs=1e-6)


def test_a_circle_has_its_analytic_speed_acceleration_and_jerk():
    """Uniform circular motion of radius r at angular speed w: speed w r, acceleration w^2 r, jerk w^3 r."""
    fps, radius, omega = 30.0, 0.05, 2.0
    t = np.arange(300) / fps
    track = radius * np.stack([np.cos(omega * t), np.sin(omega * t), np.zeros_like(t)], axis=1)
    got = point_kinematics(track, fps)
    want = [omega ** n * radius * 1000.0 for n in (1, 2, 3)]
    np.testing.assert_allclose([got[key] for key in KINEMATICS_KEYS], want, rtol=2e-3)


def test_savitzky_golay_derivatives_are_exact_on_a_cubic():
    fps = 30.0
    t = np.arange(40) / fps
    a = np.array([0.01, -0.02, 0.005])  # m/s^3
    track = np.outer(t ** 3, a) + np.outer(t, [0.001, 0.0, 0.002])
    velocity, acceleration, jerk = time_derivatives(track, fps, window=9)
    assert velocity.shape == acceleration.shape == jerk.shape == track.shape
    np.testing.assert_allclose(velocity, np.outer(3 * t ** 2, a) + [0.001, 0.0, 0.002], atol=1e-10)
    np.testing.assert_allclose(acceleration, np.outer(6 * t, a), atol=1e-9)
    np.testing.assert_allclose(jerk, np.broadcast_to(6 * a, track.shape), atol=1e-8)


def test_finite_differences_have_one_frame_fewer_per_order():
    velocity, acceleration, jerk = time_derivatives(_track(frames=12, keypoints=4), 30.0)
    assert [len(velocity), len(acceleration), len(jerk)] == [11, 10, 9]
    assert velocity.shape[1:] == (4, 3)


def test_the_jitter_of_white_noise_is_the_documented_figure():
    """Independent noise of s per axis: sqrt(8 / pi) * sqrt(20) * s * fps^3 (the docstring's figure)."""
    fps, s = 30.0, 0.001
    noise = np.random.default_rng(1).normal(scale=s, size=(20000, 3))
    want = np.sqrt(8 / np.pi) * np.sqrt(20) * s * fps ** 3 * 1000.0
    assert jitter_mm_per_s3(noise, fps) == pytest.approx(want, rel=0.02)
    assert jitter_mm_per_s3(np.zeros((10, 29, 3)), fps) == 0.0


def test_a_smoothing_window_lowers_the_jerk_of_a_noisy_track():
    fps = 30.0
    t = np.arange(150) / fps
    truth = 0.02 * np.stack([np.sin(t), np.cos(0.5 * t), t], axis=1)
    noisy = truth + np.random.default_rng(2).normal(scale=0.0005, size=truth.shape)
    true_jerk = point_kinematics(truth, fps)["jerk_mm_per_s3"]
    raw, smoothed = (point_kinematics(noisy, fps, window)["jerk_mm_per_s3"] for window in (None, 15))
    assert raw > 100 * true_jerk
    assert smoothed < raw / 10
