"""The hand's anatomy: bone lengths, joint limits, the rest skeleton and the pose parametrisation.

An adult right hand of about the 50th percentile (186 mm from the wrist to the middle fingertip, between the
50th-percentile hand lengths of adult women and men in Pheasant and Haslegrave, Bodyspace, 3rd ed., 2006);
MANO's kinematic tree (16 joints, Romero et al. 2017) plus 5 fingertips; a MANO-style pose of 48 axis-angle values and its conversion to anatomical angles.
:mod:`hupbench.datagen.assets.hand_mesh` builds the skinned surface, :mod:`hupbench.datagen.assets.hand` the posable model.

Convention:
    Metres and radians. Hand frame (the rest pose): origin at the wrist
    joint centre, +x distal (towards the middle finger), +y dorsal (back of
    the hand), +z = x cross y, towards the little finger; the thumb lies on
    the -z side. The rest pose is a flat hand.
    Pose: 48 axis-angle values like MANO's: 3 global (hand frame -> world)
    then 15 joints in MANO order (index 1-3, middle 4-6, little 7-9, ring
    10-12, thumb 13-15), each the rotation of a joint relative to its parent,
    expressed in the rest-pose axes. Translation: wrist position in the
    world frame. Anatomical angles per joint are (flexion, abduction, twist)
    about the joint's anatomical axes: intrinsic x-y-z Euler angles in the
    frame whose z is the rest direction of the bone the joint moves, x the
    flexion axis (positive flexion curls towards the palm) and y = z cross x.
"""


from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hupbench.core import keypoints as kp
from hupbench.core.geometry import (
    axis_angle_to_matrix,
    euler_to_matrix,
    matrix_to_axis_angle,
    matrix_to_euler_xyz,
)

MM = 1e-3
NUM_JOINTS = kp.MANO_NUM_JOINTS  # 16
POSE_DIM = 3 * NUM_JOINTS  # 48

# --- adult right hand of about the 50th percentile (module docstring), millimetres -----
# wrist-to-MCP distance and phalanx lengths (proximal, middle, distal to tip)
FINGER_LENGTHS_MM = {
    "index": (85.0, 46.0, 27.0, 18.0),
    "middle": (84.0, 50.0, 32.0, 20.0),
    "ring": (77.0, 46.0, 31.0, 20.0),
    "little": (70.0, 39.0, 22.0, 18.0),
}
#: the hand's length, metres: wrist to the middle fingertip with the finger straight (its wrist-to-MCP
#: distance plus its three phalanges), the farthest any point of the hand reaches from the wrist
HAND_LENGTH_M = sum(FINGER_LENGTHS_MM["middle"]) * MM
# CMC distance from the wrist, metacarpal, proximal, distal (ranges 36-47, 31-37, 27-30)
THUMB_LENGTHS_MM = (22.0, 42.0, 34.0, 28.0)

# MCP positions across the palm (z, mm) and palmar arch (y, mm); the x follows from the length
_MCP_Z_MM = {"index": -24.0, "middle": -5.0, "ring": 13.0, "little": 29.0}
_MCP_Y_MM = {"index": 0.0, "middle": 0.0, "ring": -2.0, "little": -5.0}
# rest splay of each finger (z component of its direction before normalising)
_SPLAY = {"index": -0.07, "middle": 0.0, "ring": 0.06, "little": 0.13}
# thumb rest directions (hand frame): CMC from the wrist, then each bone
_THUMB_DIRS = (
    (0.55, -0.40, -0.73),
    (0.70, -0.30, -0.65),
    (0.80, -0.22, -0.56),
    (0.86, -0.17, -0.48),
)
# capsule radii per bone (proximal, middle, distal), mm
FINGER_RADII_MM = {
    "index": (9.0, 8.0, 7.0),
    "middle": (9.3, 8.3, 7.2),
    "ring": (8.7, 7.8, 6.9),
    "little": (7.8, 7.0, 6.3),
}
THUMB_RADII_MM = (12.5, 9.8, 8.8)  # metacarpal (thenar), proximal, distal

# --- joint limits, degrees: (flexion, abduction, twist) x (min, max) -----------------
_FINGER_LIMITS_DEG = (
    ((-30.0, 90.0), (-20.0, 20.0), (-10.0, 10.0)),  # MCP
    ((0.0, 105.0), (-5.0, 5.0), (-5.0, 5.0)),  # PIP
    ((0.0, 90.0), (-5.0, 5.0), (-5.0, 5.0)),  # DIP
)
_THUMB_LIMITS_DEG = (
    ((-20.0, 45.0), (-20.0, 45.0), (-30.0, 30.0)),  # CMC (twist: opposition)
    ((-10.0, 60.0), (-10.0, 10.0), (-10.0, 10.0)),  # MCP
    ((-15.0, 90.0), (-5.0, 5.0), (-5.0, 5.0)),  # IP
)
#: wrist flexion/extension and radial/ulnar deviation between forearm and hand
WRIST_LIMITS_RAD = np.deg2rad((-45.0, 45.0))


def joint_limits_rad() -> np.ndarray:
    """Anatomical joint limits.

    Returns:
        (15, 3, 2) float64, radians: for each MANO joint 1..15, (flexion,
        abduction, twist) x (min, max).
    """
    rows = []
    for finger in kp.MANO_FINGER_ORDER:
        rows.extend(_THUMB_LIMITS_DEG if finger == "thumb" else _FINGER_LIMITS_DEG)
    return np.deg2rad(np.array(rows, dtype=np.float64))


#: the range of every proportion factor of :class:`HandSpec` (and of its scale): half to one and a half of the
#: tables' hand, wider than adult hands vary (Pheasant and Haslegrave 2006: 1st-99th percentile hand lengths
#: within about +-15 % of the mean)
FACTOR_RANGE = (0.5, 1.5)
#: :class:`HandSpec`'s size and proportion fields, in the order a grasps file records them
PROPORTION_FIELDS = ("scale", "palm", "fingers", "breadth", "thickness")


@dataclass(frozen=True)
class HandSpec:
    """Parameters of the procedural hand: its size, its proportions and how finely it is meshed.

    Every proportion is a factor on the module's tables (1.0 keeps them); they change lengths and widths but
    never the rest directions of the bones, so that the anatomical frames, and what a pose means, are the same
    on every hand.

    Attributes:
        scale: overall size; 1.0 is the hand of the module's tables (about the adult 50th percentile);
            lengths and radii scale linearly.
        palm: wrist-to-MCP lengths along the hand (x in the hand frame) and the thumb CMC's distance from the wrist.
        fingers: phalanx lengths (fingers and thumb).
        breadth: spacing of the MCPs across the palm (z in the hand frame) and the palm's and wrist's widths.
        thickness: capsule radii of the fingers and thumb, the palm slab's and wrist's thickness, the palmar arch.
        voxel_m: marching-cubes grid step for the rest mesh, metres.
        max_faces: triangle budget after decimation.
    """

    scale: float = 1.0
    palm: float = 1.0
    fingers: float = 1.0
    breadth: float = 1.0
    thickness: float = 1.0
    voxel_m: float = 0.0012
    max_faces: int = 7800

    def __post_init__(self) -> None:
        # built in code or from a subject whose config or file was checked where it entered: invariants
        low, high = FACTOR_RANGE
        assert all(low <= getattr(self, name) <= high for name in PROPORTION_FIELDS), self
        assert 0.0003 <= self.voxel_m <= 0.004 and self.max_faces >= 1000, self

    @property
    def proportions(self) -> tuple[float, ...]:
        """(scale, palm, fingers, breadth, thickness), the order of :data:`PROPORTION_FIELDS`."""
        return tuple(getattr(self, name) for name in PROPORTION_FIELDS)


def unit_vector(v) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v)


def rest_skeleton(spec: HandSpec = HandSpec()) -> tuple[np.ndarray, np.ndarray]:
    """Rest-pose joints and fingertips in the hand frame.

    The proportions move the joints along the table's bone directions (``palm`` the MCPs' x and the thumb
    CMC's distance, ``breadth`` the MCPs' z, ``thickness`` the palmar arch's y, ``fingers`` the phalanges), so
    every bone keeps its rest direction.

    Args:
        spec: the hand's size and proportions (its mesh settings are not used).

    Returns:
        joints_hand: (16, 3) float64, metres, MANO joint order.
        tips_hand: (5, 3) float64, metres, MANO finger order (index, middle,
            little, ring, thumb).
    """
    joints = np.zeros((NUM_JOINTS, 3))
    tips = np.zeros((5, 3))
    for i, finger in enumerate(kp.MANO_FINGER_ORDER):
        if finger == "thumb":
            d0, *bones = THUMB_LENGTHS_MM
            chain = [unit_vector(_THUMB_DIRS[0]) * (d0 * spec.palm)]
            for length, direction in zip(bones, _THUMB_DIRS[1:]):
                chain.append(chain[-1] + unit_vector(direction) * (length * spec.fingers))
        else:
            d0, *bones = FINGER_LENGTHS_MM[finger]
            y, z = _MCP_Y_MM[finger], _MCP_Z_MM[finger]
            mcp = np.array([np.sqrt(d0**2 - y**2 - z**2) * spec.palm, y * spec.thickness, z * spec.breadth])
            direction = unit_vector([1.0, 0.0, _SPLAY[finger]])
            chain = [mcp]
            for length in bones:
                chain.append(chain[-1] + direction * (length * spec.fingers))
        joints[1 + 3 * i : 4 + 3 * i] = chain[:3]
        tips[i] = chain[3]
    return joints * MM * spec.scale, tips * MM * spec.scale


def child_of_joint(joints: np.ndarray, tips: np.ndarray) -> np.ndarray:
    """(16, 3) rest position of the point each joint's bone ends at (child joint or tip)."""
    ends = np.zeros_like(joints)
    ends[0] = joints[kp.MANO_FINGER_ORDER.index("middle") * 3 + 1]  # wrist bone: to the middle MCP
    for i in range(5):
        ends[1 + 3 * i] = joints[2 + 3 * i]
        ends[2 + 3 * i] = joints[3 + 3 * i]
        ends[3 + 3 * i] = tips[i]
    return ends


def anatomical_frames() -> np.ndarray:
    """Rest-pose anatomical axes of joints 1..15, the same for every :class:`HandSpec` (its proportions keep the
    bones' rest directions).

    Returns:
        (15, 3, 3) float64; column 0 the flexion axis, 1 the abduction axis,
        2 the bone direction (twist axis), in the hand frame, right-handed.
    """
    joints, tips = rest_skeleton()
    ends = child_of_joint(joints, tips)
    frames = np.zeros((15, 3, 3))
    for j in range(1, NUM_JOINTS):
        twist = unit_vector(ends[j] - joints[j])
        is_thumb = j >= 13
        # direction the pad faces: the palm (-y) for fingers; for the thumb, whose pad faces
        # the index finger, mostly +z with some palmar tilt
        palmar = unit_vector([0.0, -0.45, 1.0]) if is_thumb else np.array([0.0, -1.0, 0.0])
        flex = unit_vector(np.cross(twist, palmar))
        abd = np.cross(twist, flex)
        frames[j - 1] = np.stack([flex, abd, twist], axis=1)
    return frames


def as_pose(pose: np.ndarray) -> np.ndarray:
    """A hand pose as float64: (48,) or (B, 48) axis-angle, radians.

    Poses come from this package or from a file whose reader checked their shape and finiteness
    (``hupbench.datagen.dataset.grasps_file``, ``hupbench.core.contract.read_annotations``).
    """
    pose = np.asarray(pose, dtype=np.float64)
    assert pose.ndim in (1, 2) and pose.shape[-1] == POSE_DIM, pose.shape
    return pose


def pose_to_anatomical(pose: np.ndarray) -> np.ndarray:
    """Joint rotations as anatomical angles.

    Args:
        pose: (48,) or (B, 48) float axis-angle (see module Convention).

    Returns:
        (15, 3) or (B, 15, 3) float64 (flexion, abduction, twist), radians.
    """
    pose = as_pose(pose)
    A = anatomical_frames()
    R = axis_angle_to_matrix(pose[..., 3:].reshape(pose.shape[:-1] + (15, 3)))  # (..., 15, 3, 3)
    R_anat = np.swapaxes(A, -1, -2) @ R @ A
    return matrix_to_euler_xyz(R_anat)


def anatomical_to_pose(angles: np.ndarray, global_axis_angle=(0.0, 0.0, 0.0)) -> np.ndarray:
    """Build a 48-value pose from anatomical angles.

    Args:
        angles: (15, 3) or (B, 15, 3) float (flexion, abduction, twist), radians,
            MANO joint order.
        global_axis_angle: (3,) or (B, 3) float, hand frame -> world rotation.

    Returns:
        (48,) or (B, 48) float64 pose.
    """
    angles = np.asarray(angles, dtype=np.float64)
    g = np.asarray(global_axis_angle, dtype=np.float64)
    A = anatomical_frames()
    R = A @ euler_to_matrix(angles, "xyz") @ np.swapaxes(A, -1, -2)
    joints_aa = matrix_to_axis_angle(R).reshape(angles.shape[:-2] + (45,))
    g = np.broadcast_to(g, joints_aa.shape[:-1] + (3,))
    return np.concatenate([g, joints_aa], axis=-1)


def clamp_pose(pose: np.ndarray) -> np.ndarray:
    """Enforce the anatomical joint limits.

    Args:
        pose: (48,) or (B, 48) float axis-angle.

    Returns:
        (48,) or (B, 48) float64 pose whose joints are within limits (the
        global rotation is untouched).
    """
    pose = as_pose(pose)
    angles = pose_to_anatomical(pose)
    limits = joint_limits_rad()
    # a hair of slack so that poses built at a limit do not flicker across it
    slack = 1e-9
    low, high = limits[..., 0] - slack, limits[..., 1] + slack
    outside = (angles < low) | (angles > high)
    if not np.any(outside):
        return pose.copy()
    clamped = np.clip(angles, limits[..., 0], limits[..., 1])
    return anatomical_to_pose(clamped, pose[..., :3])

