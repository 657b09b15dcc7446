"""The checks of :mod:`hupbench.datagen.dataset.verify` on a dataset of clips (a clinic dataset whose manifest has a
"sequence" record: ``hupbench generate +track=clinic_sequences``): each clip whole, in order and in time, and its
labels continuous to its own kinematic bounds.

``clip_continuity`` is reported once per failing clip, naming its first failing frame, when

* the manifest's ``sequence.clips`` has no record of a clip the annotations hold, or the record's grasp, room
  (``background_id``), glove or split are not the frames';
* the clip's frames are not ``frames_per_clip`` consecutive frame ids with ``frame_in_clip`` 0, 1, ... and
  ``time_s = frame_in_clip / fps``, of one grasp, room, glove and start camera (``view_id``);
* the probe's centre (the mean of keypoints 21-28), taken from the camera-frame labels back to the patient's body
  frame through the frame's ``T_cam_world`` and ``T_world_body``, steps, accelerates or jerks between frames more
  than the clip's ``bounds`` allow (its finite differences at the frame rate against the maxima of the oversampled
  motion's: an n-th difference over a frame is a weighted mean of the oversampled ones, so at most their maximum),
  with the slack of the labels' float32 rounding;
* the camera moves or turns relative to the patient's room between frames faster than the clip's ``head_bounds``;
* a hand keypoint, taken back to the world (probe) frame, moves between frames faster than the clip's
  ``fingers.keypoint_speed_mm_per_s`` (0 for a record without ``fingers``: a hand that holds its grasp), or the
  record's ``fingers.adjustments`` are not adjustments
  (:func:`hupbench.datagen.dataset.finger_motion.clip_adjustments`).

Each frame's ``hand_pose`` is the grasp's with the clip's adjustments
(:func:`hupbench.datagen.dataset.finger_motion.finger_poses`):
:func:`hupbench.datagen.dataset.finger_motion.expected_hand_poses`, which
:func:`hupbench.datagen.dataset.verify_annotations.check_grasps_file` holds the frames to.

The contact (the lens on the skin in every frame, nothing of the hand or forearm in the body) is
:func:`hupbench.datagen.dataset.verify_clinic.check_lens_skin`'s, at each frame's body pose.

Convention:
    Metres and seconds in the annotations, mm/s^n and degrees/s in the records; world = probe frame.
"""

from __future__ import annotations

import numpy as np

from hupbench.core import keypoints as kp
from hupbench.core.contract import ANNOTATIONS, MANIFEST, SEQUENCE
from hupbench.core.geometry import invert_transform, transform_points
from hupbench.core.input_checks import is_number
from hupbench.core.motion_metrics import KINEMATICS_KEYS, time_derivatives
from hupbench.datagen.dataset.clips import hand_steps, head_steps
from hupbench.datagen.dataset.finger_motion import FINGERS, clip_adjustments
from hupbench.datagen.dataset.verify_frames import _problem

#: a clip's time stamps are frame_in_clip / fps to this, seconds
TIME_S = 1e-9
#: relative slack on a bound: the bounds and the frames' differences are computed in float64 along different paths
BOUND_RTOL = 1e-6
#: the head's bounds a clip's record holds (:func:`hupbench.datagen.dataset.clips.clip_record`)
HEAD_KEYS = ("speed_mm_per_s", "turn_deg_per_s")
#: the annotations that stay the same over a clip, and the record's name for them
_CONSTANT = {"grasp_index": "grasp_index", "background_id": "background_id", "glove_id": "glove_id", "view_id": None}


def check_clips(ann: dict, split: str, manifest: dict) -> list[dict]:
    """The ``clip_continuity`` problems of one split's annotations (every array of a dataset of clips, rows in
    frame order) against the manifest's "sequence" record."""
    record = manifest[SEQUENCE]
    fps, frames = float(record["fps"]), int(record["frames_per_clip"])
    clips = {c.get("clip_id"): c for c in record.get("clips", []) if isinstance(c, dict)}
    where = f"{split}/{ANNOTATIONS}"
    problems = []
    for clip_id in np.unique(ann["clip_id"]).tolist():
        rows = np.flatnonzero(ann["clip_id"] == clip_id)
        why = _order_problem(ann, rows, clips.get(clip_id), split, fps, frames)
        if why is None:
            why = _motion_problem(ann, rows, clips[clip_id], fps)
        if why is not None:
            frame, what = why
            problems.append(_problem(split, frame, "clip_continuity", f"clip {clip_id}: {what}",
                                     MANIFEST if what.startswith("the manifest") else where))
    return problems


def _order_problem(ann: dict, rows: np.ndarray, record: dict | None, split: str, fps: float, frames: int
                   ) -> tuple[int, str] | None:
    """(first frame id, what) when a clip's frames are not whole, in order and in time, or disagree with its record."""
    ids = ann["frame_id"][rows]
    first = int(ids[0])
    if record is None:
        return first, f"the manifest's {SEQUENCE}.clips has no record of it"
    for key, name in _CONSTANT.items():
        values = np.unique(ann[key][rows])
        if len(values) != 1:
            return first, f"its frames have {len(values)} values of {key}, {values[:4].tolist()}: a clip has one"
        if name is not None and record.get(name) != int(values[0]):
            return first, (f"the manifest's record gives {name} {record.get(name)!r}, its frames "
                           f"{int(values[0])}")
    if record.get("split") != split:
        return first, f"the manifest's record puts it in {record.get('split')!r}, its frames are in {split}"
    order = ann["frame_in_clip"][rows]
    if len(rows) != frames or not (order == np.arange(frames)).all() or not (ids == first + np.arange(frames)).all():
        bad = np.flatnonzero((order != np.arange(len(rows))) | (ids != first + np.arange(len(rows))))
        at = int(ids[bad[0]]) if len(bad) else int(ids[-1])
        return at, (f"{len(rows)} frames (the clips have {frames}), frame_in_clip and frame ids not consecutive "
                    "from 0 and its first id")
    off = np.abs(ann["time_s"][rows] - order / fps)
    if not (off <= TIME_S).all():
        i = int(np.argmax(~(off <= TIME_S)))
        return int(ids[i]), (f"time_s {ann['time_s'][rows[i]]!r} at frame_in_clip {int(order[i])}, expected "
                             f"{order[i] / fps!r} at {fps:g} frames/s")
    return None


def _motion_problem(ann: dict, rows: np.ndarray, record: dict, fps: float) -> tuple[int, str] | None:
    """(frame id, what) when the probe's centre or the head moves between a clip's frames beyond its bounds."""
    ids = ann["frame_id"][rows]
    bounds, head = record.get("bounds"), record.get("head_bounds")
    for name, values, keys in (("bounds", bounds, KINEMATICS_KEYS), ("head_bounds", head, HEAD_KEYS)):
        if not isinstance(values, dict) or not all(is_number(values.get(k)) for k in keys):
            return int(ids[0]), f"the manifest's record has no {name} {list(keys)} (numbers), got {values!r}"
    keypoints = ann["keypoints_3d_cam"][rows].astype(np.float64)  # (F, 29, 3)
    T_body_cam = invert_transform(ann["T_world_body"][rows]) @ invert_transform(ann["T_cam_world"][rows])
    centre = transform_points(T_body_cam, keypoints[:, kp.NUM_HAND:]).mean(axis=1)  # (F, 3) body frame
    # a stored coordinate is within half a float32 ulp: the centre within eps * the farthest label, and an n-th
    # difference within 2^n times that
    rounding = float(np.finfo(np.float32).eps) * float(np.abs(keypoints).max())
    for n, (key, derivative) in enumerate(zip(KINEMATICS_KEYS, time_derivatives(centre, fps)), start=1):
        size = 1e3 * np.linalg.norm(derivative, axis=1)
        bound = bounds[key]
        allowed = bound * (1 + BOUND_RTOL) + 1e3 * 2 ** n * rounding * fps ** n
        if not (size <= allowed).all():
            i = int(np.argmax(~(size <= allowed)))
            return int(ids[i + n]), (f"the probe's centre's {key.split('_')[0]} {size[i]:.3f} "
                                     f"{key.split('_', 1)[1].replace('_', ' ')} between frames "
                                     f"{int(ids[i]):06d}-{int(ids[i + n]):06d} exceeds the clip's bound "
                                     f"{bound!r} (a label jump)")
    if clip_adjustments(record) is None:
        return int(ids[0]), (f"the manifest's record's fingers are not {{'adjustments': [...], "
                             f"'keypoint_speed_mm_per_s': number}} with each adjustment's fingers among {FINGERS}, "
                             f"numbers start_s, move_s > 0, hold_s >= 0 and an open_deg triple per finger, got "
                             f"{record.get('fingers')!r}")
    fingers = record.get("fingers")
    bound = 0.0 if fingers is None else fingers["keypoint_speed_mm_per_s"]
    hand_world = transform_points(invert_transform(ann["T_cam_world"][rows]), keypoints[:, kp.HAND_SLICE])
    speed = hand_steps(hand_world, fps)
    allowed = bound * (1 + BOUND_RTOL) + 1e3 * 2 * rounding * fps
    if not (speed <= allowed).all():
        i = int(np.argmax(~(speed <= allowed)))
        return int(ids[i + 1]), (f"a hand keypoint moves {speed[i]:.3f} mm/s relative to the probe between frames "
                                 f"{int(ids[i]):06d}-{int(ids[i + 1]):06d}, beyond the clip's fingers' bound "
                                 f"{bound!r} (a label jump)")
    for key, values in zip(HEAD_KEYS, head_steps(ann["T_cam_world"][rows], ann["T_world_body"][rows], fps)):
        bound = head[key]
        allowed = bound * (1 + BOUND_RTOL) + 1e-9
        if not (values <= allowed).all():
            i = int(np.argmax(~(values <= allowed)))
            return int(ids[i + 1]), (f"the head's {key.split('_')[0]} {values[i]:.3f} "
                                     f"{key.split('_', 1)[1].replace('_', ' ')} between frames "
                                     f"{int(ids[i]):06d}-{int(ids[i + 1]):06d} exceeds the clip's bound {bound!r}")
    return None

