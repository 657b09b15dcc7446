"""The clinic track's checks of :mod:`hupbench.datagen.dataset.verify`: what the track promises of its world.

On the clinic track (:mod:`hupbench.datagen.dataset.clinic`) every grasp has its own subject's hand and its own
patient placement, both read from the dataset's ``grasps.npz`` (``subject_*`` / ``hand_*_mm`` and ``patient_*``
arrays), and its cameras are a sonographer's head's (:mod:`hupbench.datagen.dataset.head`). verify checks here:

* ``lens_skin``: per grasp, the probe's lens rests on the skin (its deepest vertex at most
  :data:`LENS_ABOVE_SKIN_M` above it), no probe vertex deeper than
  :data:`hupbench.datagen.assets.patient.PROBE_MAX_DEPTH_M`, and no vertex of the hand or forearm, built as the
  renderer builds them for the grasp's hand, more than :data:`BODY_PENETRATION_M` inside the body or below the
  bed's top; reported once per failing grasp with its frames;
* ``camera_in_patient``: each camera centre (from ``T_cam_world``) outside the body and above the bed plane;
* ``hand_size``: each frame's ``hand_length_mm`` / ``hand_breadth_mm`` are its grasp's subject's;
* ``look_at``: keypoint 9 (the manifest's ``protocol.look_at``) projects at the frame's ``aim_px`` and lies
  ``z_ego`` from the camera centre (the head turned the target off the optical axis);
and, per frame with the images (:mod:`hupbench.datagen.dataset.verify_frames`), ``patient_depth`` (pixels the mask
calls patient, unprojected with their depth, lie on the body's surface) and ``mask_depth`` (every pixel has depth:
the room and the patient stand behind everything).

Convention:
    World = probe frame, metres; ``T_cam_world`` in OpenCV axes; signed distances negative inside the body
    (:func:`hupbench.datagen.assets.patient.body_sdf`); the bed's top is the body frame's z = 0.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hupbench.core import keypoints as kp
from hupbench.core import tolerances as tol
from hupbench.core.camera import project_points
from hupbench.core.contract import ANNOTATIONS
from hupbench.core.geometry import invert_transform
from hupbench.datagen.assets.patient import (PROBE_MAX_DEPTH_M, PatientPlacement, below_skin, body_sdf,
                                             moved_placement)
from hupbench.datagen.dataset.verify_frames import _problem

#: the lens's deepest vertex lies at most this far above the skin: it rests on it, metres
LENS_ABOVE_SKIN_M = 0.001
#: no hand or forearm vertex lies deeper than this inside the body (or below the bed's top), metres
BODY_PENETRATION_M = 0.003
#: a frame's subject measures and its grasp's subject's are copies of one float64: they agree to this, mm
HAND_SIZE_MM = 1e-6
#: the hand measures a frame records (the grasps file holds the same names)
HAND_SIZE_FIELDS = ("hand_length_mm", "hand_breadth_mm")


@dataclass
class ClinicGrasps:
    """What the clinic checks read of a dataset's ``grasps.npz``.

    Attributes:
        grasps: the :class:`hupbench.datagen.dataset.grasps_file.GraspSet` (each grasp's hand: ``hand_spec(g)``;
            its subject's measures: ``subjects``).
        placements: each grasp's patient placement, grasps-file order (on a dataset of clips, its clips' first
            frame's: :func:`frame_placement` gives each frame's).
        contact: {grasp index: (lens height m, deepest probe vertex m, hand / forearm penetration m)}, filled
            by :func:`check_lens_skin` (each grasp measured once).
    """

    grasps: object
    placements: list[PatientPlacement]
    contact: dict
    #: {grasp index: (lens vertices, probe vertices, hand and forearm vertices)}, world frame, metres
    vertices: dict = field(default_factory=dict)


def read_clinic_grasps(root: Path) -> tuple[ClinicGrasps | None, str | None]:
    """The dataset's grasps with their subjects and patient placements, or None and why the clinic checks of
    the world cannot run (the grasps file's own problems are :func:`check_grasps_file`'s to report)."""
    from hupbench.datagen.dataset.grasps_file import GraspSet

    try:
        grasps = GraspSet(root / "grasps.npz")
    except (OSError, ValueError) as exc:
        return None, f"grasps.npz is not readable ({type(exc).__name__})"
    if grasps.placements is None or grasps.subjects is None:
        what = "patient placements (patient_*)" if grasps.placements is None else "subjects (subject_hand, hand_*_mm)"
        return None, f"grasps.npz holds no {what} for its {len(grasps)} grasps"
    return ClinicGrasps(grasps, grasps.placements, {}), None


def _known(ann: dict, world: ClinicGrasps) -> np.ndarray:
    """(N,) bool: rows whose grasp_index names a grasp of the file (others are check_grasps_file's)."""
    return (ann["grasp_index"] >= 0) & (ann["grasp_index"] < len(world.placements))


def check_hand_size(ann: dict, split: str, world: ClinicGrasps) -> list[dict]:
    """Each frame's hand length and breadth against its grasp's subject's (the grasps file's)."""
    rows = np.flatnonzero(_known(ann, world))
    problems = []
    for key in HAND_SIZE_FIELDS:
        expected = world.grasps.subjects[key][ann["grasp_index"][rows]]
        off = np.abs(ann[key][rows] - expected)
        bad = ~(off <= HAND_SIZE_MM)  # NaN fails
        for i, e, o in zip(rows[bad], expected[bad], off[bad]):
            problems.append(_problem(split, ann["frame_id"][i], "hand_size",
                                     f"{key} {ann[key][i]:.3f}, its grasp's subject's (grasp index "
                                     f"{int(ann['grasp_index'][i])}) is {e:.3f} ({o:.3f} mm off)",
                                     f"{split}/{ANNOTATIONS}"))
    return problems


def check_aim(ann: dict, split: str, look_at: str) -> list[dict]:
    """The head camera's aim: the look-at keypoint (a keypoint name: the manifest's ``protocol.look_at``) projects
    at the frame's ``aim_px`` (within ``tol.VERIFY_REPROJECTION_PX``) and lies ``z_ego`` from the camera centre
    (within ``tol.VERIFY_LOOK_AT_M``)."""
    point = ann["keypoints_3d_cam"][:, kp.KEYPOINT_NAMES.index(look_at)].astype(np.float64)
    uv = project_points(point[:, None], ann["K"], behind="nan")[:, 0]
    px = np.abs(uv - ann["aim_px"]).max(axis=1)
    metres = np.abs(np.linalg.norm(point, axis=1) - ann["z_ego"])
    bad = ~(px <= tol.VERIFY_REPROJECTION_PX) | ~(metres <= tol.VERIFY_LOOK_AT_M)
    return [_problem(split, ann["frame_id"][i], "look_at",
                     f"{look_at} projects at {np.round(uv[i], 3).tolist()} px, {np.linalg.norm(point[i]):.6f} m "
                     f"from the camera; expected aim_px {np.round(ann['aim_px'][i], 3).tolist()} at z_ego "
                     f"{ann['z_ego'][i]:.6f} m", f"{split}/{ANNOTATIONS}")
            for i in np.flatnonzero(bad)]


def frame_placement(world: ClinicGrasps, g: int, T_world_body: np.ndarray | None = None) -> PatientPlacement:
    """Grasp ``g``'s patient placement, moved to a frame's body pose ``T_world_body`` ((4, 4), a dataset of clips'
    annotation; None: the grasp's own pose)."""
    placement = world.placements[g]
    return placement if T_world_body is None else moved_placement(placement, T_world_body)


def _placement_of_row(ann: dict, i: int, world: ClinicGrasps) -> PatientPlacement:
    """Row ``i``'s patient placement: its grasp's, at the row's body pose on a dataset of clips."""
    return frame_placement(world, int(ann["grasp_index"][i]), ann["T_world_body"][i] if "T_world_body" in ann else None)


def check_cameras(ann: dict, split: str, world: ClinicGrasps) -> list[dict]:
    """Each camera centre outside its frame's patient (``body_sdf`` > 0) and above the bed plane."""
    problems = []
    centres = invert_transform(ann["T_cam_world"])[:, :3, 3]  # (N, 3) world
    for i in np.flatnonzero(_known(ann, world)):
        placement = _placement_of_row(ann, i, world)
        sdf = float(body_sdf(placement, centres[i][None])[0])
        height = float(placement.to_body(centres[i])[2])   # above the bed's top: the body frame's z
        if not (sdf > 0 and height > 0):
            problems.append(_problem(split, ann["frame_id"][i], "camera_in_patient",
                                     f"the camera centre is {'inside' if sdf <= 0 else 'outside'} the body "
                                     f"({1000 * sdf:.1f} mm from the skin) and {1000 * height:.1f} mm above the "
                                     "bed's top: a head cannot be there", f"{split}/{ANNOTATIONS}"))
    return problems


def _grasp_vertices(world: ClinicGrasps, g: int, probe) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Grasp ``g``'s (lens vertices, probe vertices, hand and forearm vertices), world frame, metres: the hand and
    forearm built as the renderer builds them (:func:`hupbench.datagen.render.scene.scene_parts` with the grasp's
    hand, ``GraspSet.hand_spec``). Kept per grasp."""
    from hupbench.datagen.render.scene import hand_and_arm_vertices

    if g not in world.vertices:
        vertices = np.asarray(probe.mesh.vertices, dtype=np.float64)
        lens = vertices[np.unique(probe.mesh.faces[probe.lens_face_mask])]
        world.vertices[g] = (lens, vertices, hand_and_arm_vertices(world.grasps, g, probe))
    return world.vertices[g]


def contact(world: ClinicGrasps, g: int, probe, placement: PatientPlacement, hand: np.ndarray | None = None
            ) -> tuple[float, float, float]:
    """Grasp ``g``'s lens against the patient at ``placement``, as rendered.

    Args:
        hand: (V, 3) float64, metres, world frame: the hand's vertices in a frame whose fingers moved (a dataset of
            clips), in place of the grasp's own; None: the grasp's.

    Returns:
        (the lens's deepest vertex's signed distance to the skin, the deepest probe vertex's, the deepest hand or
        forearm vertex's depth inside the body or below the bed's top, >= 0), metres.
    """
    lens, vertices, body = _grasp_vertices(world, g, probe)
    if hand is not None:
        body = np.concatenate([hand, body[len(hand):]])
    depth = below_skin(placement.radius_m, placement.to_body(body))
    return (float(body_sdf(placement, lens).min()), float(body_sdf(placement, vertices).min()),
            max(0.0, float(depth.max())))


def grasp_contact(world: ClinicGrasps, g: int, probe) -> tuple[float, float, float]:
    """:func:`contact` at grasp ``g``'s own placement, measured once."""
    if g not in world.contact:
        world.contact[g] = contact(world, g, probe, world.placements[g])
    return world.contact[g]


def _frame_hands(ann: dict, rows: np.ndarray, world: ClinicGrasps) -> dict[int, np.ndarray]:
    """{row: (V, 3) its hand's vertices, world frame} for the ``rows`` whose ``hand_pose`` is not their grasp's (a
    clip's frames whose fingers moved), built as the renderer builds them (the joints clamped to their limits)."""
    from hupbench.datagen.assets.hand import build_hand

    grasps = world.grasps
    index = ann["grasp_index"][rows]
    moved = rows[(ann["hand_pose"][rows] != grasps.hand_pose[index]).any(axis=1)]
    out = {}
    for g in np.unique(ann["grasp_index"][moved]).tolist():
        at = moved[ann["grasp_index"][moved] == g]
        vertices = build_hand(grasps.hand_spec(g)).vertices(ann["hand_pose"][at], grasps.hand_trans[g])
        out.update(zip(at.tolist(), vertices))
    return out


def _contact_problem(lens_m: float, probe_m: float, hand_m: float) -> str | None:
    """What is wrong with a :func:`contact` measure, None when the lens rests on the skin and nothing sinks in."""
    why = []
    if lens_m > LENS_ABOVE_SKIN_M:
        why.append(f"the lens floats {1000 * lens_m:.2f} mm above the skin (at most {1000 * LENS_ABOVE_SKIN_M:g})")
    if probe_m < -PROBE_MAX_DEPTH_M:
        why.append(f"the probe sinks {-1000 * probe_m:.2f} mm into the skin (at most {1000 * PROBE_MAX_DEPTH_M:g})")
    if hand_m > BODY_PENETRATION_M:
        why.append(f"a hand or forearm vertex lies {1000 * hand_m:.2f} mm inside the body or the bed (at most "
                   f"{1000 * BODY_PENETRATION_M:g})")
    return "; ".join(why) or None


def check_lens_skin(ann: dict, split: str, world: ClinicGrasps, probe) -> list[dict]:
    """Per grasp of the split: the lens on the skin, the probe no deeper than ``PROBE_MAX_DEPTH_M``, the hand and
    forearm no deeper than :data:`BODY_PENETRATION_M`; one problem per failing grasp, naming its frames. On a
    dataset of clips the same in every frame, at the frame's body pose and with the frame's hand pose: one problem
    per failing clip, naming its first failing frame and how many fail (the contact kept throughout)."""
    problems = []
    known = _known(ann, world)
    if "T_world_body" in ann:
        for clip in np.unique(ann["clip_id"][known]).tolist():
            rows = np.flatnonzero(known & (ann["clip_id"] == clip))
            hands = _frame_hands(ann, rows, world)
            failing = [(i, why) for i in rows for why in [_contact_problem(*contact(
                world, int(ann["grasp_index"][i]), probe, _placement_of_row(ann, i, world), hands.get(i)))] if why]
            if failing:
                i, why = failing[0]
                problems.append(_problem(split, ann["frame_id"][i], "lens_skin",
                                         f"clip {clip} (grasp index {int(ann['grasp_index'][i])}): {len(failing)} of "
                                         f"its {len(rows)} frames lose the contact, first frame "
                                         f"{int(ann['frame_id'][i]):06d}: {why}", f"{split}/{ANNOTATIONS}"))
        return problems
    for g in np.unique(ann["grasp_index"][known]).tolist():
        why = _contact_problem(*grasp_contact(world, g, probe))
        if why:
            frames = ann["frame_id"][known & (ann["grasp_index"] == g)]
            problems.append(_problem(split, frames[0], "lens_skin",
                                     f"grasp index {g} ({len(frames)} frames, first {int(frames[0]):06d}): {why}",
                                     "grasps.npz"))
    return problems


def check_clinic_annotations(ann: dict, split: str, look_at: str, world: ClinicGrasps | None, probe
                             ) -> list[dict]:
    """A clinic split's checks that need no image: the aim (:func:`check_aim`) and, with the dataset's grasps
    (``world``; None when its grasps file holds no subjects or patients), the hand size, the cameras and the
    lens on the skin."""
    problems = check_aim(ann, split, look_at)
    if world is not None:
        problems += check_hand_size(ann, split, world) + check_cameras(ann, split, world) \
            + check_lens_skin(ann, split, world, probe)
    return problems


def hand_spec_of(world: ClinicGrasps | None):
    """grasp index -> its grasp's HandSpec (None for an index the file lacks), for
    :func:`hupbench.datagen.dataset.verify_annotations.check_geometry`; None without the dataset's grasps."""
    if world is None:
        return None
    return lambda g: world.grasps.hand_spec(g) if 0 <= g < len(world.placements) else None
