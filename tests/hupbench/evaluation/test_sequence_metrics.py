"""A split of clips scored as motion: clips in time order, the filter chosen on the tuning split by its criterion,
tracking that lowers a noisy prediction's acceleration error without raising its MPJPE (with the paired interval
of the difference below 0), and no filter where every setting would raise the MPJPE."""

from __future__ import annotations

import numpy as np
import pytest

from hupbench.core import keypoints as kp

from hupbench.evaluation.sequence_metrics import (KEPT, SCORES, choose_filter, clip_rows, clip_scores, room_poses,
                                                   sequence_block, sequence_block_problem, tracked)

FPS, FRAMES, CLIPS_PER_GRASP, GRASPS = 30.0, 60, 2, 3


def _clips(seed: int):
    """A split of GRASPS x CLIPS_PER_GRASP clips of slowly moving keypoints (a few cm/s, as a probe on the skin),
    and (N, 29, 3) predictions = truth + 3 mm white noise per axis."""
    rng = np.random.default_rng(seed)
    t = np.arange(FRAMES) / FPS
    truth, fields = [], {"clip_id": [], "frame_in_clip": [], "time_s": [], "grasp_id": []}
    for clip in range(GRASPS * CLIPS_PER_GRASP):
        base = rng.uniform(-0.1, 0.1, (29, 3)) + [0.0, 0.0, 0.5]
        omega, amplitude = rng.uniform(0.5, 2.0, 3), rng.uniform(0.005, 0.02, 3)
        truth.append(base[None] + (amplitude * np.sin(omega * t[:, None]))[:, None, :])
        fields["clip_id"] += [clip] * FRAMES
        fields["frame_in_clip"] += list(range(FRAMES))
        fields["time_s"] += list(t)
        fields["grasp_id"] += [100 + clip // CLIPS_PER_GRASP] * FRAMES
    gt = np.concatenate(truth)
    fields = {k: np.asarray(v) for k, v in fields.items()}
    # the camera in the room: turned 90 degrees about z and 1 m up (the room's figures equal the camera's)
    T = np.array([[0.0, -1.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 1.0], [0.0, 0.0, 0.0, 1.0]])
    fields["T_world_body"] = np.tile(np.eye(4), (len(gt), 1, 1))
    fields["T_cam_world"] = np.tile(np.linalg.inv(T), (len(gt), 1, 1))
    return gt + rng.normal(0.0, 0.003, gt.shape), gt, fields


def test_clip_rows_follow_time_not_row_order():
    fields = {"clip_id": np.array([4, 4, 2, 4, 2]), "frame_in_clip": np.array([2, 0, 1, 1, 0])}
    rows = clip_rows(fields)
    assert [r.tolist() for r in rows] == [[4, 2], [1, 3, 0]]


def test_the_truth_scores_zero_and_a_filter_is_fresh_per_clip():
    pred, gt, fields = _clips(0)
    clips = clip_rows(fields)
    scores = clip_scores(gt, gt, clips, FPS, room_poses(fields))
    for key in SCORES:
        if key != "jitter_mm_per_s3":
            assert np.all(scores[key] == 0.0), key
    np.testing.assert_allclose(scores["jitter_mm_per_s3"], scores["truth_jitter_mm_per_s3"])
    # each clip's first frame passes the filter unchanged: its state does not leak from the clip before
    smoothed = tracked(pred, fields, clips, {"min_cutoff_hz": 0.5, "beta": 0.0})
    firsts = [r[0] for r in clips]
    np.testing.assert_array_equal(smoothed[firsts], pred[firsts])
    assert np.abs(smoothed[clips[0][1:]] - pred[clips[0][1:]]).max() > 1e-4


def test_tracking_chosen_on_val_lowers_the_acceleration_error_on_test_without_raising_mpjpe():
    val_pred, val_gt, val_fields = _clips(1)
    choice = choose_filter(val_pred, val_gt, val_fields, FPS)
    assert choice["settings"] is not None
    kept = [t for t in choice["tried"] if all(t[k] <= choice["untracked"][k] for k in KEPT)]
    assert len(kept) < len(choice["tried"])
    best = min(t["acceleration_error_mm_per_frame2"] for t in kept)
    chosen = [t for t in choice["tried"] if t["min_cutoff_hz"] == choice["settings"]["min_cutoff_hz"]
              and t["beta"] == choice["settings"]["beta"]]
    assert chosen[0]["acceleration_error_mm_per_frame2"] == best
    pred, gt, fields = _clips(2)
    block = sequence_block(pred, gt, fields, FPS, choice, "val", 2000, 0)
    assert sequence_block_problem(block) is None
    broken = {**block, "intervals": {**block["intervals"], "tracked": {**block["intervals"]["tracked"],
                                                                       "jitter_mm_per_s3": [2.0, 1.0]}}}
    assert sequence_block_problem(broken) == ("['intervals']['tracked']['jitter_mm_per_s3']: must be [low, high] "
                                              "numbers, low <= high, got [2.0, 1.0]")
    assert "must have the keys" in sequence_block_problem({**block, "extra": 1})
    assert block["clips"] == GRASPS * CLIPS_PER_GRASP and block["intervals"]["grasps"] == GRASPS
    untracked, tracked_ = block["untracked"], block["tracked"]
    assert tracked_["acceleration_error_mm_per_frame2"] < 0.5 * untracked["acceleration_error_mm_per_frame2"]
    assert tracked_["jitter_mm_per_s3"] < 0.5 * untracked["jitter_mm_per_s3"]
    assert all(tracked_[k] <= untracked[k] for k in KEPT)
    assert block["intervals"]["tracked_minus_untracked"]["acceleration_error_mm_per_frame2"][1] < 0
    # the noise is white: the per-frame prediction's acceleration error is the noise's second difference,
    # sqrt(6) x 3 mm per axis, its mean norm sqrt(8 / pi) x that
    assert untracked["acceleration_error_mm_per_frame2"] == pytest.approx(np.sqrt(8 / np.pi) * np.sqrt(6) * 3.0,
                                                                          rel=0.05)
    # the probe's speed measured from the noisy track is far off; tracked, closer; a camera still in the room gives
    # the room the camera's figures
    assert tracked_["probe_speed_mm_per_s_error"] < untracked["probe_speed_mm_per_s_error"]
    for key in ("speed_mm_per_s", "acceleration_mm_per_s2", "jerk_mm_per_s3"):
        assert untracked[f"probe_room_{key}_error"] == pytest.approx(untracked[f"probe_{key}_error"], rel=1e-9)
        assert block["truth"][f"probe_room_{key}"] == pytest.approx(block["truth"][f"probe_{key}"], rel=1e-9)


def test_no_filter_where_every_setting_raises_the_mpjpe():
    """A prediction equal to the truth: any filter lags behind it, so none is kept and tracking changes nothing."""
    _, gt, fields = _clips(3)
    choice = choose_filter(gt, gt, fields, FPS)
    assert choice["settings"] is None
    block = sequence_block(gt, gt, fields, FPS, choice, "val", 100, 0)
    assert block["tracked"] == block["untracked"]


def test_no_setting_that_raises_the_hands_mpjpe_is_chosen_even_where_it_lowers_all_of_them():
    """The hand's keypoints nearly exact (2 mm of noise) and swinging (2 cm at 1 Hz: a filter lags behind them),
    the probe's noisy (15 mm more: a filter smooths them): a strong filter lowers MPJPE all and raises the hand's;
    the chosen one raises none of the three. And the filter runs on the tracked fits' prediction where given (here
    the truth), against the per-frame prediction's MPJPE."""
    pred, gt, fields = _clips(3)
    t = fields["time_s"][:, None]
    gt[:, kp.HAND_SLICE, 0] += 0.02 * np.sin(2 * np.pi * 1.0 * t)
    hand = gt[:, kp.HAND_SLICE]
    pred[:, kp.HAND_SLICE] = hand + np.random.default_rng(5).normal(0.0, 0.002, hand.shape)
    pred[:, kp.CORNER_SLICE] += np.random.default_rng(4).normal(0.0, 0.015, pred[:, kp.CORNER_SLICE].shape)
    choice = choose_filter(pred, gt, fields, FPS)
    only_all = min((t for t in choice["tried"] if t["mpjpe_all_mm"] <= choice["untracked"]["mpjpe_all_mm"]),
                   key=lambda t: t["acceleration_error_mm_per_frame2"])
    assert only_all["mpjpe_hand_mm"] > choice["untracked"]["mpjpe_hand_mm"] + 3.0
    chosen = next(t for t in choice["tried"] if t["min_cutoff_hz"] == choice["settings"]["min_cutoff_hz"]
                  and t["beta"] == choice["settings"]["beta"])
    assert all(chosen[k] <= choice["untracked"][k] for k in KEPT)
    on_truth = choose_filter(pred, gt, fields, FPS, tracked3d=gt)
    assert on_truth["untracked"] == choice["untracked"]
    assert on_truth["tried"] == choose_filter(gt, gt, fields, FPS)["tried"] != choice["tried"]
