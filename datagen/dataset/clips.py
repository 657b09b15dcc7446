"""A clip of a scan on the clinic track's world: its frames' cameras, the patient's pose and the labels.

A clip starts from one of a grasp's head cameras (:meth:`hupbench.datagen.dataset.clinic.ClinicWorld.cameras`):
the probe moves on the skin (:func:`hupbench.datagen.dataset.scan_motion.scan_motion`) with the hand holding it
as in the grasp, its fingers loosening and closing again on it
(:func:`hupbench.datagen.dataset.finger_motion.finger_motion`), and the wearer's head follows
(:func:`hupbench.datagen.dataset.head_motion.head_track`). :func:`clip_geometry` gives everything of the clip but
its pixels: per frame the camera in the world (probe) frame, the patient's body frame in it, the hand's pose, the
29 keypoints in the world, the camera and the image, and the clip's kinematics. A head whose camera would come within the clinic track's clearance of the skin, or lose keypoint 9
out of the image, is drawn again.

Convention:
    World = the grasp's probe frame (the probe's keypoints and the hand's wrist are fixed in it); body frame as in
    :mod:`hupbench.datagen.assets.patient` (the room's). Cameras ``T_cam_world`` in OpenCV axes, metres, 2D in
    pixels of the stored image.
"""

from __future__ import annotations

import numpy as np

from hupbench.core import keypoints as kp
from hupbench.core.camera import project_points
from hupbench.core.errors import RunFailedError
from hupbench.core.geometry import invert_transform, transform_points
from hupbench.datagen.assets.hand import build_hand
from hupbench.datagen.assets.patient import body_sdf_local
from hupbench.datagen.dataset.clinic import HEAD_CLEARANCE_M, ClinicWorld
from hupbench.datagen.dataset.finger_motion import FingerMotionSpec, finger_motion, finger_poses
from hupbench.datagen.dataset.head import horizontal_axes
from hupbench.datagen.dataset.head_motion import HeadMotionSpec, head_track
from hupbench.datagen.dataset.scan_motion import ScanMotion, ScanMotionSpec, scan_motion

__all__ = ["CLIP_STREAM", "FINGER_STREAM", "HEAD_DRAWS", "clip_cameras", "clip_geometry", "clip_record", "draw_clip",
           "hand_steps", "head_steps"]

#: draws of a clip's head before the clip is given up
HEAD_DRAWS = 20
#: the seed stream of a clip's draws (with the dataset seed, the grasp and the clip)
CLIP_STREAM = 103
#: the seed stream of a clip's fingers (with the dataset seed, the grasp and the clip): apart from the probe's and
#: the head's draws, which stay those of a clip whose hand holds still
FINGER_STREAM = 104
_LOOK_AT = kp.KEYPOINT_NAMES.index("middle_mcp")


def clip_geometry(world: ClinicWorld, g: int, view: int, scan: ScanMotionSpec, head: HeadMotionSpec,
                  rng: np.random.Generator, fingers: FingerMotionSpec | None = None,
                  fingers_rng: np.random.Generator | None = None) -> dict:
    """The geometry of one clip of grasp ``g`` starting at its camera ``view``.

    Args:
        world: the clinic track's world (its spec's intrinsics, the grasps with their patients, the cameras).
        g: the grasp. view: the index of the clip's first camera among the grasp's head cameras.
        scan, head: how the probe and the head move.
        rng: the seeded generator of the clip (its probe motion, then its head).
        fingers: how the fingers adjust; None: the hand holds its grasp's pose in every frame.
        fingers_rng: the seeded generator of the fingers (given with ``fingers``).

    Returns:
        {"time_s": (F,) seconds; "T_cam_world": (F, 4, 4); "T_world_body": (F, 4, 4); "hand_pose": (F, 48);
        "keypoints_world": (F, 29, 3), "keypoints_cam": (F, 29, 3) metres; "keypoints_2d": (F, 29, 2) pixels},
        float64; "adjustments": the fingers' (:func:`finger_motion`'s records); "motion": the :class:`ScanMotion`.

    Raises:
        RunFailedError: :data:`HEAD_DRAWS` heads in a row came within the clearance of the skin or lost
            keypoint 9 from the image.
    """
    grasps, intrinsics = world.grasps, world.spec.intrinsics
    placement = world.placements[g]
    motion: ScanMotion = scan_motion(placement, grasps.probe, scan, rng, keep_out=world.keep_out(g))
    T_body_world = invert_transform(motion.T_world_body)  # (F, 4, 4)
    frames = len(motion.time_s)
    keypoints_world = np.repeat(grasps.keypoints_world[g][None], frames, axis=0)  # (F, 29, 3)
    hand_pose, adjustments = np.repeat(grasps.hand_pose[g][None], frames, axis=0), []
    if fingers is not None:
        hand, trans = build_hand(grasps.hand_spec(g)), grasps.hand_trans[g]
        adjustments = finger_motion(fingers, grasps.hand_pose[g], lambda poses: hand.vertices(poses, trans),
                                    grasps.probe, placement.radius_m, T_body_world, motion.time_s, fingers_rng)
        hand_pose = finger_poses(grasps.hand_pose[g], adjustments, motion.time_s)
        moving = np.flatnonzero((hand_pose != grasps.hand_pose[g]).any(axis=1))
        if len(moving):
            keypoints_world[moving, kp.HAND_SLICE] = hand.keypoints(hand_pose[moving], trans, clamp=False)
    # the look-at keypoint (the middle finger's MCP) moves with the wrist only: the same in every frame
    target_body = transform_points(T_body_world, keypoints_world[0, _LOOK_AT][None])[:, 0]  # (F, 3)
    T_cam_body0 = world.cameras(g)["T_cam_world"][view] @ placement.T_world_body
    for _ in range(HEAD_DRAWS):
        T_cam_body = head_track(T_cam_body0, target_body, motion.time_s, head, rng)
        T_cam_world = T_cam_body @ T_body_world
        clear = float(body_sdf_local(placement.radius_m, invert_transform(T_cam_body)[:, :3, 3]).min())
        keypoints_cam = transform_points(T_cam_world, keypoints_world)  # (F, 29, 3)
        uv = project_points(keypoints_cam[:, _LOOK_AT], intrinsics.K)
        inside = bool(np.all((uv >= 0) & (uv <= [intrinsics.width - 1, intrinsics.height - 1])))
        if clear > HEAD_CLEARANCE_M and inside:
            break
    else:
        raise RunFailedError(f"clip of grasp {g}, camera {view}: {HEAD_DRAWS} heads in a row came within "
                             f"{HEAD_CLEARANCE_M:g} m of the skin or lost keypoint 9 from the image (the last: "
                             f"{clear:.3f} m, {'in' if inside else 'out of'} the image): lower "
                             "dataset.head_motion.drift_m or turn_deg")
    return {"time_s": motion.time_s, "T_cam_world": T_cam_world, "T_world_body": motion.T_world_body,
            "hand_pose": hand_pose, "keypoints_world": keypoints_world, "keypoints_cam": keypoints_cam,
            "keypoints_2d": project_points(keypoints_cam, intrinsics.K), "adjustments": adjustments, "motion": motion}


def draw_clip(world: ClinicWorld, g: int, clip: int) -> dict:
    """Clip ``clip`` of grasp ``g`` of a dataset of clips (``world.spec.scan`` and ``head_motion`` set): it starts at
    the grasp's head camera ``clip``; its room (background) and glove are drawn with it, from a generator seeded with
    (dataset seed, :data:`CLIP_STREAM`, grasp, clip), and its fingers (``world.spec.fingers``) from one seeded with
    (dataset seed, :data:`FINGER_STREAM`, grasp, clip), so a clip is a pure function of the config and the grasps.

    Returns:
        :func:`clip_geometry`'s dict with "background" and "glove" (ints).
    """
    spec = world.spec
    assert spec.scan is not None and spec.head_motion is not None
    rng = np.random.default_rng([spec.seed, CLIP_STREAM, g, clip])
    background, glove = int(rng.integers(spec.n_backgrounds)), int(rng.integers(spec.n_gloves))
    fingers_rng = np.random.default_rng([spec.seed, FINGER_STREAM, g, clip])
    return clip_geometry(world, g, clip, spec.scan, spec.head_motion, rng, spec.fingers, fingers_rng) \
        | {"background": background, "glove": glove}


def clip_cameras(world: ClinicWorld, g: int, clip: dict) -> dict[str, np.ndarray]:
    """Each frame's camera as the clinic annotations record it, measured on the frame's pose.

    ``theta`` is the camera's angle from the room's vertical seen from keypoint 9 and ``phi`` its azimuth about
    it, on the room's horizontal axes of the grasp's placement moving with the room (so the first frame's are the
    drawn camera's), ``z_ego`` its distance to keypoint 9, ``aim_px`` where keypoint 9 projects, ``roll_deg`` the
    angle of the room's vertical in the image from the image's up (positive: turned as a positive head roll turns
    it; the drawn camera's own roll differs by what the aim's turn adds).

    Args:
        world: the clinic world. g: the grasp. clip: :func:`clip_geometry`'s dict.

    Returns:
        {"theta", "phi" (F,) radians; "z_ego" (F,) metres; "roll_deg" (F,) degrees; "aim_px" (F, 2) pixels}.
    """
    placement = world.placements[g]
    h0, h1, up = horizontal_axes(placement.vertical_world)
    # the room's axes in each frame's world: they move with the body
    R_move = clip["T_world_body"][:, :3, :3] @ placement.T_world_body[:3, :3].T  # (F, 3, 3)
    h0, h1, up = (R_move @ axis for axis in (h0, h1, up))  # (F, 3) each
    target_cam = clip["keypoints_cam"][:, _LOOK_AT]  # (F, 3)
    z_ego = np.linalg.norm(target_cam, axis=1)
    R = clip["T_cam_world"][:, :3, :3]
    direction = -np.einsum("fji,fj->fi", R, target_cam) / z_ego[:, None]  # (F, 3) keypoint 9 -> camera, world
    theta = np.arccos(np.clip(np.einsum("fi,fi->f", direction, up), -1.0, 1.0))
    phi = np.mod(np.arctan2(np.einsum("fi,fi->f", direction, h1), np.einsum("fi,fi->f", direction, h0)),
                 2.0 * np.pi)
    up_cam = np.einsum("fij,fj->fi", R, up)
    roll_deg = np.degrees(np.arctan2(-up_cam[:, 0], -up_cam[:, 1]))
    return {"theta": theta, "phi": phi, "z_ego": z_ego, "roll_deg": roll_deg,
            "aim_px": clip["keypoints_2d"][:, _LOOK_AT]}


def head_steps(T_cam_world: np.ndarray, T_world_body: np.ndarray, fps: float) -> tuple[np.ndarray, np.ndarray]:
    """The head's frame-to-frame motion relative to the room: (F - 1,) the camera centre's speed, mm/s, and (F - 1,)
    its turn rate, degrees/s, over each frame interval (at ``fps``)."""
    T_cam_body = T_cam_world @ T_world_body
    centres = invert_transform(T_cam_body)[:, :3, 3]
    speed = 1e3 * fps * np.linalg.norm(np.diff(centres, axis=0), axis=1)
    R = T_cam_body[:, :3, :3]
    cos = (np.einsum("fij,fij->f", R[1:], R[:-1]) - 1.0) / 2.0  # trace(R_{f+1} R_f^T) = 1 + 2 cos(angle)
    return speed, fps * np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def hand_steps(keypoints_world: np.ndarray, fps: float) -> np.ndarray:
    """(F - 1,) the fastest hand keypoint's speed relative to the probe, mm/s, over each frame interval (at
    ``fps``): the fingers' adjustments (the wrist is fixed in the world, the probe frame).

    Args:
        keypoints_world: (F, 29, 3) or (F, 21, 3) float64, metres, world frame.
    """
    step = np.linalg.norm(np.diff(keypoints_world[:, kp.HAND_SLICE], axis=0), axis=-1)  # (F - 1, 21)
    return 1e3 * fps * step.max(axis=1)


def clip_record(clip: dict, fps: float) -> dict:
    """A clip's manifest record of its motion: the skill drawn; the probe's drawn and measured mean speed,
    acceleration and jerk and their maxima ("bounds": no frame-to-frame change of its centre exceeds them); the
    head's top speed and turn rate between frames ("head_bounds"); the fingers' adjustments and the top speed of
    a hand keypoint relative to the probe between frames ("fingers"); its room and glove."""
    motion = clip["motion"]
    speed, turn = head_steps(clip["T_cam_world"], clip["T_world_body"], fps)
    fingers = hand_steps(clip["keypoints_world"], fps)
    return {"background_id": clip["background"], "glove_id": clip["glove"], "skill": motion.skill,
            "target": dict(motion.target), "kinematics": dict(motion.kinematics), "bounds": dict(motion.bounds),
            "head_bounds": {"speed_mm_per_s": float(speed.max()), "turn_deg_per_s": float(turn.max())},
            "fingers": {"adjustments": clip["adjustments"], "keypoint_speed_mm_per_s": float(fingers.max())}}
