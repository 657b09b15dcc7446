"""A split of clips scored as motion (a dataset of ``hupbench generate +track=clinic_sequences``): per clip the
MPJPE, the acceleration error, the jitter and the probe's speed, acceleration and jerk, of the per-frame predictions
and of the tracked ones, with intervals over the evaluated grasps.

Tracking is what a video's frames allow and a single image does not: state carried from frame to frame. Here it is
the fits started where they left the frame before (:func:`hupbench.fits.track_fits`: the probe's pose; a model
without fits has none), then the 1-euro filter (:class:`hupbench.inference.tracking.OneEuroFilter`) over each clip's
predicted camera-frame keypoints in time order, both reset at the clip's start, as ``hupbench predict --track`` runs
them over a video or an ordered folder of frames. Its settings are chosen on the validation split (:func:`choose_filter`): of :data:`FILTER_GRID`, the one with
the lowest acceleration error among those whose MPJPE (all, hand and probe, each) is not above the per-frame
prediction's (no setting: no
filter). A test split is scored with the settings its validation split chose.

The metrics (:mod:`hupbench.core.motion_metrics`), each the mean over clips (every clip has the same frames):

* ``mpjpe_mm`` all / hand / probe, as the single-frame benchmark's;
* ``acceleration_error_mm_per_frame2``: the predicted minus the true second difference, all 29 keypoints;
* ``jitter_mm_per_s3``: the prediction's own third difference (the truth's is beside it under ``truth``);
* ``probe_<kinematics>_error``: per clip, the probe centre's (keypoints 21-28) mean speed, acceleration and jerk from
  the predicted track minus the true track's, absolute, mm/s^n, both in the camera frame, which moves with the head;
* ``probe_room_<kinematics>_error``: the same in the room (the patient's bed), each frame's prediction taken there
  with the camera's pose in the room, as a headset's own head tracking gives it (a HoloLens 2 reports its pose in a
  world-locked frame): the skill-assessment figures (Le Lous et al. 2024 measured 12.9 against 24.6 mm/s,
  consultants and fellows), which the head's motion swamps in the camera frame. The network and the fits never read
  that pose; the score takes the frame's true pose, so it assumes the headset's tracking exact.

Intervals are the percentile bootstrap over the evaluated grasps (:mod:`hupbench.evaluation.intervals`; a grasp's
value the mean of its clips), one set of draws for every metric; ``tracked_minus_untracked`` holds the paired
intervals of the differences, the evidence that tracking lowers one number and not another.

Convention:
    Keypoints (N, 29, 3) float, metres, camera frame, rows of a split in frame order (a clip's frames consecutive);
    clips and grasps by the annotations' ``clip_id`` and ``grasp_id``.
"""

from __future__ import annotations

import time

import numpy as np

from hupbench.core import keypoints as kp
from hupbench.core.input_checks import is_number, is_whole
from hupbench.core.geometry import invert_transform, transform_points
from hupbench.core.motion_metrics import (KINEMATICS_KEYS, acceleration_error_mm_per_frame2, jitter_mm_per_s3,
                                          point_kinematics)
from hupbench.evaluation.intervals import CONFIDENCE, METHOD, grasp_interval_of_grasps
from hupbench.fits.settings import HandFitSettings, ProbeFitSettings
from hupbench.inference.tracking import OneEuroFilter

__all__ = ["FIELDS", "FILTER_GRID", "choose_filter", "clip_rows", "clip_scores", "room_poses", "sequence_block",
           "sequence_block_problem", "tracked"]

#: the 1-euro settings :func:`choose_filter` tries: cut-off at rest (Hz) and its rise with speed (Hz per m/s of a
#: keypoint; a probe moves at 0.01-0.03 m/s, a head-worn camera's view of it faster)
FILTER_GRID = {"min_cutoff_hz": (0.25, 0.5, 1.0, 2.0, 4.0, 8.0), "beta": (0.0, 1.0, 3.0, 10.0, 30.0, 100.0)}
#: the annotations the metrics read
#: the MPJPEs the chosen filter may not raise on the tuning split (:func:`choose_filter`)
KEPT = ("mpjpe_all_mm", "mpjpe_hand_mm", "mpjpe_probe_mm")
FIELDS = ("clip_id", "frame_in_clip", "time_s", "grasp_id", "T_cam_world", "T_world_body")
#: the per-clip metrics, in results order (:func:`clip_scores`)
SCORES = ("mpjpe_all_mm", "mpjpe_hand_mm", "mpjpe_probe_mm", "acceleration_error_mm_per_frame2", "jitter_mm_per_s3",
          *(f"probe_{key}_error" for key in KINEMATICS_KEYS), *(f"probe_room_{key}_error" for key in KINEMATICS_KEYS))


def room_poses(fields: dict) -> np.ndarray:
    """(N, 4, 4) each frame's camera in the room (the patient's body frame): ``inv(T_world_body) inv(T_cam_world)``,
    what a headset's head tracking reports."""
    return invert_transform(fields["T_world_body"]) @ invert_transform(fields["T_cam_world"])


def clip_rows(fields: dict) -> list[np.ndarray]:
    """The row indices of each clip of a split, in time order (``frame_in_clip``), clips by increasing id.

    Args:
        fields: the split's annotations with "clip_id" and "frame_in_clip" (rows in frame order).
    """
    out = []
    for clip in np.unique(fields["clip_id"]):
        rows = np.flatnonzero(fields["clip_id"] == clip)
        out.append(rows[np.argsort(fields["frame_in_clip"][rows], kind="stable")])
    return out


def tracked(points: np.ndarray, fields: dict, clips: list[np.ndarray], settings: dict | None) -> np.ndarray:
    """(N, ...) float64: each clip's ``points`` through a fresh :class:`OneEuroFilter` of ``settings`` in time order
    (``fields["time_s"]``); ``settings`` None: the points unchanged."""
    out = np.asarray(points, np.float64).copy()
    if settings is None:
        return out
    for rows in clips:
        smoother = OneEuroFilter(**settings)
        for i in rows:
            out[i] = smoother(points[i], float(fields["time_s"][i]))
    return out


def clip_scores(pred3d: np.ndarray, gt3d: np.ndarray, clips: list[np.ndarray], fps: float,
                T_room_cam: np.ndarray) -> dict[str, np.ndarray]:
    """Each clip's metrics (:data:`SCORES`, and ``truth_jitter_mm_per_s3`` and ``truth_probe_[room_]<kinematics>``),
    (C,) float64 each, from predicted and true camera-frame keypoints; ``T_room_cam`` (N, 4, 4) each frame's camera
    in the room."""
    keys = SCORES + ("truth_jitter_mm_per_s3",) + tuple(f"truth_probe_{frame}{k}" for frame in ("", "room_")
                                                         for k in KINEMATICS_KEYS)
    out = {key: [] for key in keys}
    for rows in clips:
        pred, gt = pred3d[rows], gt3d[rows]
        error = 1e3 * np.linalg.norm(pred - gt, axis=-1)  # (F, 29) mm
        out["mpjpe_all_mm"].append(error.mean())
        out["mpjpe_hand_mm"].append(error[:, :kp.NUM_HAND].mean())
        out["mpjpe_probe_mm"].append(error[:, kp.NUM_HAND:].mean())
        out["acceleration_error_mm_per_frame2"].append(acceleration_error_mm_per_frame2(pred, gt))
        out["jitter_mm_per_s3"].append(jitter_mm_per_s3(pred, fps))
        out["truth_jitter_mm_per_s3"].append(jitter_mm_per_s3(gt, fps))
        centres = [points[:, kp.NUM_HAND:].mean(axis=1) for points in (pred, gt)]  # (F, 3) each, camera frame
        for frame, (predicted, true) in (("", centres), ("room_", [transform_points(T_room_cam[rows], c[:, None])[:, 0]
                                                                   for c in centres])):
            predicted, true = point_kinematics(predicted, fps), point_kinematics(true, fps)
            for key in KINEMATICS_KEYS:
                out[f"probe_{frame}{key}_error"].append(abs(predicted[key] - true[key]))
                out[f"truth_probe_{frame}{key}"].append(true[key])
    return {key: np.asarray(values, np.float64) for key, values in out.items()}


def choose_filter(pred3d: np.ndarray, gt3d: np.ndarray, fields: dict, fps: float,
                  tracked3d: np.ndarray | None = None) -> dict:
    """The 1-euro settings of :data:`FILTER_GRID` with the lowest mean acceleration error over the clips among those
    whose mean MPJPE (all, hand and probe, each: :data:`KEPT`) is not above the untracked prediction's; call it on the
    validation split. The filter runs
    on ``tracked3d`` (the prediction with the fits tracking each clip, :class:`hupbench.evaluation.prediction.
    SplitPrediction`) where given, else on ``pred3d``.

    Returns:
        {"settings": {"min_cutoff_hz", "beta"} or None (no setting kept the MPJPE: no filter), "untracked":
        {each of :data:`KEPT`, "acceleration_error_mm_per_frame2"}, "tried": [{"min_cutoff_hz", "beta", the same
        scores}, ...]}, all means over the split's clips.
    """
    clips, T_room_cam = clip_rows(fields), room_poses(fields)

    def score(points: np.ndarray) -> dict:
        scores = clip_scores(points, gt3d, clips, fps, T_room_cam)
        return {key: float(scores[key].mean()) for key in (*KEPT, "acceleration_error_mm_per_frame2")}

    untracked = score(pred3d)
    filtered = pred3d if tracked3d is None else tracked3d
    tried = []
    for cutoff in FILTER_GRID["min_cutoff_hz"]:
        for beta in FILTER_GRID["beta"]:
            settings = {"min_cutoff_hz": cutoff, "beta": beta}
            tried.append(settings | score(tracked(filtered, fields, clips, settings)))
    kept = [t for t in tried if all(t[key] <= untracked[key] for key in KEPT)]
    best = min(kept, key=lambda t: t["acceleration_error_mm_per_frame2"], default=None)
    settings = None if best is None else {"min_cutoff_hz": best["min_cutoff_hz"], "beta": best["beta"]}
    return {"settings": settings, "untracked": untracked, "tried": tried}


def sequence_block(pred3d: np.ndarray, gt3d: np.ndarray, fields: dict, fps: float, choice: dict, chosen_on: str,
                   resamples: int, seed: int, tracked3d: np.ndarray | None = None,
                   tracked_fits_ms: float | None = None, fit_settings: tuple | None = None) -> dict:
    """The ``sequence`` block of a results file.

    Args:
        pred3d, gt3d: (N, 29, 3) metres, the split's per-frame predictions and labels.
        fields: the split's annotations (:data:`FIELDS`).
        fps: the clips' frame rate. choice: :func:`choose_filter`'s answer. chosen_on: the split it was made on.
        resamples, seed: the bootstrap's.
        tracked3d: the predictions with the fits tracking each clip (:func:`hupbench.fits.track_fits`), which the
            filter then smooths; None: the model has no fits, the filter smooths ``pred3d``.
        tracked_fits_ms: the tracked fits' median time per frame, ms (with ``tracked3d``).
        fit_settings: the model's (probe, hand) fit settings (:func:`hupbench.fits.model_fit_settings`; None: the
            defaults), whose tracking steps the block records.

    Returns:
        {"fps", "clips", "frames_per_clip", "filter": {"name", "settings", "chosen_on", "grid", "criterion"},
        "untracked", "tracked", "truth": {metric: mean over clips}, "intervals": {"method", "confidence",
        "resamples", "seed", "grasps", "untracked", "tracked", "tracked_minus_untracked": {metric: [low, high]}},
        "filter_ms_per_frame": the filter's own time per frame, "tracked_fits": None (a model without fits) or
        {"probe_tracking_iterations", "hand_tracking_iterations", "ms_per_frame"}}.
    """
    probe_fit, hand_fit = fit_settings or (ProbeFitSettings(), HandFitSettings())
    clips = clip_rows(fields)
    settings = choice["settings"]
    start = time.perf_counter()
    smoothed = tracked(pred3d if tracked3d is None else tracked3d, fields, clips, settings)
    filter_ms = 1e3 * (time.perf_counter() - start) / len(pred3d)
    T_room_cam = room_poses(fields)
    untracked = clip_scores(pred3d, gt3d, clips, fps, T_room_cam)
    tracked_scores = clip_scores(smoothed, gt3d, clips, fps, T_room_cam)
    grasp_of_clip = np.array([int(fields["grasp_id"][rows[0]]) for rows in clips])
    grasps = np.unique(grasp_of_clip)
    frames = np.array([sum(len(clips[c]) for c in np.flatnonzero(grasp_of_clip == g)) for g in grasps], np.int64)

    def interval(values: np.ndarray) -> list[float]:
        per_grasp = np.array([values[grasp_of_clip == g].mean() for g in grasps])
        found = grasp_interval_of_grasps(per_grasp, frames, resamples, seed)
        return [found["low"], found["high"]]

    def means(scores: dict, keys) -> dict:
        return {key: float(scores[key].mean()) for key in keys}

    truth_keys = [k for k in untracked if k.startswith("truth_")]
    return {
        "fps": float(fps), "clips": len(clips), "frames_per_clip": int(max(len(r) for r in clips)),
        "filter": {"name": "1-euro (hupbench.inference.tracking.OneEuroFilter)", "settings": settings,
                   "chosen_on": chosen_on, "grid": {k: list(v) for k, v in FILTER_GRID.items()},
                   "criterion": "lowest acceleration error among the settings whose MPJPE (all, hand and probe, "
                                "each) is not above the untracked prediction's"},
        "untracked": means(untracked, SCORES), "tracked": means(tracked_scores, SCORES),
        "truth": {key[len("truth_"):]: float(untracked[key].mean()) for key in truth_keys},
        "intervals": {"method": METHOD + " (a grasp's value the mean of its clips)", "confidence": CONFIDENCE,
                      "resamples": int(resamples), "seed": int(seed), "grasps": len(grasps),
                      "untracked": {key: interval(untracked[key]) for key in SCORES},
                      "tracked": {key: interval(tracked_scores[key]) for key in SCORES},
                      "tracked_minus_untracked": {key: interval(tracked_scores[key] - untracked[key])
                                                  for key in SCORES}},
        "filter_ms_per_frame": float(filter_ms),
        "tracked_fits": None if tracked3d is None or tracked_fits_ms is None else {
            "probe_tracking_iterations": probe_fit.tracking_iterations,
            "hand_tracking_iterations": hand_fit.tracking_iterations, "ms_per_frame": float(tracked_fits_ms)},
    }


def sequence_block_problem(block) -> str | None:
    """The first field of a results file's ``sequence`` block (:func:`sequence_block`) that is missing, unknown or
    malformed, as ``['key']...: what it must be, got ...``; None when the block is well formed."""
    def number(v):
        return is_number(v) and v >= 0

    def count(v):
        return is_whole(v) and v >= 1

    def interval(v):
        return isinstance(v, list) and len(v) == 2 and all(is_number(x) for x in v) and v[0] <= v[1]

    def settings(v):
        return v is None or (isinstance(v, dict) and set(v) == {"min_cutoff_hz", "beta"}
                             and all(number(x) for x in v.values()))

    def text(v):
        return isinstance(v, str)

    def tracked_fits(v):
        return v is None or (isinstance(v, dict) and set(v) == {"probe_tracking_iterations", "hand_tracking_iterations",
                                                                "ms_per_frame"}
                             and count(v["probe_tracking_iterations"]) and count(v["hand_tracking_iterations"])
                             and number(v["ms_per_frame"]))

    scores = dict.fromkeys(SCORES, (number, "a number >= 0"))
    spans = dict.fromkeys(SCORES, (interval, "[low, high] numbers, low <= high"))
    shape = {"fps": (number, "a number >= 0"), "clips": (count, "a count >= 1"),
             "frames_per_clip": (count, "a count >= 1"), "filter_ms_per_frame": (number, "a number >= 0"),
             "tracked_fits": (tracked_fits, "null or {probe_tracking_iterations, hand_tracking_iterations, "
                                            "ms_per_frame}"),
             "filter": {"name": (text, "a string"), "settings": (settings, "null or {min_cutoff_hz, beta} >= 0"),
                        "chosen_on": (text, "a string"), "grid": (lambda v: isinstance(v, dict), "a dict"),
                        "criterion": (text, "a string")},
             "untracked": scores, "tracked": scores, "truth": (lambda v: isinstance(v, dict), "a dict"),
             "intervals": {"method": (text, "a string"), "confidence": (number, "a number >= 0"),
                           "resamples": (count, "a count >= 1"), "seed": (is_whole, "an integer"),
                           "grasps": (count, "a count >= 1"), "untracked": spans, "tracked": spans,
                           "tracked_minus_untracked": spans}}

    def walk(value, expected, path: str) -> str | None:
        if isinstance(expected, dict):
            if not isinstance(value, dict) or set(value) != set(expected):
                got = sorted(value) if isinstance(value, dict) else repr(value)[:80]
                return f"{path}: must have the keys {sorted(expected)}, got {got}"
            return next((p for k, e in expected.items() if (p := walk(value[k], e, f"{path}['{k}']")) is not None),
                        None)
        ok, what = expected
        return None if ok(value) else f"{path}: must be {what}, got {repr(value)[:80]}"

    return walk(block, shape, "")
