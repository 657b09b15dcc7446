"""A clip of a scan on the clinic track's world: its frames' cameras, the patient's pose and the labels.

A clip starts from one of a grasp's head cameras (:meth:`hupbench.datagen.dataset.clinic.ClinicWorld.cameras`):
the probe moves on the skin (:func:`hupbench.datagen.dataset.scan_motion.scan_motion`) with the hand holding it
as in the grasp, and the wearer's head follows (:func:`hupbench.datagen.dataset.head_motion.head_track`).
:func:`clip_geometry` gives everything of the clip but its pixels: per frame the camera in the world (probe)
frame, the patient's body frame in it, the 29 keypoints in the camera and in the image, and the clip's
kinematics. A head whose camera would come within the clinic track's clearance of the skin, or lose keypoint 9
out of the image, is drawn again.

Convention:
    World = the grasp's probe frame (the hand and probe keypoints are fixed in it); body frame as in
    :mod:`hupbench.datagen.assets.patient` (the room's). Cameras ``T_cam_world`` in OpenCV axes, metres, 2D in
    pixels of the stored image.
"""

from __future__ import annotations

import numpy as np

from hupbench.core import keypoints as kp
from hupbench.core.camera import project_points
from hupbench.core.errors import RunFailedError
from hupbench.core.geometry import invert_transform, transform_points
from hupbench.datagen.assets.patient import body_sdf_local
from hupbench.datagen.dataset.clinic import HEAD_CLEARANCE_M, ClinicWorld
from hupbench.datagen.dataset.head_motion import HeadMotionSpec, head_track
from hupbench.datagen.dataset.scan_motion import ScanMotion, ScanMotionSpec, scan_motion

__all__ = ["HEAD_DRAWS", "clip_geometry"]

#: draws of a clip's head before the clip is given up
HEAD_DRAWS = 20
_LOOK_AT = kp.KEYPOINT_NAMES.index("middle_mcp")


def clip_geometry(world: ClinicWorld, g: int, view: int, scan: ScanMotionSpec, head: HeadMotionSpec,
                  rng: np.random.Generator) -> dict:
    """The geometry of one clip of grasp ``g`` starting at its camera ``view``.

    Args:
        world: the clinic track's world (its spec's intrinsics, the grasps with their patients, the cameras).
        g: the grasp. view: the index of the clip's first camera among the grasp's head cameras.
        scan, head: how the probe and the head move.
        rng: the seeded generator of the clip (its probe motion, then its head).

    Returns:
        {"time_s": (F,) seconds; "T_cam_world": (F, 4, 4); "T_world_body": (F, 4, 4); "keypoints_cam": (F, 29, 3)
        metres; "keypoints_2d": (F, 29, 2) pixels; "motion": the :class:`ScanMotion`}, float64.

    Raises:
        RunFailedError: :data:`HEAD_DRAWS` heads in a row came within the clearance of the skin or lost
            keypoint 9 from the image.
    """
    grasps, intrinsics = world.grasps, world.spec.intrinsics
    placement = world.placements[g]
    motion: ScanMotion = scan_motion(placement, grasps.probe, scan, rng)
    T_body_world = invert_transform(motion.T_world_body)  # (F, 4, 4)
    keypoints_world = grasps.keypoints_world[g]
    target_body = transform_points(T_body_world, keypoints_world[_LOOK_AT][None])[:, 0]  # (F, 3)
    T_cam_body0 = world.cameras(g)["T_cam_world"][view] @ placement.T_world_body
    for _ in range(HEAD_DRAWS):
        T_cam_body = head_track(T_cam_body0, target_body, motion.time_s, head, rng)
        T_cam_world = T_cam_body @ T_body_world
        clear = float(body_sdf_local(placement.radius_m, invert_transform(T_cam_body)[:, :3, 3]).min())
        keypoints_cam = transform_points(T_cam_world, keypoints_world[None])  # (F, 29, 3)
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
            "keypoints_cam": keypoints_cam, "keypoints_2d": project_points(keypoints_cam, intrinsics.K),
            "motion": motion}
