"""The bootstrap interval over test grasps against a plain numpy reference, and its zero-width and seed cases."""

import json

import numpy as np
import pytest

from hupbench.evaluation.intervals import (
    METHOD,
    grasp_interval,
    grasp_interval_of_grasps,
    interval_text,
    intervals_block,
)
from hupbench.evaluation.split_metrics import split_breakdowns, split_intervals

#: a hand-made results set: frame errors (mm) of four grasps with 3, 1, 2 and 4 frames
GRASP_IDS = np.array([41, 41, 41, 7, 76, 76, 120, 120, 120, 120])
ERRORS_MM = np.array([30.0, 28.0, 31.0, 9.5, 7.0, 8.5, 15.0, 16.0, 14.0, 17.5])


def _reference(errors, grasp_ids, resamples, seed):
    """The interval by a loop: draw the grasps of each resample, gather their frames, take the mean."""
    grasps = sorted(set(grasp_ids.tolist()))
    drawn = np.random.default_rng(seed).integers(0, len(grasps), size=(resamples, len(grasps)))
    statistics = []
    for row in drawn:
        frames = [e for g in row for e, gid in zip(errors, grasp_ids) if gid == grasps[g]]
        statistics.append(np.mean(frames))
    return np.percentile(statistics, 2.5), np.percentile(statistics, 97.5)


@pytest.mark.parametrize("seed", [0, 3])
def test_interval_equals_a_numpy_reference(seed):
    out = grasp_interval(ERRORS_MM, GRASP_IDS, resamples=2000, seed=seed)
    low, high = _reference(ERRORS_MM, GRASP_IDS, 2000, seed)
    assert out["low"] == pytest.approx(low, abs=1e-9) and out["high"] == pytest.approx(high, abs=1e-9)
    assert out["estimate"] == pytest.approx(ERRORS_MM.mean(), abs=1e-12)
    assert (out["n_grasps"], out["resamples"], out["seed"], out["confidence"], out["method"]) == \
        (4, 2000, seed, 0.95, METHOD)
    assert out["low"] < out["estimate"] < out["high"]
    # the four grasps' means are 29.67, 9.5, 7.75, 15.63 mm: the interval lies within their range
    assert 7.75 <= out["low"] and out["high"] <= 29.67


def test_per_grasp_values_give_the_interval_of_frames_carrying_them():
    values, frames = np.array([22.5, 8.0, 30.25]), np.array([3, 1, 5])
    per_frame = np.repeat(values, frames)
    ids = np.repeat([2, 5, 9], frames)
    by_grasp = grasp_interval_of_grasps(values, frames, resamples=3000, seed=1)
    by_frame = grasp_interval(per_frame, ids, resamples=3000, seed=1)
    for key in ("estimate", "low", "high"):
        assert by_grasp[key] == pytest.approx(by_frame[key], abs=1e-9)
    assert by_grasp["estimate"] == pytest.approx(np.average(values, weights=frames))
    assert (by_grasp["low"], by_grasp["high"]) == pytest.approx(_reference(per_frame, ids, 3000, 1), abs=1e-9)


def test_same_error_in_every_grasp_gives_zero_width():
    errors = np.full(10, 18.62)
    out = grasp_interval(errors, GRASP_IDS, resamples=500)
    assert out["low"] == out["high"] == out["estimate"] == 18.62
    floor = grasp_interval_of_grasps(np.full(4, 59.3), np.array([3, 1, 2, 4]), resamples=500)
    assert floor["low"] == floor["high"] == floor["estimate"] == 59.3


def test_one_grasp_gives_zero_width():
    out = grasp_interval(np.array([1.0, 2.0, 6.0]), np.array([4, 4, 4]), resamples=100)
    assert out["low"] == out["high"] == pytest.approx(3.0) and out["n_grasps"] == 1


def test_seeded_draws_are_reproducible_and_seeds_differ():
    a = grasp_interval(ERRORS_MM, GRASP_IDS, resamples=200, seed=11)
    assert a == grasp_interval(ERRORS_MM, GRASP_IDS, resamples=200, seed=11)
    b = grasp_interval(ERRORS_MM, GRASP_IDS, resamples=200, seed=12)
    assert (a["low"], a["high"]) != (b["low"], b["high"])


def test_two_grasps_interval_spans_both_grasp_means():
    """With two grasps the extreme resamples are each grasp alone: the 95 % interval reaches both means."""
    errors, ids = np.array([29.52, 29.52, 7.72, 7.72]), np.array([41, 41, 76, 76])
    out = grasp_interval(errors, ids)
    assert out["resamples"] == 10_000 and out["seed"] == 0
    assert out["low"] == pytest.approx(7.72) and out["high"] == pytest.approx(29.52)


def test_split_intervals_of_each_mpjpe_and_the_floor():
    """The eval's block: per-keypoint errors of hand-made frames, the floor's per-grasp values, one set of draws."""
    rng = np.random.default_rng(5)
    errors = rng.uniform(1.0, 40.0, size=(len(GRASP_IDS), 29))                     # (N, 29) mm
    floor = {"per_grasp": {str(g): {"floor_mm": {"hand": 10.0 + g, "probe": 50.0 - g / 4, "all": 20.0 + g / 2},
                                    "frames": int(np.sum(GRASP_IDS == g))} for g in (7, 41, 76, 120)}}
    block = split_intervals(errors, GRASP_IDS, floor, resamples=1500, seed=2)
    assert (block["method"], block["confidence"], block["resamples"], block["seed"], block["grasps"]) == \
        (METHOD, 0.95, 1500, 2, 4)
    for part, cols in (("all", slice(None)), ("hand", slice(0, 21)), ("probe", slice(21, 29))):
        assert block["mpjpe_mm"][part] == pytest.approx(_reference(errors[:, cols].mean(axis=1), GRASP_IDS, 1500, 2),
                                                        abs=1e-9)
        per_frame_floor = np.array([floor["per_grasp"][str(g)]["floor_mm"][part] for g in GRASP_IDS])
        assert block["split_floor_mm"][part] == pytest.approx(_reference(per_frame_floor, GRASP_IDS, 1500, 2),
                                                              abs=1e-9)
    assert split_intervals(errors, GRASP_IDS, None, 10, 0)["split_floor_mm"] is None


def test_intervals_recomputed_from_a_results_files_breakdown_equal_evals():
    """What eval writes (the grasp breakdown, the floor, the intervals), read back from JSON: the intervals
    recomputed from the breakdown and the floor's per-grasp values are the stored ones, and those of the
    frames' errors (:func:`grasp_interval`) to well below the printed digits."""
    rng = np.random.default_rng(8)
    # twelve grasps, ids whose text order is not their numeric order, frames 1-6 each: a near-continuous statistic
    grasps = np.array([3, 5, 7, 9, 12, 25, 41, 76, 90, 103, 120, 200])
    grasp_ids = np.repeat(grasps, rng.integers(1, 7, size=len(grasps)))                 # (N,)
    errors = rng.gamma(2.0, 6.0, size=(len(grasp_ids), 29)) * (1.0 + grasp_ids[:, None] % 4)   # (N, 29) mm
    floor = {"per_grasp": {str(g): {"floor_mm": {"hand": 10.0 + g / 3, "probe": 55.0 - g / 5, "all": 20.0 + g / 7},
                                    "frames": int(np.sum(grasp_ids == g))} for g in grasps}}
    fields = {"theta": np.full(len(grasp_ids), 0.5), "z_ego": np.full(len(grasp_ids), 0.5),
              "background_id": np.zeros(len(grasp_ids), int), "grasp_id": grasp_ids}
    written = {"breakdowns": split_breakdowns(errors, fields, {}, None), "split_floor": floor,
               "intervals": split_intervals(errors, grasp_ids, floor, 10_000, 0)}
    results = json.loads(json.dumps(written))
    recomputed = intervals_block(results["breakdowns"]["grasp"], results["split_floor"]["per_grasp"])
    assert recomputed == results["intervals"]
    for part, cols in (("all", slice(None)), ("hand", slice(0, 21)), ("probe", slice(21, 29))):
        by_frame = grasp_interval(errors[:, cols].mean(axis=1), grasp_ids)
        assert recomputed["mpjpe_mm"][part] == pytest.approx([by_frame["low"], by_frame["high"]], abs=1e-9)
        assert interval_text(recomputed["mpjpe_mm"][part]) == interval_text([by_frame["low"], by_frame["high"]])
        assert recomputed["mpjpe_mm"][part][0] < recomputed["mpjpe_mm"][part][1]


def test_interval_text():
    assert interval_text([7.71, 29.46]) == "[7.7-29.5]"
    assert interval_text([7.71, 29.46], "95 % CI ") == "[95 % CI 7.7-29.5]"
    assert interval_text(None) == "—" and interval_text(None, missing="[—]") == "[—]"
