"""The 1-euro filter against the exponential smoother's closed forms, and what it does to a noisy track."""

import numpy as np
import pytest

from hupbench.core.errors import BadValueError
from hupbench.core.motion_metrics import acceleration_error_mm_per_frame2, jitter_mm_per_s3
from hupbench.inference.tracking import OneEuroFilter

FPS = 30.0


def _run(f, track):
    return np.stack([f(points, t / FPS) for t, points in enumerate(track)])


def _alpha(cutoff_hz):
    return 1.0 / (1.0 + FPS / (2 * np.pi * cutoff_hz))


def test_the_first_frame_passes_and_a_still_hand_stays_still():
    points = np.random.default_rng(0).normal(size=(29, 3))
    out = _run(OneEuroFilter(min_cutoff_hz=0.5, beta=2.0), np.broadcast_to(points, (20, 29, 3)))
    np.testing.assert_array_equal(out[0], points)
    np.testing.assert_allclose(out, np.broadcast_to(points, out.shape), atol=1e-15)


def test_at_rest_it_is_an_exponential_smoother_of_the_documented_weight():
    """beta 0: white noise's variance shrinks by alpha / (2 - alpha), alpha = 1 / (1 + 1 / (2 pi f_c dt))."""
    noise = np.random.default_rng(1).normal(scale=0.002, size=(20000, 1, 3))
    out = _run(OneEuroFilter(min_cutoff_hz=1.5, beta=0.0), noise)
    alpha = _alpha(1.5)
    assert out[100:].var() / noise.var() == pytest.approx(alpha / (2 - alpha), rel=0.05)


def test_speed_opens_the_filter_so_a_moving_hand_lags_less():
    """A ramp of 0.1 m/s: at rest (beta 0) the steady lag is v dt (1 - alpha) / alpha; beta shrinks it."""
    track = (np.arange(120) / FPS * 0.1)[:, None, None] * np.array([1.0, 0.0, 0.0])
    slow = _run(OneEuroFilter(min_cutoff_hz=1.0, beta=0.0), track)
    lag = track[-1, 0, 0] - slow[-1, 0, 0]
    alpha = _alpha(1.0)
    assert lag == pytest.approx(0.1 / FPS * (1 - alpha) / alpha, rel=0.01)
    fast = _run(OneEuroFilter(min_cutoff_hz=1.0, beta=200.0), track)
    assert track[-1, 0, 0] - fast[-1, 0, 0] < lag / 5


def test_filtering_a_noisy_track_lowers_its_acceleration_error_and_jitter():
    t = np.arange(300) / FPS
    truth = 0.03 * np.stack([np.sin(0.5 * t), np.cos(0.3 * t), 0.5 + 0 * t], axis=1)[:, None, :]
    noisy = truth + np.random.default_rng(2).normal(scale=0.003, size=truth.shape)
    filtered = _run(OneEuroFilter(min_cutoff_hz=1.0, beta=10.0), noisy)
    assert acceleration_error_mm_per_frame2(filtered, truth) < acceleration_error_mm_per_frame2(noisy, truth) / 3
    assert jitter_mm_per_s3(filtered, FPS) < jitter_mm_per_s3(noisy, FPS) / 3


def test_reset_forgets_the_track():
    f = OneEuroFilter(min_cutoff_hz=0.5)
    f(np.zeros((2, 3)), 0.0)
    f(np.ones((2, 3)), 1 / FPS)
    f.reset()
    np.testing.assert_array_equal(f(np.full((2, 3), 5.0), 2 / FPS), np.full((2, 3), 5.0))


@pytest.mark.parametrize("kwargs, message", [({"min_cutoff_hz": 0}, "min_cutoff_hz must be a finite number"),
                                             ({"beta": -1}, "beta must be a finite number"),
                                             ({"derivative_cutoff_hz": float("nan")}, "derivative_cutoff_hz must be")])
def test_bad_settings_are_refused_naming_them(kwargs, message):
    with pytest.raises(BadValueError, match=message):
        OneEuroFilter(**kwargs)
