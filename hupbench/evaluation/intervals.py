"""Confidence intervals of a split's mean error over its test grasps: the percentile bootstrap, resampling grasps.

The frames of one grasp are not independent samples (they share the hand pose and the probe pose), so the
unit that is resampled is the grasp, as the cluster (two-stage) bootstrap resamples the top-level units of
hierarchical data (Davison & Hinkley 1997, *Bootstrap Methods and their Application*, Sec. 3.8). A resample
draws as many grasps as the split holds, with replacement; its statistic is the mean over the frames of the
drawn grasps (a grasp drawn twice counts twice), i.e. the frame-weighted mean of the drawn grasps' means.
The interval is the percentile interval of those statistics (Efron & Tibshirani 1993, *An Introduction to
the Bootstrap*, Ch. 13). Pure numpy; the draws come from a seeded ``numpy.random.Generator``.

Convention: values in the unit they come in (mm for the benchmark's errors); the interval is
``(low, high)`` at the ``(1 - confidence) / 2`` and ``(1 + confidence) / 2`` quantiles.
"""

from __future__ import annotations

import numpy as np

__all__ = ["CONFIDENCE", "METHOD", "PARTS", "RESAMPLES", "SEED", "grasp_interval", "grasp_interval_of_grasps",
           "interval_text", "intervals_block"]

#: the interval's coverage
CONFIDENCE = 0.95
#: bootstrap resamples by default
RESAMPLES = 10_000
#: the draws' seed by default
SEED = 0
#: how the interval is made, as results files record it
METHOD = ("percentile bootstrap over test grasps: grasps drawn with replacement, statistic the mean over the drawn "
          "grasps' frames")
#: the keypoint sets of each MPJPE and floor, as results files key them
PARTS = ("all", "hand", "probe")


def _interval(ref: float, deviation_sums: np.ndarray, frames: np.ndarray, resamples: int, seed: int,
              confidence: float) -> dict:
    """The interval of ``ref + sum(deviation_sums[drawn]) / sum(frames[drawn])`` over ``resamples`` draws.

    Args:
        ref: a value every statistic is measured from (a frame's error): equal values then give exactly equal
            statistics, with no rounding of a sum of many equal terms.
        deviation_sums: (G,) float64, each grasp's sum over its frames of (value - ref), grasps in increasing id.
        frames: (G,) int64 > 0, each grasp's frames.
    """
    assert deviation_sums.shape == frames.shape and frames.ndim == 1 and len(frames) >= 1, (deviation_sums.shape,
                                                                                             frames.shape)
    assert np.all(frames > 0) and resamples >= 1 and 0.0 < confidence < 1.0, (frames, resamples, confidence)
    n_grasps = len(frames)
    drawn = np.random.default_rng(seed).integers(0, n_grasps, size=(resamples, n_grasps))  # (B, G) grasp indices
    statistics = ref + deviation_sums[drawn].sum(axis=1) / frames[drawn].sum(axis=1)      # (B,)
    tail = 100.0 * (1.0 - confidence) / 2.0
    low, high = np.percentile(statistics, [tail, 100.0 - tail])
    return {"estimate": float(ref + deviation_sums.sum() / frames.sum()), "low": float(low), "high": float(high),
            "confidence": float(confidence), "n_grasps": int(n_grasps), "resamples": int(resamples),
            "seed": int(seed), "method": METHOD}


def grasp_interval(errors: np.ndarray, grasp_ids: np.ndarray, resamples: int = RESAMPLES, seed: int = SEED,
                   confidence: float = CONFIDENCE) -> dict:
    """The bootstrap interval over grasps of the mean of per-frame errors.

    Each of ``resamples`` resamples draws G grasps with replacement from the G distinct ids of ``grasp_ids``
    (``numpy.random.default_rng(seed).integers(0, G, size=(resamples, G))`` indexing the ids in increasing
    order); its statistic is the mean of the errors of every frame of the drawn grasps, a grasp drawn twice
    counting twice. With one grasp every resample is that grasp: the interval has zero width (it says nothing
    about other grasps). It has zero width too when every frame has the same error.

    Args:
        errors: (N,) float, one error per frame (e.g. a frame's mean keypoint error in mm), N >= 1.
        grasp_ids: (N,) int, the grasp of each frame.
        resamples: bootstrap resamples B >= 1. seed: the generator's seed. confidence: in (0, 1).

    Returns:
        {"estimate": mean over all frames, "low", "high": the percentile interval, "confidence", "n_grasps": G,
        "resamples": B, "seed", "method": :data:`METHOD`}, python scalars, values in the unit of ``errors``.
    """
    errors = np.asarray(errors, np.float64)
    grasp_ids = np.asarray(grasp_ids)
    assert errors.ndim == 1 and errors.shape == grasp_ids.shape and len(errors) >= 1, (errors.shape, grasp_ids.shape)
    _, grasp_index = np.unique(grasp_ids, return_inverse=True)                          # (N,) in [0, G)
    ref = errors[0]
    deviation_sums = np.bincount(grasp_index.ravel(), weights=errors - ref)             # (G,)
    frames = np.bincount(grasp_index.ravel())                                            # (G,)
    return _interval(float(ref), deviation_sums, frames, resamples, seed, confidence)


def grasp_interval_of_grasps(values: np.ndarray, frames: np.ndarray, resamples: int = RESAMPLES, seed: int = SEED,
                             confidence: float = CONFIDENCE) -> dict:
    """:func:`grasp_interval` of a value known per grasp, not per frame (e.g. a split floor's ``per_grasp``
    ``floor_mm``): each grasp weighs as many frames as it has, so that the statistic is the frame-weighted mean
    of the drawn grasps' values and the interval equals :func:`grasp_interval` of frames that each carry their
    grasp's value. With the grasps in increasing id and the same ``seed`` and ``resamples``, the draws are the
    same as :func:`grasp_interval`'s over the same grasps. One grasp, or equal values: zero width.

    Args:
        values: (G,) float, one value per grasp, grasps in increasing id, G >= 1.
        frames: (G,) int > 0, each grasp's frames in the split.
        resamples, seed, confidence: as :func:`grasp_interval`'s.

    Returns:
        As :func:`grasp_interval`, "estimate" the frame-weighted mean of ``values``.
    """
    values = np.asarray(values, np.float64)
    frames = np.asarray(frames, np.int64)
    assert values.ndim == 1 and values.shape == frames.shape and len(values) >= 1, (values.shape, frames.shape)
    ref = values[0]
    return _interval(float(ref), (values - ref) * frames, frames, resamples, seed, confidence)


def intervals_block(by_grasp: dict[str, dict], floor_by_grasp: dict[str, dict] | None, resamples: int = RESAMPLES,
                    seed: int = SEED) -> dict:
    """The ``intervals`` block of a results file, from its per-grasp records: the intervals over the grasps
    (:func:`grasp_interval_of_grasps`, one set of draws for all) of the MPJPE all / hand / probe and of the split
    floor.

    A resample's statistic, the mean error over the drawn grasps' frames, depends on each grasp's mean error and
    frame count only, so these are the intervals :func:`grasp_interval` gives of the frames' errors (equal up to
    float rounding), with the same draws: grasps in increasing id.

    Args:
        by_grasp: {decimal grasp id: {"frames": int >= 1, "mpjpe_mm": {"all", "hand", "probe": float mm}}}, each
            grasp's frames and mean error over them (a results file's ``breakdowns["grasp"]``), G >= 1 grasps.
        floor_by_grasp: {grasp id: {"floor_mm": {"all", "hand", "probe": float mm}, ...}} of the same grasps (a
            split floor's ``per_grasp``), each weighted by its frames in ``by_grasp``; or None.
        resamples: bootstrap resamples >= 1. seed: the draws' seed.

    Returns:
        {"method": :data:`METHOD`, "confidence", "resamples", "seed", "grasps": G, "mpjpe_mm": {part: [low, high]},
        "split_floor_mm": {part: [low, high]} or None}, mm.
    """
    grasps = sorted(by_grasp, key=int)
    assert grasps and (floor_by_grasp is None or set(floor_by_grasp) == set(grasps)), (grasps, floor_by_grasp)
    frames = np.array([by_grasp[g]["frames"] for g in grasps], np.int64)                # (G,)

    def bounds(values: list[float]) -> list[float]:
        interval = grasp_interval_of_grasps(np.array(values, np.float64), frames, resamples, seed)
        return [interval["low"], interval["high"]]

    floor = None if floor_by_grasp is None else {
        part: bounds([floor_by_grasp[g]["floor_mm"][part] for g in grasps]) for part in PARTS}
    return {"method": METHOD, "confidence": CONFIDENCE, "resamples": int(resamples), "seed": int(seed),
            "grasps": len(grasps), "mpjpe_mm": {part: bounds([by_grasp[g]["mpjpe_mm"][part] for g in grasps])
                                                for part in PARTS},
            "split_floor_mm": floor}


def interval_text(bounds: list[float] | None, label: str = "", missing: str = "—") -> str:
    """``"[7.7-29.5]"`` (``label`` ``"95 % CI "``: ``"[95 % CI 7.7-29.5]"``): an interval's [low, high] in one
    decimal, or ``missing`` where there is none."""
    return missing if bounds is None else f"[{label}{bounds[0]:.1f}-{bounds[1]:.1f}]"
