"""A procedural, license-free articulated right hand.

The hand has MANO's kinematic tree (16 joints: wrist; index, middle, little,
ring, thumb, three joints each) plus 5 fingertips, adult bone lengths and
anatomical joint limits, and a closed skinned mesh built here from an
implicit surface (capsules and a rounded palm slab blended by smooth
minimum, meshed by marching cubes, decimated, skinned by linear blend
skinning). No MANO file is read.

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

import functools
from dataclasses import dataclass

import numpy as np
import torch

from datagen import keypoints as kp
from datagen.geometry import (
    _check_last,
    axis_angle_to_matrix,
    euler_to_matrix,
    matrix_to_axis_angle,
    matrix_to_euler_xyz,
)

MM = 1e-3
NUM_JOINTS = kp.MANO_NUM_JOINTS  # 16
POSE_DIM = 3 * NUM_JOINTS  # 48

# --- adult right hand, 50th percentile (REFERENCE.md), millimetres -----------------
# wrist-to-MCP distance and phalanx lengths (proximal, middle, distal to tip)
FINGER_LENGTHS_MM = {
    "index": (85.0, 46.0, 27.0, 18.0),
    "middle": (84.0, 50.0, 32.0, 20.0),
    "ring": (77.0, 46.0, 31.0, 20.0),
    "little": (70.0, 39.0, 22.0, 18.0),
}
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
_FINGER_RADII_MM = {
    "index": (9.0, 8.0, 7.0),
    "middle": (9.3, 8.3, 7.2),
    "ring": (8.7, 7.8, 6.9),
    "little": (7.8, 7.0, 6.3),
}
_THUMB_RADII_MM = (12.5, 9.8, 8.8)  # metacarpal (thenar), proximal, distal

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


@dataclass(frozen=True)
class HandSpec:
    """Parameters of the procedural hand.

    Attributes:
        scale: overall size; 1.0 is the adult 50th-percentile hand of
            REFERENCE.md, lengths and radii scale linearly.
        voxel_m: marching-cubes grid step for the rest mesh, metres.
        max_faces: triangle budget after decimation.
    """

    scale: float = 1.0
    voxel_m: float = 0.0012
    max_faces: int = 7800

    def __post_init__(self) -> None:
        if not np.isfinite(self.scale) or not 0.5 <= self.scale <= 1.5:
            raise ValueError(f"hand scale must be in [0.5, 1.5], got {self.scale!r}")
        if not np.isfinite(self.voxel_m) or not 0.0003 <= self.voxel_m <= 0.004:
            raise ValueError(f"voxel_m must be in [0.3, 4] mm, got {self.voxel_m!r} m")
        if self.max_faces < 1000:
            raise ValueError(f"max_faces must be at least 1000, got {self.max_faces}")


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v)


def rest_skeleton(scale: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Rest-pose joints and fingertips in the hand frame.

    Args:
        scale: hand size factor (1.0 = adult 50th percentile).

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
            chain = [_unit(_THUMB_DIRS[0]) * d0]
            for length, direction in zip(bones, _THUMB_DIRS[1:]):
                chain.append(chain[-1] + _unit(direction) * length)
        else:
            d0, *bones = FINGER_LENGTHS_MM[finger]
            y, z = _MCP_Y_MM[finger], _MCP_Z_MM[finger]
            mcp = np.array([np.sqrt(d0**2 - y**2 - z**2), y, z])
            direction = _unit([1.0, 0.0, _SPLAY[finger]])
            chain = [mcp]
            for length in bones:
                chain.append(chain[-1] + direction * length)
        joints[1 + 3 * i : 4 + 3 * i] = chain[:3]
        tips[i] = chain[3]
    return joints * MM * scale, tips * MM * scale


def _child_of_joint(joints: np.ndarray, tips: np.ndarray) -> np.ndarray:
    """(16, 3) rest position of the point each joint's bone ends at (child joint or tip)."""
    ends = np.zeros_like(joints)
    ends[0] = joints[kp.MANO_FINGER_ORDER.index("middle") * 3 + 1]  # wrist bone: to the middle MCP
    for i in range(5):
        ends[1 + 3 * i] = joints[2 + 3 * i]
        ends[2 + 3 * i] = joints[3 + 3 * i]
        ends[3 + 3 * i] = tips[i]
    return ends


def anatomical_frames(scale: float = 1.0) -> np.ndarray:
    """Rest-pose anatomical axes of joints 1..15.

    Returns:
        (15, 3, 3) float64; column 0 the flexion axis, 1 the abduction axis,
        2 the bone direction (twist axis), in the hand frame, right-handed.
    """
    joints, tips = rest_skeleton(scale)
    ends = _child_of_joint(joints, tips)
    frames = np.zeros((15, 3, 3))
    for j in range(1, NUM_JOINTS):
        twist = _unit(ends[j] - joints[j])
        is_thumb = j >= 13
        # direction the pad faces: the palm (-y) for fingers; for the thumb, whose pad faces
        # the index finger, mostly +z with some palmar tilt
        palmar = _unit([0.0, -0.45, 1.0]) if is_thumb else np.array([0.0, -1.0, 0.0])
        flex = _unit(np.cross(twist, palmar))
        abd = np.cross(twist, flex)
        frames[j - 1] = np.stack([flex, abd, twist], axis=1)
    return frames


def check_pose(pose: np.ndarray, name: str = "pose") -> np.ndarray:
    """Validate a hand pose.

    Args:
        pose: (48,) or (B, 48) float axis-angle, radians.

    Returns:
        the same as float64.
    """
    pose = np.asarray(pose, dtype=np.float64)
    if pose.ndim not in (1, 2) or pose.shape[-1] != POSE_DIM:
        raise ValueError(f"{name} must be ({POSE_DIM},) or (B, {POSE_DIM}) axis-angle, got {tuple(pose.shape)}")
    if not np.all(np.isfinite(pose)):
        raise ValueError(f"{name} contains NaN or inf")
    return pose


def pose_to_anatomical(pose: np.ndarray, scale: float = 1.0) -> np.ndarray:
    """Joint rotations as anatomical angles.

    Args:
        pose: (48,) or (B, 48) float axis-angle (see module Convention).
        scale: hand size (the anatomical axes do not depend on it).

    Returns:
        (15, 3) or (B, 15, 3) float64 (flexion, abduction, twist), radians.
    """
    pose = check_pose(pose)
    A = anatomical_frames(scale)
    R = axis_angle_to_matrix(pose[..., 3:].reshape(pose.shape[:-1] + (15, 3)))  # (..., 15, 3, 3)
    R_anat = np.swapaxes(A, -1, -2) @ R @ A
    return matrix_to_euler_xyz(R_anat)


def anatomical_to_pose(angles: np.ndarray, global_axis_angle=(0.0, 0.0, 0.0), scale: float = 1.0) -> np.ndarray:
    """Build a 48-value pose from anatomical angles.

    Args:
        angles: (15, 3) or (B, 15, 3) float (flexion, abduction, twist), radians,
            MANO joint order.
        global_axis_angle: (3,) or (B, 3) float, hand frame -> world rotation.
        scale: hand size (the anatomical axes do not depend on it).

    Returns:
        (48,) or (B, 48) float64 pose.
    """
    angles = _check_last(angles, (15, 3), "angles")
    g = _check_last(global_axis_angle, (3,), "global_axis_angle")
    A = anatomical_frames(scale)
    R = A @ euler_to_matrix(angles, "xyz") @ np.swapaxes(A, -1, -2)
    joints_aa = matrix_to_axis_angle(R).reshape(angles.shape[:-2] + (45,))
    g = np.broadcast_to(g, joints_aa.shape[:-1] + (3,))
    return np.concatenate([g, joints_aa], axis=-1)


def clamp_pose(pose: np.ndarray, strict: bool = False, scale: float = 1.0) -> np.ndarray:
    """Enforce the anatomical joint limits.

    Args:
        pose: (48,) or (B, 48) float axis-angle.
        strict: raise instead of clamping when a joint is outside its limits.
        scale: hand size (the anatomical axes do not depend on it).

    Returns:
        (48,) or (B, 48) float64 pose whose joints are within limits (the
        global rotation is untouched).
    """
    pose = check_pose(pose)
    angles = pose_to_anatomical(pose, scale)
    limits = joint_limits_rad()
    # a hair of slack so that poses built at a limit do not flicker across it
    slack = 1e-9
    low, high = limits[..., 0] - slack, limits[..., 1] + slack
    outside = (angles < low) | (angles > high)
    if not np.any(outside):
        return pose.copy()
    if strict:
        names = joint_names()
        axes = ("flexion", "abduction", "twist")
        where = np.argwhere(outside)
        msgs = []
        for idx in where[:6]:
            *b, j, a = idx
            value = np.rad2deg(angles[tuple(idx)])
            lo, hi = np.rad2deg(limits[j, a])
            msgs.append(f"{names[j + 1]} {axes[a]} {value:.1f} deg not in [{lo:.0f}, {hi:.0f}]")
        raise ValueError("pose outside joint limits: " + "; ".join(msgs))
    clamped = np.clip(angles, limits[..., 0], limits[..., 1])
    return anatomical_to_pose(clamped, pose[..., :3], scale)


def joint_names() -> tuple[str, ...]:
    """Names of the 16 MANO joints, in MANO order."""
    names = ["wrist"]
    for finger in kp.MANO_FINGER_ORDER:
        for k in range(3):
            names.append(kp.HAND_NAMES[kp.FINGER_START[finger] + k])
    return tuple(names)


def forward_kinematics_torch(R_local: torch.Tensor, trans: torch.Tensor, joints_rest: torch.Tensor):
    """World rotations and positions of the 16 joints (differentiable).

    Args:
        R_local: (..., 16, 3, 3) joint rotations relative to the parent, rest axes
            (index 0 is the global rotation, hand frame -> world).
        trans: (..., 3) wrist position in the world, metres.
        joints_rest: (16, 3) rest joint positions, metres, hand frame.

    Returns:
        R_world: (..., 16, 3, 3) and t_world: (..., 16, 3): a rest point ``p``
        rigidly attached to joint j goes to ``R_world[j] @ (p - J_j) + t_world[j]``.
    """
    R_world = [R_local[..., 0, :, :]]
    t_world = [trans]
    for j in range(1, NUM_JOINTS):
        p = kp.MANO_PARENTS[j]
        R_world.append(R_world[p] @ R_local[..., j, :, :])
        t_world.append(t_world[p] + (R_world[p] @ (joints_rest[j] - joints_rest[p])[:, None])[..., 0])
    return torch.stack(R_world, dim=-3), torch.stack(t_world, dim=-2)


def keypoints_torch(R_world, t_world, joints_rest, tips_rest):
    """(..., 21, 3) OpenPose-order keypoints from :func:`forward_kinematics_torch`'s output."""
    out = [None] * kp.NUM_HAND
    for j, op in enumerate(kp.MANO_TO_OPENPOSE):
        out[op] = t_world[..., j, :]
    for tip_op, j in kp.TIP_PARENT_MANO.items():
        offset = tips_rest[(j - 1) // 3] - joints_rest[j]
        out[tip_op] = (R_world[..., j, :, :] @ offset[:, None])[..., 0] + t_world[..., j, :]
    return torch.stack(out, dim=-2)


def skin_torch(R_world, t_world, joints_rest, vertices_rest, weights):
    """Linear blend skinning (differentiable).

    Args:
        R_world, t_world: from :func:`forward_kinematics_torch`, (..., 16, 3, 3), (..., 16, 3).
        joints_rest: (16, 3); vertices_rest: (V, 3) metres, hand frame; weights: (V, 16).

    Returns:
        (..., V, 3) posed vertices, metres, world frame.
    """
    offset = t_world - (R_world @ joints_rest[:, :, None])[..., 0]  # (..., 16, 3)
    batch = R_world.shape[:-3]
    # blend the 16 rotations per vertex as one (V, 16) x (16, 9) matmul: no (V, 16, 3, 3) intermediate
    R_blend = (weights @ R_world.reshape(batch + (16, 9))).reshape(batch + (-1, 3, 3))  # (..., V, 3, 3)
    return (R_blend @ vertices_rest[:, :, None])[..., 0] + weights @ offset


def forward_kinematics(pose: np.ndarray, trans, scale: float = 1.0) -> np.ndarray:
    """World transforms of the 16 joints.

    Args:
        pose: (48,) or (B, 48) float axis-angle (module Convention).
        trans: (3,) or (B, 3) float, metres, wrist position in the world.
        scale: hand size.

    Returns:
        (16, 4, 4) or (B, 16, 4, 4) float64 ``G``: ``G[j] @ [p_rest - J_j, 1]``
        is where a rest-pose point ``p_rest`` rigidly attached to joint j goes.
    """
    pose = check_pose(pose)
    trans = _check_last(trans, (3,), "trans")
    joints, _ = rest_skeleton(scale)
    batch = pose.shape[:-1]
    R = axis_angle_to_matrix(pose.reshape(batch + (NUM_JOINTS, 3)))  # (..., 16, 3, 3)
    R_world, t_world = forward_kinematics_torch(
        torch.from_numpy(R), torch.from_numpy(np.broadcast_to(trans, batch + (3,)).copy()), torch.from_numpy(joints)
    )
    G = np.zeros(batch + (NUM_JOINTS, 4, 4))
    G[..., :3, :3] = R_world.numpy()
    G[..., :3, 3] = t_world.numpy()
    G[..., 3, 3] = 1.0
    return G


def torch_cat_global(R_global, R_joints):
    """Stack the global rotation (..., 3, 3) in front of the joints' (..., 15, 3, 3)."""
    return torch.cat([R_global[..., None, :, :].expand(R_joints.shape[:-3] + (1, 3, 3)), R_joints], dim=-3)


def _posed_keypoints(G: np.ndarray, joints_rest: np.ndarray, tips_rest: np.ndarray) -> np.ndarray:
    """(..., 21, 3) OpenPose-order keypoints from joint transforms."""
    t = lambda a: torch.from_numpy(np.ascontiguousarray(a))  # noqa: E731
    return keypoints_torch(t(G[..., :3, :3]), t(G[..., :3, 3]), t(joints_rest), t(tips_rest)).numpy()


class HandModel:
    """Articulated, skinned right hand.

    Use :func:`build_hand` to get a cached instance.

    Attributes:
        spec: the :class:`HandSpec` it was built from.
        joints_rest: (16, 3) float64, metres, hand frame, MANO order.
        tips_rest: (5, 3) float64, metres, MANO finger order.
        vertices_rest: (V, 3) float64, metres, hand frame.
        faces: (F, 3) int64, outward winding.
        weights: (V, 16) float64 skinning weights, rows sum to 1.
    """

    def __init__(self, spec: HandSpec) -> None:
        self.spec = spec
        self.joints_rest, self.tips_rest = rest_skeleton(spec.scale)
        self.vertices_rest, self.faces, self.weights = _build_mesh(spec)
        self.limits_rad = joint_limits_rad()

    @property
    def keypoints_rest(self) -> np.ndarray:
        """(21, 3) float64 rest keypoints, metres, hand frame, OpenPose order."""
        G = forward_kinematics(np.zeros(POSE_DIM), np.zeros(3), self.spec.scale)
        return _posed_keypoints(G, self.joints_rest, self.tips_rest)

    def keypoints(self, pose: np.ndarray, trans, clamp: bool = True) -> np.ndarray:
        """Posed keypoints.

        Args:
            pose: (48,) or (B, 48) float axis-angle.
            trans: (3,) or (B, 3) float, metres, wrist position in the world.
            clamp: enforce joint limits first (see :func:`clamp_pose`).

        Returns:
            (21, 3) or (B, 21, 3) float64, metres, world frame, OpenPose order.
        """
        if clamp:
            pose = clamp_pose(pose, scale=self.spec.scale)
        G = forward_kinematics(pose, trans, self.spec.scale)
        return _posed_keypoints(G, self.joints_rest, self.tips_rest)

    def skinning_transforms(self, pose: np.ndarray, trans) -> np.ndarray:
        """(..., 16, 4, 4) transforms taking rest-pose points to posed points per joint."""
        G = forward_kinematics(pose, trans, self.spec.scale)
        A = G.copy()
        # G maps (p - J_j); fold the rest offset in so A maps rest points directly
        A[..., :3, 3] -= np.einsum("...jik,jk->...ji", G[..., :3, :3], self.joints_rest)
        return A

    def vertices(self, pose: np.ndarray, trans, clamp: bool = True) -> np.ndarray:
        """Linear blend skinning of the mesh.

        Args:
            pose: (48,) or (B, 48) float axis-angle.
            trans: (3,) or (B, 3) float, metres, wrist position in the world.
            clamp: enforce joint limits first.

        Returns:
            (V, 3) or (B, V, 3) float64, metres, world frame.
        """
        if clamp:
            pose = clamp_pose(pose, scale=self.spec.scale)
        G = forward_kinematics(pose, trans, self.spec.scale)
        t = lambda a: torch.from_numpy(np.ascontiguousarray(a))  # noqa: E731
        return skin_torch(t(G[..., :3, :3]), t(G[..., :3, 3]), t(self.joints_rest), t(self.vertices_rest),
                          t(self.weights)).numpy()

    def buffers(self, dtype=None, device=None) -> dict:
        """The model's constant arrays as torch tensors, cached per dtype and device.

        Returns:
            dict with "joints_rest" (16, 3), "tips_rest" (5, 3), "vertices_rest" (V, 3),
            "weights" (V, 16), "frames" (15, 3, 3) anatomical axes and "limits" (15, 3, 2) radians.
        """
        dtype = dtype or torch.float32
        device = torch.device(device or "cpu")
        key = (dtype, device)
        cache = self.__dict__.setdefault("_buffers", {})
        if key not in cache:
            arrays = {
                "joints_rest": self.joints_rest,
                "tips_rest": self.tips_rest,
                "vertices_rest": self.vertices_rest,
                "weights": self.weights,
                "frames": anatomical_frames(self.spec.scale),
                "limits": self.limits_rad,
            }
            cache[key] = {k: torch.as_tensor(v, dtype=dtype, device=device) for k, v in arrays.items()}
        return cache[key]

    def forward_torch(self, R_global, trans, angles, vertex_index=None):
        """Differentiable keypoints and skinned vertices from anatomical angles.

        Args:
            R_global: (..., 3, 3) tensor, hand frame -> world rotation.
            trans: (..., 3) tensor, metres, wrist position in the world.
            angles: (..., 15, 3) tensor (flexion, abduction, twist), radians, MANO
                joint order; not clamped here (bound them in the caller).
            vertex_index: optional (V',) long tensor: skin only these vertices.

        Returns:
            keypoints: (..., 21, 3) OpenPose order; vertices: (..., V', 3); both metres, world.
        """
        from datagen.rotations_torch import euler_xyz_to_matrix

        b = self.buffers(angles.dtype, angles.device)
        frames = b["frames"]
        R_joints = frames @ euler_xyz_to_matrix(angles) @ frames.transpose(-1, -2)  # (..., 15, 3, 3)
        R_local = torch_cat_global(R_global, R_joints)
        R_world, t_world = forward_kinematics_torch(R_local, trans, b["joints_rest"])
        keypoints = keypoints_torch(R_world, t_world, b["joints_rest"], b["tips_rest"])
        verts, weights = b["vertices_rest"], b["weights"]
        if vertex_index is not None:
            verts, weights = verts[vertex_index], weights[vertex_index]
        return keypoints, skin_torch(R_world, t_world, b["joints_rest"], verts, weights)

    def mesh(self, pose: np.ndarray, trans, clamp: bool = True):
        """Posed mesh as a ``trimesh.Trimesh`` (metres, world frame)."""
        import trimesh

        pose = check_pose(pose)
        if pose.ndim != 1:
            raise ValueError(f"mesh() takes one pose (48,), got {tuple(pose.shape)}")
        return trimesh.Trimesh(self.vertices(pose, trans, clamp), self.faces, process=False)


@functools.lru_cache(maxsize=8)
def build_hand(spec: HandSpec = HandSpec()) -> HandModel:
    """The hand for ``spec``, built once per process."""
    if not isinstance(spec, HandSpec):
        raise TypeError(f"spec must be a HandSpec, got {type(spec).__name__}")
    return HandModel(spec)


# --- the rest mesh: implicit surface -> marching cubes -> decimation -> skin weights --------


def _segment_distance(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distance from points (N, 3) to segment ab, and the segment parameter t in [0, 1]."""
    ab = b - a
    t = np.clip((points - a) @ ab / max(ab @ ab, 1e-18), 0.0, 1.0)
    return np.linalg.norm(points - (a + t[:, None] * ab), axis=1), t


def _smin(a: np.ndarray, b: np.ndarray, k: float) -> np.ndarray:
    """Polynomial smooth minimum: blends surfaces within ~k of each other."""
    h = np.clip(0.5 + 0.5 * (b - a) / k, 0.0, 1.0)
    return b * (1 - h) + a * h - k * h * (1.0 - h)


def _polygon_sdf_2d(points: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """Signed distance (negative inside) from (N, 2) points to a convex CCW polygon (M, 2)."""
    d = np.full(len(points), np.inf)
    inside = np.ones(len(points), dtype=bool)
    for i in range(len(polygon)):
        a, b = polygon[i], polygon[(i + 1) % len(polygon)]
        e = b - a
        w = points - a
        t = np.clip(w @ e / (e @ e), 0.0, 1.0)
        d = np.minimum(d, np.linalg.norm(w - t[:, None] * e, axis=1))
        inside &= (e[0] * w[:, 1] - e[1] * w[:, 0]) >= 0
    return np.where(inside, -d, d)


@dataclass
class _Primitive:
    bone: int  # MANO joint whose transform moves it
    sdf: callable


def _primitives(spec: HandSpec) -> list[_Primitive]:
    """Implicit pieces of the rest hand, each tied to the joint that moves it."""
    s = spec.scale * MM
    joints, tips = rest_skeleton(spec.scale)
    prims: list[_Primitive] = []

    def capsule(a, b, r, bone):
        prims.append(_Primitive(bone, lambda p, a=a, b=b, r=r: _segment_distance(p, a, b)[0] - r))

    for i, finger in enumerate(kp.MANO_FINGER_ORDER):
        j0 = 1 + 3 * i
        chain = [joints[j0], joints[j0 + 1], joints[j0 + 2], tips[i]]
        radii = np.array(_THUMB_RADII_MM if finger == "thumb" else _FINGER_RADII_MM[finger]) * s
        for k in range(3):
            a, b = chain[k], chain[k + 1]
            if k == 2:  # the tip keypoint sits on the surface at the end of the pad
                b = b - _unit(b - a) * radii[k]
            capsule(a, b, radii[k], j0 + k)
        if finger != "thumb":
            # knuckle: the metacarpal head, a little dorsal of the MCP centre
            head = joints[j0] + np.array([-4.0, 2.5, 0.0]) * s
            prims.append(_Primitive(0, lambda p, c=head, r=radii[0] + 1.2 * s: np.linalg.norm(p - c, axis=1) - r))

    # palm: a rounded slab over the convex polygon of wrist corners and MCP heads (x-z plane)
    mcps = {f: joints[1 + 3 * i] for i, f in enumerate(kp.MANO_FINGER_ORDER)}
    poly = np.array(
        [
            [mcps["index"][0] - 6 * s, mcps["index"][2] + 2 * s],
            [5 * s, -21 * s],
            [5 * s, 21 * s],
            [mcps["little"][0] - 6 * s, mcps["little"][2] - 1 * s],
            [mcps["ring"][0] - 5 * s, mcps["ring"][2]],
            [mcps["middle"][0] - 5 * s, mcps["middle"][2]],
        ]
    )
    # order counter-clockwise in the (x, z) plane
    centre = poly.mean(axis=0)
    poly = poly[np.argsort(np.arctan2(poly[:, 1] - centre[1], poly[:, 0] - centre[0]))]
    half_thickness, rounding = 12.0 * s, 9.0 * s
    palm_y = -3.0 * s

    def palm(p):
        d2 = _polygon_sdf_2d(p[:, [0, 2]], poly) + rounding
        dy = np.abs(p[:, 1] - palm_y) - half_thickness + rounding
        w = np.stack([d2, dy], axis=1)
        return np.minimum(w.max(axis=1), 0.0) + np.linalg.norm(np.maximum(w, 0.0), axis=1) - rounding

    prims.append(_Primitive(0, palm))
    # hypothenar pad along the ulnar edge of the palm
    capsule(np.array([14.0, -6.0, 20.0]) * s, np.array([52.0, -6.0, 26.0]) * s, 10.0 * s, 0)
    # wrist: an oval bar across, carrying the hand into the forearm
    capsule(np.array([-2.0, -2.0, -19.0]) * s, np.array([-2.0, -2.0, 19.0]) * s, 14.5 * s, 0)
    return prims


def _build_mesh(spec: HandSpec) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    import fast_simplification
    from skimage.measure import marching_cubes

    prims = _primitives(spec)
    joints, tips = rest_skeleton(spec.scale)
    pad = 20.0 * MM * spec.scale
    lo = np.minimum(joints.min(0), tips.min(0)) - pad
    step = spec.voxel_m
    extent = np.maximum(joints.max(0), tips.max(0)) + pad - lo
    block = 8
    nblocks = np.ceil(extent / (step * block)).astype(int)
    field = _narrow_band_field(prims, spec, lo, step, block, nblocks)
    verts, faces, _, _ = marching_cubes(field, level=0.0, spacing=(step, step, step))
    verts = verts + lo
    verts, faces = _decimate(verts, faces, spec.max_faces, fast_simplification)
    faces = _orient_outward(verts, faces)
    weights = _skin_weights(verts, faces, prims, spec)
    return verts, faces.astype(np.int64), weights


def _narrow_band_field(prims, spec, lo, step, block, nblocks) -> np.ndarray:
    """Sample the blended field on the grid, exactly only in blocks the surface can cross.

    The blended field is 1-Lipschitz (a distance bound), so a block whose centre
    value exceeds its half-diagonal holds no surface; such blocks get the centre
    value (right sign, no zero crossing) instead of a full evaluation.
    """
    half_diag = 0.5 * np.sqrt(3.0) * block * step
    centres = lo + (np.stack(np.meshgrid(*[np.arange(n) for n in nblocks], indexing="ij"), -1) + 0.5) * block * step
    coarse = _blend_points(centres.reshape(-1, 3), prims, spec).reshape(tuple(nblocks))
    near = np.abs(coarse) <= half_diag + step
    field = np.repeat(np.repeat(np.repeat(coarse, block, 0), block, 1), block, 2).astype(np.float64)
    offsets = np.stack(np.meshgrid(*[np.arange(block)] * 3, indexing="ij"), -1).reshape(-1, 3)
    idx = np.argwhere(near)  # (Bn, 3) block indices
    cells = (idx[:, None, :] * block + offsets[None]).reshape(-1, 3)  # (Bn * block^3, 3)
    values = _blend_points(lo + cells * step, prims, spec)
    field[cells[:, 0], cells[:, 1], cells[:, 2]] = values
    return field


def _blend_points(points: np.ndarray, prims: list[_Primitive], spec: HandSpec) -> np.ndarray:
    """Blended field at (N, 3) points."""
    return _blend(np.stack([p.sdf(points) for p in prims], axis=1), prims, spec)


def _blend(values: np.ndarray, prims: list[_Primitive], spec: HandSpec) -> np.ndarray:
    """Smooth union: tight within a finger (joints), wide into the palm (webs, thenar)."""
    s = spec.scale * MM
    bones = np.array([p.bone for p in prims])
    palm_like = bones == 0
    thumb_base = bones == 13
    field_palm = values[:, palm_like][:, 0]
    for k in np.flatnonzero(palm_like)[1:]:
        field_palm = _smin(field_palm, values[:, k], 6.0 * s)
    field = _smin(field_palm, values[:, thumb_base].min(axis=1), 9.0 * s)
    for i in range(5):
        j0 = 1 + 3 * i
        if j0 == 13:
            finger = values[:, bones == 14][:, 0]
            finger = _smin(finger, values[:, bones == 15][:, 0], 2.0 * s)
            field = _smin(field, finger, 3.0 * s)
            continue
        finger = values[:, bones == j0][:, 0]
        for j in (j0 + 1, j0 + 2):
            finger = _smin(finger, values[:, bones == j][:, 0], 2.0 * s)
        field = _smin(field, finger, 4.0 * s)
    return field


def _decimate(verts, faces, max_faces, fast_simplification):
    if len(faces) <= max_faces:
        return verts, faces
    reduction = 1.0 - max_faces / len(faces)
    v, f = fast_simplification.simplify(verts.astype(np.float32), faces.astype(np.int32), target_reduction=reduction)
    return np.asarray(v, dtype=np.float64), np.asarray(f, dtype=np.int64)


def _orient_outward(verts: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Flip the winding if the signed volume is negative."""
    tri = verts[faces]
    volume = np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() / 6.0
    return faces[:, ::-1].copy() if volume < 0 else faces


def _smoothstep(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def _bone_radii(spec: HandSpec) -> np.ndarray:
    """(16,) capsule radius of the bone each joint moves, metres (0 for the wrist)."""
    radii = np.zeros(NUM_JOINTS)
    for i, finger in enumerate(kp.MANO_FINGER_ORDER):
        radii[1 + 3 * i : 4 + 3 * i] = _THUMB_RADII_MM if finger == "thumb" else _FINGER_RADII_MM[finger]
    return radii * MM * spec.scale


def _skin_weights(verts, faces, prims, spec: HandSpec) -> np.ndarray:
    """Linear-blend-skinning weights with compact blend zones around the joints.

    Each vertex belongs to the bone of the implicit piece it lies on. Across
    each finger joint the weight passes from parent to child bone with a
    smoothstep over +-0.75 bone radii along the bone axis, the same function
    on both sides so the weights are continuous where ownership changes; on
    the palm side the blend fades out radially so the palm is not dragged
    by a finger. The thenar eminence (soft tissue over the thumb metacarpal)
    blends with the palm where their surface distances differ by under 6 mm. Outside the zones a
    vertex follows one bone exactly (weight 1).
    """
    s = spec.scale * MM
    values = np.stack([p.sdf(verts) for p in prims], axis=1)  # (V, P)
    bones = np.array([p.bone for p in prims])
    per_bone = np.stack([values[:, bones == j].min(axis=1) for j in range(NUM_JOINTS)], axis=1)  # (V, 16)
    owner = np.argmin(per_bone, axis=1)
    w = np.zeros((len(verts), NUM_JOINTS))
    w[np.arange(len(verts)), owner] = 1.0

    joints, tips = rest_skeleton(spec.scale)
    ends = _child_of_joint(joints, tips)
    radii = _bone_radii(spec)
    thumb_cmc = 13
    for j in range(1, NUM_JOINTS):
        p = kp.MANO_PARENTS[j]
        if j == thumb_cmc:
            sel = (owner == 0) | (owner == thumb_cmc)
            t = _smoothstep((per_bone[sel, 0] - per_bone[sel, thumb_cmc] + 6.0 * s) / (12.0 * s))
            w[sel, 0], w[sel, thumb_cmc] = 1.0 - t, t
            continue
        direction = _unit(ends[j] - joints[j])
        delta = 0.75 * radii[j]
        rel = verts - joints[j]
        axial = rel @ direction
        radial = np.linalg.norm(rel - axial[:, None] * direction, axis=1)
        t = _smoothstep((axial + delta) / (2.0 * delta))  # 0: parent bone, 1: this bone
        child_side = owner == j
        w[child_side, p] += 1.0 - t[child_side]
        w[child_side, j] -= 1.0 - t[child_side]
        parent_side = owner == p
        if p == 0:
            t = t * _smoothstep((1.9 * radii[j] - radial) / (0.6 * radii[j]))
        w[parent_side, j] += t[parent_side]
        w[parent_side, p] -= t[parent_side]
    w = np.clip(w, 0.0, None)
    w /= w.sum(axis=1, keepdims=True)
    # one round of neighbour averaging softens the few seams where two zones meet
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    acc, count = w.copy(), np.ones(len(verts))
    np.add.at(acc, edges[:, 0], w[edges[:, 1]])
    np.add.at(acc, edges[:, 1], w[edges[:, 0]])
    np.add.at(count, edges[:, 0], 1)
    np.add.at(count, edges[:, 1], 1)
    w = acc / count[:, None]
    # snap negligible weights to zero so that rigid regions move exactly rigidly
    w[w < 1e-6] = 0.0
    return w / w.sum(axis=1, keepdims=True)
