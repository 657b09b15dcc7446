"""The fingers adjusting between grasp poses over a clip of a scan.

A sonographer's grip is not frozen over a sweep: fingers loosen on the probe and close on it again as the probe
is swept, rocked and fanned. :func:`finger_motion` makes one clip of that for a grasp:

1. **When.** Adjustments follow one another at a mean rate of ``rate_hz`` (exponential gaps from the clip's start
   or the last adjustment's end); each lasts its opening move, its hold and its closing move (``move_s``,
   ``hold_s``, drawn uniformly). One that would not end before the clip does is not made.
2. **Which fingers, how far.** Each adjustment loosens 1 to ``max_fingers`` of the four fingers; the thumb stays
   on the probe, and with the fingers left it holds it. Every joint of a loosened finger (MCP, PIP, DIP) extends
   by an angle drawn uniformly in ``open_deg``, never past its extension limit
   (:func:`hupbench.datagen.assets.hand_anatomy.joint_limits_rad`).
3. **How.** The flexion follows a minimum-jerk profile (Flash and Hogan 1985, the smooth point-to-point move of
   the human arm and hand) out and back: the hand moves between two grasp poses, the grasp's and the loosened
   one, with the joints' angle, speed and acceleration continuous; abduction and twist keep the grasp's. A frame
   outside every adjustment holds the grasp's pose exactly.
4. **Kept clear.** An adjustment that in one of its frames sinks a hand vertex deeper into the probe than the
   grasp's own pose does (by more than :data:`PROBE_SLACK_M`), or into the patient's body or below the bed's top
   by more than :data:`hupbench.datagen.assets.patient.MAX_PENETRATION_M`, is drawn again (:data:`DRAWS` times,
   then not made).

The adjustments are the clip's record: :func:`finger_poses` rebuilds every frame's pose from the grasp's pose and
that record, which is how ``hupbench verify`` checks each frame's ``hand_pose``.

Convention:
    Seconds and metres; angles in degrees in the record and the spec, radians in poses. World = the grasp's probe
    frame; ``T_world_body`` as in :mod:`hupbench.datagen.assets.patient`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hupbench.core import keypoints as kp
from hupbench.core.contract import SEQUENCE
from hupbench.core.input_checks import check_int, check_interval, check_number, is_number
from hupbench.datagen.assets.hand_anatomy import anatomical_to_pose, joint_limits_rad, pose_to_anatomical
from hupbench.datagen.assets.patient import MAX_PENETRATION_M, below_skin

__all__ = ["DRAWS", "FINGERS", "FingerMotionSpec", "clip_adjustments", "expected_hand_poses", "finger_motion",
           "finger_poses", "min_jerk"]

#: the fingers an adjustment may loosen (the thumb holds the probe), in MANO order
FINGERS = tuple(name for name in kp.MANO_FINGER_ORDER if name != "thumb")
#: each finger's first row among the 15 joints of an anatomical pose (its MCP, then PIP and DIP)
_FINGER_ROWS = {name: 3 * i for i, name in enumerate(kp.MANO_FINGER_ORDER)}
#: draws of one adjustment before it is not made
DRAWS = 10
#: how much deeper than the grasp's own pose a loosening finger may reach into the probe, metres: the probe's
#: signed distance is interpolated on a grid, off by a few tenths of a millimetre near its surface
PROBE_SLACK_M = 0.0005


@dataclass(frozen=True)
class FingerMotionSpec:
    """How the fingers adjust over a clip (config node ``dataset.fingers``).

    Attributes:
        rate_hz: mean adjustments per second, >= 0 (0: the hand holds its grasp throughout).
        open_deg: (min, max) degrees each joint of a loosened finger extends by, drawn uniformly.
        move_s: (min, max) seconds of the opening and of the closing move, drawn uniformly (one for both).
        hold_s: (min, max) seconds the loosened pose is held.
        max_fingers: 1-4, the most fingers one adjustment loosens (the number drawn uniformly from 1).
    """

    rate_hz: float = 0.5
    open_deg: tuple = (5.0, 20.0)
    move_s: tuple = (0.3, 0.8)
    hold_s: tuple = (0.2, 1.0)
    max_fingers: int = 2

    def __post_init__(self) -> None:
        object.__setattr__(self, "rate_hz", check_number(self.rate_hz, "dataset.fingers.rate_hz", 0.0, 10.0))
        object.__setattr__(self, "open_deg", check_interval(self.open_deg, "dataset.fingers.open_deg", 0.0, 60.0,
                                                            unit="deg"))
        object.__setattr__(self, "move_s", check_interval(self.move_s, "dataset.fingers.move_s", 0.05, 10.0, unit="s"))
        object.__setattr__(self, "hold_s", check_interval(self.hold_s, "dataset.fingers.hold_s", 0.0, 60.0, unit="s"))
        check_int(self.max_fingers, "dataset.fingers.max_fingers", 1, len(FINGERS))


def min_jerk(s: np.ndarray) -> np.ndarray:
    """The minimum-jerk profile from 0 to 1 over ``s`` in [0, 1] (clipped outside): 10 s^3 - 15 s^4 + 6 s^5, its
    first and second derivatives 0 at both ends."""
    s = np.clip(s, 0.0, 1.0)
    return s ** 3 * (10.0 + s * (-15.0 + 6.0 * s))


def _opening(adjustment: dict, time_s: np.ndarray) -> np.ndarray:
    """(F,) in [0, 1]: how far one adjustment has loosened its fingers at each time (exactly 0 at and outside its
    start and end)."""
    start, move, hold = adjustment["start_s"], adjustment["move_s"], adjustment["hold_s"]
    opening = min_jerk((time_s - start) / move) - min_jerk((time_s - start - move - hold) / move)
    return np.where((time_s > start) & (time_s < start + 2 * move + hold), opening, 0.0)


def finger_poses(grasp_pose: np.ndarray, adjustments: list[dict], time_s: np.ndarray) -> np.ndarray:
    """Each frame's hand pose of a clip whose fingers adjust as ``adjustments`` record.

    Args:
        grasp_pose: (48,) float64 axis-angle, the grasp's pose (``hupbench.datagen.assets.hand`` Convention).
        adjustments: the clip's adjustments, each {"fingers": names of :data:`FINGERS`, "start_s", "move_s",
            "hold_s": seconds, "open_deg": per finger its (MCP, PIP, DIP) extension, degrees}, as
            :func:`finger_motion` records them.
        time_s: (F,) float64, the frames' times from the clip's start, seconds.

    Returns:
        (F, 48) float64: the grasp's pose where no adjustment acts, else the grasp's with the loosened fingers'
        flexion lowered.
    """
    time_s = np.asarray(time_s, dtype=np.float64)
    flexion = np.zeros((len(time_s), 15))  # (F, 15) radians the joints extend by
    for adjustment in adjustments:
        opening = _opening(adjustment, time_s)
        for name, open_deg in zip(adjustment["fingers"], adjustment["open_deg"]):
            row = _FINGER_ROWS[name]
            flexion[:, row:row + 3] += opening[:, None] * np.deg2rad(np.asarray(open_deg, dtype=np.float64))
    poses = np.repeat(np.asarray(grasp_pose, dtype=np.float64)[None], len(time_s), axis=0)
    moving = np.flatnonzero((flexion != 0.0).any(axis=1))
    if len(moving):
        angles = np.repeat(pose_to_anatomical(grasp_pose)[None], len(moving), axis=0)
        angles[..., 0] -= flexion[moving]
        poses[moving] = anatomical_to_pose(angles, grasp_pose[:3])
    return poses


def finger_motion(spec: FingerMotionSpec, grasp_pose: np.ndarray, hand_vertices, probe, radius_m: float,
                  T_body_world: np.ndarray, time_s: np.ndarray, rng: np.random.Generator) -> list[dict]:
    """The adjustments of one clip's fingers (the module's steps 1-4).

    Args:
        spec: how the fingers adjust.
        grasp_pose: (48,) float64, the grasp's pose.
        hand_vertices: callable (B, 48) poses -> (B, V, 3) float64 hand vertices, metres, world frame, as the renderer
            builds the grasp's hand.
        probe: the :class:`hupbench.datagen.assets.probe.Probe` held (world = its frame).
        radius_m: the patient's abdomen radius. T_body_world: (F, 4, 4) float64, the body frame in each frame.
        time_s: (F,) float64 the frames' times, seconds. rng: the clip's seeded generator of the fingers.

    Returns:
        The adjustments (:func:`finger_poses`' records), in time order, none overlapping.
    """
    grasp_pose = np.asarray(grasp_pose, dtype=np.float64)
    flexion0 = pose_to_anatomical(grasp_pose)[:, 0]
    extend_limit = flexion0 - joint_limits_rad()[:, 0, 0]  # (15,) radians each joint can extend before its limit
    own_depth = float(-probe.signed_distance(hand_vertices(grasp_pose[None])[0]).min())
    end_s = float(time_s[-1])
    adjustments, start = [], 0.0
    while spec.rate_hz > 0:
        start += float(rng.exponential(1.0 / spec.rate_hz))
        move, hold = float(rng.uniform(*spec.move_s)), float(rng.uniform(*spec.hold_s))
        if start + 2 * move + hold > end_s:
            break
        for _ in range(DRAWS):
            count = int(rng.integers(1, spec.max_fingers + 1))
            fingers = [FINGERS[i] for i in sorted(rng.choice(len(FINGERS), count, replace=False))]
            open_deg = [[float(min(a, np.degrees(max(0.0, limit)))) for a, limit in
                         zip(rng.uniform(*spec.open_deg, size=3), extend_limit[_FINGER_ROWS[name]:][:3])]
                        for name in fingers]
            adjustment = {"fingers": fingers, "start_s": start, "move_s": move, "hold_s": hold, "open_deg": open_deg}
            frames = np.flatnonzero(_opening(adjustment, time_s) > 0.0)
            if _clear(finger_poses(grasp_pose, [adjustment], time_s[frames]), frames, hand_vertices, probe,
                      own_depth, radius_m, T_body_world):
                adjustments.append(adjustment)
                break
        start += 2 * move + hold
    return adjustments


def _clear(poses: np.ndarray, frames: np.ndarray, hand_vertices, probe, own_depth: float, radius_m: float,
           T_body_world: np.ndarray) -> bool:
    """Whether the hand at ``poses`` (those of ``frames``) stays out of the probe (as deep as the grasp's own pose,
    ``own_depth``, plus :data:`PROBE_SLACK_M`) and out of the body and the bed (``MAX_PENETRATION_M``)."""
    if not len(frames):
        return True
    vertices = hand_vertices(poses)  # (B, V, 3) world
    if -probe.signed_distance(vertices).min() > max(own_depth, 0.0) + PROBE_SLACK_M:
        return False
    T = T_body_world[frames]
    body = np.einsum("fij,fvj->fvi", T[:, :3, :3], vertices) + T[:, None, :3, 3]
    return bool(below_skin(radius_m, body).max() <= MAX_PENETRATION_M)


def clip_adjustments(record: dict) -> list[dict] | None:
    """A clip record's finger adjustments (:func:`hupbench.datagen.dataset.finger_motion.finger_motion`'s): [] for a
    record without ``fingers`` (a dataset whose hands hold their grasps), None when ``fingers`` is there but not
    adjustments and a number ``keypoint_speed_mm_per_s``."""
    fingers = record.get("fingers")
    if fingers is None:
        return []
    if not isinstance(fingers, dict) or not is_number(fingers.get("keypoint_speed_mm_per_s")) \
            or not isinstance(fingers.get("adjustments"), list):
        return None
    for adjustment in fingers["adjustments"]:
        if not isinstance(adjustment, dict) or not all(is_number(adjustment.get(k)) for k in
                                                       ("start_s", "move_s", "hold_s")):
            return None
        names, opens = adjustment.get("fingers"), adjustment.get("open_deg")
        if not (adjustment["move_s"] > 0 and adjustment["hold_s"] >= 0 and isinstance(names, list)
                and isinstance(opens, list) and len(names) == len(opens) and all(n in FINGERS for n in names)
                and all(isinstance(o, list) and len(o) == 3 and all(map(is_number, o)) for o in opens)):
            return None
    return fingers["adjustments"]


def expected_hand_poses(grasp_poses: np.ndarray, ann: dict, manifest: dict) -> np.ndarray:
    """(N,) rows' hand poses on a dataset of clips: each the pose of its grasp (``grasp_poses[grasp_index]``, the
    grasps file's) with its clip's adjustments at its ``time_s``; a row whose grasp index is outside the file or
    whose clip has no valid record keeps its own (``hupbench verify``'s ``clip_continuity`` and ``grasps_file`` report those).

    Args:
        grasp_poses: (G, 48) float64, the grasps file's hand poses. ann: a split's annotations. manifest: the
            dataset's (its "sequence" record).

    Returns:
        (N, 48) float64.
    """
    expected = np.array(ann["hand_pose"], dtype=np.float64, copy=True)
    clips = {c.get("clip_id"): c for c in manifest[SEQUENCE].get("clips", []) if isinstance(c, dict)}
    for clip_id in np.unique(ann["clip_id"]).tolist():
        rows = np.flatnonzero(ann["clip_id"] == clip_id)
        grasp = np.unique(ann["grasp_index"][rows])
        adjustments = clip_adjustments(clips[clip_id]) if clip_id in clips else None
        if adjustments is None or len(grasp) != 1 or not 0 <= grasp[0] < len(grasp_poses):
            continue
        expected[rows] = finger_poses(grasp_poses[grasp[0]], adjustments, ann["time_s"][rows])
    return expected
