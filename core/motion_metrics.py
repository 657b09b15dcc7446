"""Metrics of keypoint tracks over time (a clip's frames in order): pure numpy functions.

Convention:
    A track is (T, K, 3) float, metres, all T frames in one frame of reference (the camera's, or the world's
    for a moving camera), sampled at a constant rate: frame t is at time t / fps seconds. A point track is
    (T, 3). The n-th finite difference along time of T frames has T - n frames. Every reported number has its
    unit in its name: millimetres per frame^n (``_mm_per_frame2``, the human-motion literature's unit of
    acceleration error) or per second^n (``_mm_per_s``, ``_mm_per_s2``, ``_mm_per_s3``, the units of the
    probe-motion studies of ultrasound skill).

Callers pass well-formed tracks (the scan-motion generator builds them): shapes are asserted, not
re-checked for users.
"""

from __future__ import annotations

import numpy as np

__all__ = ["KINEMATICS_KEYS", "acceleration_error_mm_per_frame2", "jitter_mm_per_s3", "point_kinematics",
           "time_derivatives"]

#: the keys of :func:`point_kinematics`, in the order of the derivatives they average
KINEMATICS_KEYS = ("speed_mm_per_s", "acceleration_mm_per_s2", "jerk_mm_per_s3")
#: the polynomial order of the Savitzky-Golay derivative filter (:func:`time_derivatives`): cubic, so that a
#: jerk (the third derivative) is defined inside each window
SAVGOL_ORDER = 3

_MM_PER_M = 1000.0


def _assert_track(track_m: np.ndarray, min_frames: int) -> np.ndarray:
    track_m = np.asarray(track_m, np.float64)
    assert track_m.ndim in (2, 3) and track_m.shape[-1] == 3, track_m.shape
    assert track_m.shape[0] >= min_frames, f"{track_m.shape[0]} frames, at least {min_frames} needed"
    return track_m


def acceleration_error_mm_per_frame2(pred_m, gt_m) -> float:
    """Acceleration error, mm per frame^2: the mean over frames and keypoints of the norm of the difference
    between the predicted and the true second differences (Kanazawa et al. 2019, "Learning 3D Human Dynamics
    from Video", CVPR: "the average difference between ground truth 3D acceleration and predicted 3D
    acceleration of each joint in mm/frame^2").

    Args:
        pred_m: (T, K, 3) or (T, 3) float, metres, predicted track, T >= 3.
        gt_m: the true track, same shape and frame.

    Returns:
        a python float, mm/frame^2; 0 for a prediction that is the truth plus any constant-velocity drift.
    """
    pred_m, gt_m = _assert_track(pred_m, 3), _assert_track(gt_m, 3)
    assert pred_m.shape == gt_m.shape, (pred_m.shape, gt_m.shape)
    difference = np.diff(pred_m - gt_m, n=2, axis=0)  # (T - 2, K, 3) or (T - 2, 3)
    return float(np.linalg.norm(difference, axis=-1).mean() * _MM_PER_M)


def time_derivatives(track_m, fps: float, window: int | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The first three time derivatives of a track, metres per second^n.

    Args:
        track_m: (T, ...) float, metres, the time axis first.
        fps: frames per second of the track, > 0.
        window: None for plain finite differences (velocity T - 1 frames, acceleration T - 2, jerk T - 3,
            each at the midpoint of its frames); an odd number of frames > SAVGOL_ORDER for a Savitzky-Golay
            filter (Savitzky and Golay 1964; a cubic fitted in each window, its derivatives taken: T frames
            each, exact for a cubic track), which smooths a noisy (predicted) track before differentiating.

    Returns:
        (velocity m/s, acceleration m/s^2, jerk m/s^3), arrays of the track's trailing shape.
    """
    assert fps > 0, fps
    if window is None:
        track_m = _assert_track(track_m, 4)
        return tuple(np.diff(track_m, n=n, axis=0) * fps ** n for n in (1, 2, 3))
    from scipy.signal import savgol_filter

    assert window % 2 == 1 and window > SAVGOL_ORDER, window
    track_m = _assert_track(track_m, window)
    return tuple(savgol_filter(track_m, window, SAVGOL_ORDER, deriv=n, delta=1.0 / fps, axis=0, mode="interp")
                 for n in (1, 2, 3))


def point_kinematics(track_m, fps: float, window: int | None = None) -> dict[str, float]:
    """Mean speed, acceleration and jerk magnitudes of a point's track: the figures of probe-motion studies
    of ultrasound skill (e.g. Le Lous et al. 2024: consultants move the probe at 12.9 mm/s, fellows at 24.6).

    Args:
        track_m: (T, 3) float, metres, one point (e.g. the probe's centre) over T frames.
        fps: frames per second, > 0.
        window: as :func:`time_derivatives` (None: finite differences; an odd frame count: Savitzky-Golay).

    Returns:
        {"speed_mm_per_s", "acceleration_mm_per_s2", "jerk_mm_per_s3"}: python floats, the mean norm of each
        derivative over the frames that have it.
    """
    track_m = np.asarray(track_m, np.float64)
    assert track_m.ndim == 2, track_m.shape
    return {key: float(np.linalg.norm(derivative, axis=-1).mean() * _MM_PER_M)
            for key, derivative in zip(KINEMATICS_KEYS, time_derivatives(track_m, fps, window))}


def jitter_mm_per_s3(track_m, fps: float) -> float:
    """Jitter of a track alone, mm/s^3: the mean norm of its jerk by finite differences (the third difference
    times fps^3) over frames and keypoints, as the motion-capture literature reports the smoothness of a
    prediction (e.g. Yi et al. 2022, "Physical Inertial Poser", CVPR). A smooth true motion has a small one;
    independent per-frame noise of standard deviation s on each axis alone has sqrt(8 / pi) * sqrt(20) * s *
    fps^3, about 7.14 s fps^3 (the third difference's weights 1, -3, 3, -1 give each axis a standard deviation
    of sqrt(20) s, and the mean norm of a 3D normal is sqrt(8 / pi) times its axes').

    Args:
        track_m: (T, K, 3) or (T, 3) float, metres, T >= 4.
        fps: frames per second, > 0.
    """
    jerk = time_derivatives(track_m, fps)[2]
    return float(np.linalg.norm(jerk, axis=-1).mean() * _MM_PER_M)
