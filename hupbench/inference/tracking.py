"""Keypoints tracked over a video: a temporal filter carrying state from frame to frame (numpy only).

:class:`OneEuroFilter` is the 1-euro filter (Casiez, Roussel and Vogel, "1 Euro Filter: A Simple Speed-based
Low-pass Filter for Noisy Input in Interactive Systems", CHI 2012): an exponential smoother per coordinate whose
cut-off frequency rises with the signal's own (smoothed) speed, ``cutoff = min_cutoff_hz + beta * |speed|``, so
a still hand is smoothed hard (little jitter) and a moving one lightly (little lag).

Convention:
    Keypoints (K, 3) float, metres (or (K, 2) pixels), one frame at a time, with the frame's time in seconds;
    cut-offs in Hz, ``beta`` in 1/metre (per unit of the keypoints).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from hupbench.core.errors import BadValueError
from hupbench.core.input_checks import check_number

__all__ = ["OneEuroFilter", "parse_track"]


def _alpha(cutoff_hz: np.ndarray | float, dt_s: float) -> np.ndarray | float:
    """The exponential smoother's weight of a new sample at a cut-off frequency and a time step."""
    tau = 1.0 / (2.0 * math.pi * np.asarray(cutoff_hz))
    return 1.0 / (1.0 + tau / dt_s)


class OneEuroFilter:
    """The 1-euro filter over arrays of keypoints (the module docstring).

    Args:
        min_cutoff_hz: the cut-off at rest, Hz, > 0: lower smooths a still hand more.
        beta: how fast the cut-off rises with speed (per unit of the keypoints per second), >= 0: higher lags
            less behind a moving hand.
        derivative_cutoff_hz: the cut-off of the speed's own smoothing, Hz, > 0 (the paper's 1 Hz).
    """

    def __init__(self, min_cutoff_hz: float = 1.0, beta: float = 0.0, derivative_cutoff_hz: float = 1.0) -> None:
        self.min_cutoff_hz = check_number(min_cutoff_hz, "min_cutoff_hz", 0.0, low_open=True)
        self.beta = check_number(beta, "beta", 0.0)
        self.derivative_cutoff_hz = check_number(derivative_cutoff_hz, "derivative_cutoff_hz", 0.0, low_open=True)
        self.reset()

    def reset(self) -> None:
        """Forget the track (a cut in the video, a lost hand): the next frame passes as it is."""
        self._value: np.ndarray | None = None
        self._speed: np.ndarray | None = None
        self._time_s: float | None = None

    def __call__(self, points: np.ndarray, time_s: float) -> np.ndarray:
        """The filtered keypoints of one frame.

        Args:
            points: (K, D) float, the frame's keypoints (the same K and D every frame).
            time_s: the frame's time, seconds, later than the previous frame's.

        Returns:
            (K, D) float64; the first frame after :meth:`reset` unchanged.
        """
        points = np.asarray(points, dtype=np.float64)
        if self._value is None:
            self._value, self._speed, self._time_s = points.copy(), np.zeros_like(points), float(time_s)
            return points.copy()
        assert points.shape == self._value.shape, (points.shape, self._value.shape)
        dt = float(time_s) - self._time_s
        assert dt > 0, f"frame times must increase, got {time_s} after {self._time_s}"
        speed = (points - self._value) / dt
        self._speed = self._speed + _alpha(self.derivative_cutoff_hz, dt) * (speed - self._speed)
        cutoff = self.min_cutoff_hz + self.beta * np.abs(self._speed)
        self._value = self._value + _alpha(cutoff, dt) * (points - self._value)
        self._time_s = float(time_s)
        return self._value.copy()


def parse_track(value: Any) -> dict[str, float]:
    """``--track`` as the 1-euro filter's settings: ``"min_cutoff_hz,beta"`` or a dict of both, a cut-off > 0 Hz
    and a beta >= 0."""
    if isinstance(value, str):
        parts = value.split(",")
        try:
            numbers = [float(v) for v in parts] if len(parts) == 2 else None
        except ValueError:
            numbers = None
        if numbers is None:
            raise BadValueError(f"--track must be two numbers min_cutoff_hz,beta (e.g. 1,10), got {value!r}")
        value = dict(zip(("min_cutoff_hz", "beta"), numbers))
    if not isinstance(value, dict) or set(value) != {"min_cutoff_hz", "beta"}:
        raise BadValueError(f"--track must give min_cutoff_hz and beta, got {value!r}")
    return {"min_cutoff_hz": check_number(value["min_cutoff_hz"], "--track's min_cutoff_hz", 0.0, low_open=True),
            "beta": check_number(value["beta"], "--track's beta", 0.0)}
