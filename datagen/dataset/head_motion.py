"""A headset wearer's head over a scan's clip: its camera drifting and turning while the eyes follow the hand.

A head-worn camera never stands still: the wearer sways, and turns the head to keep looking at the probe as
it moves, a little late. :func:`head_track` moves a clip's first camera (one of
:func:`hupbench.datagen.dataset.head.head_cameras`) over the clip's frames:

1. **Sway.** The camera's centre drifts from where it starts by a smooth random offset on each axis of the
   room, a sum of sinusoids in ``band_hz`` (:func:`hupbench.datagen.dataset.scan_motion.band_noise`) with a
   standard deviation of ``drift_m`` per axis.
2. **Following.** The gaze follows keypoint 9 (the middle finger's MCP, where the first camera looks) with a
   first-order lag of time constant ``follow_s``: the head turns by the smallest rotation that takes the first
   frame's line of sight to the lagged target onto the current one, so the roll and the target's place in the
   image stay those of the first frame but for the lag.
3. **Own turns.** A smooth random turn about each camera axis, sinusoids in ``band_hz`` with a standard deviation
   of ``turn_deg``.

The defaults are hupbench's choices for a sonographer standing at the bed (a couple of centimetres of sway,
a couple of degrees of the head's own turns, a half-second lag), not measured figures; the config sets them.

Convention:
    Metres, seconds; degrees in the spec, radians inside. The body frame of
    :mod:`hupbench.datagen.assets.patient` is the room's (the bed and the room are fixed to it); cameras are
    ``T_cam_body`` in OpenCV axes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from hupbench.core.geometry import axis_angle_to_matrix, invert_transform
from hupbench.core.input_checks import check_interval, check_number
from hupbench.datagen.dataset.scan_motion import band_noise

__all__ = ["HeadMotionSpec", "head_track"]

@dataclass(frozen=True)
class HeadMotionSpec:
    """How a wearer's head moves over a clip (config node ``dataset.head_motion``).

    Attributes:
        drift_m: standard deviation of the camera centre's sway per axis of the room, metres, in [0, 0.2].
        turn_deg: standard deviation of the head's own turn about each camera axis, degrees, in [0, 20].
        follow_s: the gaze's lag behind keypoint 9, seconds (a first-order time constant), in (0, 10].
        band_hz: (low, high) the frequencies of the sway and the own turns, Hz, within 0.01-5.
    """

    drift_m: float = 0.02
    turn_deg: float = 2.0
    follow_s: float = 0.5
    band_hz: tuple = (0.05, 0.5)

    def __post_init__(self) -> None:
        object.__setattr__(self, "drift_m", check_number(self.drift_m, "dataset.head_motion.drift_m", 0.0, 0.2))
        object.__setattr__(self, "turn_deg", check_number(self.turn_deg, "dataset.head_motion.turn_deg", 0.0, 20.0))
        object.__setattr__(self, "follow_s", check_number(self.follow_s, "dataset.head_motion.follow_s", 0.0, 10.0,
                                                          low_open=True))
        object.__setattr__(self, "band_hz", check_interval(self.band_hz, "dataset.head_motion.band_hz", 0.01, 5.0,
                                                           unit="Hz"))


def _turn_onto(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(F, 3, 3) the smallest rotations taking unit (3,) ``a`` onto each unit (F, 3) ``b``."""
    cross = np.cross(a, b)  # (F, 3)
    sin = np.linalg.norm(cross, axis=1)
    angle = np.arctan2(sin, b @ a)
    scale = np.where(sin > 1e-15, angle / np.maximum(sin, 1e-15), 1.0)
    return axis_angle_to_matrix(cross * scale[:, None])


def head_track(T_cam_body0: np.ndarray, target_body: np.ndarray, time_s: np.ndarray, spec: HeadMotionSpec,
               rng: np.random.Generator) -> np.ndarray:
    """The head's camera over a clip (the module's steps 1-3).

    Args:
        T_cam_body0: (4, 4) float, the first frame's camera, OpenCV axes, body (room) frame.
        target_body: (F, 3) float, metres, keypoint 9 in the body frame per frame (it moves with the probe).
        time_s: (F,) float, the frames' times, seconds, increasing.
        spec: how the head moves.
        rng: the seeded generator of the clip's head.

    Returns:
        (F, 4, 4) float64 T_cam_body per frame; the first is ``T_cam_body0``.
    """
    target_body = np.asarray(target_body, dtype=np.float64)
    assert target_body.ndim == 2 and target_body.shape == (len(time_s), 3), target_body.shape
    T_body_cam0 = invert_transform(np.asarray(T_cam_body0, dtype=np.float64))
    centre = T_body_cam0[:3, 3] + spec.drift_m * band_noise(rng, time_s, spec.band_hz, 3)  # (F, 3)
    own = np.radians(spec.turn_deg) * band_noise(rng, time_s, spec.band_hz, 3)  # (F, 3) camera axes
    # the gaze's lagged target: first-order smoothing at the frames' own time steps
    gaze = np.empty_like(target_body)
    gaze[0] = target_body[0]
    for f in range(1, len(time_s)):
        weight = 1.0 - math.exp(-(time_s[f] - time_s[f - 1]) / spec.follow_s)
        gaze[f] = gaze[f - 1] + weight * (target_body[f] - gaze[f - 1])
    sight0 = gaze[0] - T_body_cam0[:3, 3]
    sight = gaze - centre
    follow = _turn_onto(sight0 / np.linalg.norm(sight0), sight / np.linalg.norm(sight, axis=1, keepdims=True))
    T_body_cam = np.tile(np.eye(4), (len(time_s), 1, 1))
    T_body_cam[:, :3, :3] = follow @ T_body_cam0[:3, :3] @ axis_angle_to_matrix(own)
    T_body_cam[:, :3, 3] = centre
    return invert_transform(T_body_cam)
