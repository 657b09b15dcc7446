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

import numpy as np
import torch

from hupbench.core import keypoints as kp
from hupbench.core.geometry import axis_angle_to_matrix
from hupbench.datagen.assets.hand_anatomy import (
    NUM_JOINTS,
    POSE_DIM,
    HandSpec,
    anatomical_frames,
    as_pose,
    clamp_pose,
    joint_limits_rad,
    rest_skeleton,
)
from hupbench.datagen.assets.hand_mesh import build_mesh


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


def forward_kinematics(pose: np.ndarray, trans, spec: HandSpec = HandSpec()) -> np.ndarray:
    """World transforms of the 16 joints.

    Args:
        pose: (48,) or (B, 48) float axis-angle (module Convention).
        trans: (3,) or (B, 3) float, metres, wrist position in the world.
        spec: the hand's size and proportions.

    Returns:
        (16, 4, 4) or (B, 16, 4, 4) float64 ``G``: ``G[j] @ [p_rest - J_j, 1]``
        is where a rest-pose point ``p_rest`` rigidly attached to joint j goes.
    """
    pose = as_pose(pose)
    trans = np.asarray(trans, dtype=np.float64)
    joints, _ = rest_skeleton(spec)
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


def hand_keypoints(spec: HandSpec, pose: np.ndarray, trans, clamp: bool = True) -> np.ndarray:
    """Posed keypoints of the hand ``spec`` from its skeleton alone (no mesh is built).

    Args:
        spec: the hand's size and proportions.
        pose: (48,) or (B, 48) float axis-angle.
        trans: (3,) or (B, 3) float, metres, wrist position in the world.
        clamp: enforce joint limits first (see :func:`clamp_pose`).

    Returns:
        (21, 3) or (B, 21, 3) float64, metres, world frame, OpenPose order.
    """
    if clamp:
        pose = clamp_pose(pose)
    joints, tips = rest_skeleton(spec)
    return _posed_keypoints(forward_kinematics(pose, trans, spec), joints, tips)


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
        self.joints_rest, self.tips_rest = rest_skeleton(spec)
        self.vertices_rest, self.faces, self.weights = build_mesh(spec)
        self.limits_rad = joint_limits_rad()

    @property
    def length_mm(self) -> float:
        """Hand length, mm: the wrist joint to the middle fingertip in the rest pose (anthropometry's hand
        length, wrist crease to the tip of the middle finger: Pheasant and Haslegrave, Bodyspace, 3rd ed., 2006)."""
        return float(np.linalg.norm(self.tips_rest[kp.MANO_FINGER_ORDER.index("middle")])) * 1e3

    @property
    def breadth_mm(self) -> float:
        """Metacarpal hand breadth, mm: the rest mesh's extent across the palm (hand-frame z) at the level of the
        index-to-little MCPs (vertices between the least and the most distal of their x), thumb excluded
        (vertices whose skinning weight is mostly on the thumb's joints), as anthropometry measures it across
        the metacarpal heads (Pheasant and Haslegrave 2006)."""
        mcp_x = self.joints_rest[[1 + 3 * i for i, f in enumerate(kp.MANO_FINGER_ORDER) if f != "thumb"], 0]
        thumb = self.weights[:, 1 + 3 * kp.MANO_FINGER_ORDER.index("thumb"):].sum(axis=1) > 0.5
        x = self.vertices_rest[:, 0]
        z = self.vertices_rest[(x >= mcp_x.min()) & (x <= mcp_x.max()) & ~thumb, 2]
        return float(z.max() - z.min()) * 1e3

    @property
    def keypoints_rest(self) -> np.ndarray:
        """(21, 3) float64 rest keypoints, metres, hand frame, OpenPose order."""
        G = forward_kinematics(np.zeros(POSE_DIM), np.zeros(3), self.spec)
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
        return hand_keypoints(self.spec, pose, trans, clamp)

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
            pose = clamp_pose(pose)
        G = forward_kinematics(pose, trans, self.spec)
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
                "frames": anatomical_frames(),
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
        from hupbench.core.rotations_torch import euler_xyz_to_matrix

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

        assert np.shape(pose) == (POSE_DIM,), np.shape(pose)
        return trimesh.Trimesh(self.vertices(pose, trans, clamp), self.faces, process=False)


@functools.lru_cache(maxsize=128)
def build_hand(spec: HandSpec = HandSpec()) -> HandModel:
    """The hand for ``spec``, built once per process (a clinic grasps file's subjects' hands: 60, about 0.5 MB
    each, all kept)."""
    return HandModel(spec)
