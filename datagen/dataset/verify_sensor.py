"""``hupbench verify`` on a dataset with a depth sensor: each frame's sensor depth against its clean depth and the
preset the manifest records (:mod:`hupbench.core.depth_sensor`).

Where the preset's depth camera sees the surface steadily (no depth edge near, in range, away from a wrap), the
sensor depth minus the depth the preset reads without random error (:func:`~hupbench.core.depth_sensor.
sensor_expectation`: the material's offset and the wrap in) must show

* an offset (its median) within :data:`BIAS_SIGMAS` of the preset's per-frame offset sigma, plus 1 mm;
* a random error (1.4826 x the median absolute deviation, per pixel in units of the preset's sigma there) within
  :data:`NOISE_RATIO` of 1;
* a share of pixels without depth within 5 binomial sigmas plus :data:`INVALID_SLACK` of the preset's expectation.

A frame whose sensor depth is its clean depth copied (no noise), another frame's, or another preset's fails one of
these; a frame with fewer than :data:`MIN_STEADY_PX` steady pixels is not judged.
"""

from __future__ import annotations

import numpy as np

from hupbench.core.depth_sensor import SensorPreset, sensor_expectation

#: the offset's bound, in the preset's per-frame offset sigmas (plus 1 mm)
BIAS_SIGMAS = 5.0
#: the random error's ratio to the preset's must lie in this interval
NOISE_RATIO = (0.7, 1.4)
#: slack on the share of invalid pixels beyond its binomial spread (the expectation is taken in the colour image)
INVALID_SLACK = 0.03
#: steady pixels a frame needs to be judged
MIN_STEADY_PX = 200


def sensor_depth_problem(clean: np.ndarray, measured: np.ndarray, seg: np.ndarray, K: np.ndarray,
                         sensor: SensorPreset, label_ids: dict[str, int], depth_scale_m: float) -> str | None:
    """What is wrong with a frame's sensor depth (``measured``, uint16) against its clean depth (``clean``, uint16),
    its labels ``seg``, the colour camera ``K`` and ``sensor``, in words; None when it fits the preset."""
    expected = sensor_expectation(clean * depth_scale_m, seg, K, sensor, label_ids)
    steady = expected["steady"] & expected["seen"] & (clean > 0)
    n = int(steady.sum())
    if n < MIN_STEADY_PX:
        return None
    got = measured * depth_scale_m
    valid = steady & (got > 0)
    observed, p = 1.0 - valid.sum() / n, expected["p_invalid"][steady]
    want, spread = float(p.mean()), float(np.sqrt((p * (1 - p)).sum()) / n)
    if abs(observed - want) > 5 * spread + INVALID_SLACK:
        return (f"{observed:.1%} of {n} steadily seen pixels have no sensor depth where {sensor.name} gives "
                f"{want:.1%} (tolerance {5 * spread + INVALID_SLACK:.1%})")
    if valid.sum() < MIN_STEADY_PX:
        return None
    residual = got[valid] - expected["z"][valid]
    bias = float(np.median(residual))
    limit = BIAS_SIGMAS * sensor.bias_sigma_m + 1e-3
    if abs(bias) > limit:
        return (f"the sensor depth is offset {bias * 1000:+.1f} mm from what {sensor.name} reads of the clean depth "
                f"(tolerance {limit * 1000:.1f} mm)")
    ratio = 1.4826 * float(np.median(np.abs((residual - bias) / expected["sigma_m"][valid])))
    if not NOISE_RATIO[0] <= ratio <= NOISE_RATIO[1]:
        return (f"the sensor depth's random error is {ratio:.2f} x {sensor.name}'s "
                f"(tolerance {NOISE_RATIO[0]}-{NOISE_RATIO[1]}): not this frame's sensor depth")
    return None
