"""Plausibility scores of grasps, and the selection of a diverse plausible set.

Scores (per grasp, measured on the final hand mesh against the probe's
signed distance, probe frame):

- ``max_penetration_mm``: deepest hand or forearm point inside the probe;
- ``pads_in_contact``: how many of the six pads (thumb, index, middle, ring,
  little fingertips and the palm) come within ``CONTACT_MM`` of the surface;
  ``thumb_contact``: whether the thumb is one of them;
- ``self_penetration_mm``: deepest overlap of phalanx capsules of different fingers;
- ``joint_limit_violation_deg``: largest excursion of an anatomical angle
  beyond its limit (the pose is re-read from its 48 axis-angle values);
- ``lens_coverage``: fraction of the acoustic lens surface with a hand point
  within ``LENS_CLEARANCE_MM``;
- ``min_contact_height_mm``: height above the lens apex of the lowest hand
  point touching the probe (fingers must hold the neck and handle);
- ``force_closure_residual``: how far the contacts (one per bone: its closest
  point within ``CONTACT_MM``) are from balancing: min over non-negative
  unit-sum contact weights of the norm of the net
  wrench (forces within friction cones, mu = 0.5, and torques about the
  contact centroid divided by a 5 cm lever); 0 means the contacts can hold
  the probe in equilibrium.

Thresholds live in :data:`PLAUSIBLE`.
"""

from __future__ import annotations

import numpy as np
import torch
from scipy.optimize import nnls
from scipy.spatial import cKDTree

from hupbench.core.geometry import matrix_to_axis_angle
from hupbench.datagen.assets.hand_anatomy import anatomical_to_pose, joint_limits_rad, pose_to_anatomical
from hupbench.datagen.grasps.refine import PADS, GraspBatch, GraspEnergy

CONTACT_MM = 5.0
LENS_CLEARANCE_MM = 10.0
TORQUE_LEVER_M = 0.05
FRICTION = 0.5
#: a grasp is plausible when all of these hold
PLAUSIBLE = {
    "max_penetration_mm": 2.0,  # at most
    "pads_in_contact": 3,  # at least, thumb included
    "self_penetration_mm": 4.0,  # at most
    "joint_limit_violation_deg": 0.0,  # at most (plus float slack)
    "lens_coverage": 0.0,  # at most
    "force_closure_residual": 0.05,  # at most
}
SCORE_NAMES = ("max_penetration_mm", "pads_in_contact", "thumb_contact", "self_penetration_mm",
               "joint_limit_violation_deg", "lens_coverage", "min_contact_height_mm", "force_closure_residual",
               "plausible")


def _friction_edges(normal: np.ndarray, mu: float, edges: int) -> np.ndarray:
    """(edges, 3) unit force directions on the boundary of a friction cone about ``normal``."""
    helper = np.eye(3)[int(np.argmin(np.abs(normal)))]
    t1 = np.cross(normal, helper)
    t1 /= np.linalg.norm(t1)
    t2 = np.cross(normal, t1)
    phi = 2.0 * np.pi * np.arange(edges) / edges
    d = normal[None] + mu * (np.cos(phi)[:, None] * t1 + np.sin(phi)[:, None] * t2)
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def force_closure_residual(points: np.ndarray, normals: np.ndarray, mu: float = FRICTION, edges: int = 4) -> float:
    """Residual of the best non-negative, unit-sum combination of contact wrenches.

    Each contact pushes within its Coulomb friction cone (coefficient ``mu``,
    linearised by ``edges`` boundary directions). The residual is the norm of
    the smallest net wrench (force, and torque about the contacts' centroid
    divided by a 5 cm lever) that unit-sum non-negative contact forces can
    make: 0 means the contacts can hold the probe in equilibrium.

    Args:
        points: (C, 3) float contact points, metres.
        normals: (C, 3) float unit normals pushing into the object.
        mu: friction coefficient (glove on plastic: about 0.5).
        edges: friction cone edges per contact.

    Returns:
        float in [0, 1]; 1.0 when there are no contacts.
    """
    points, normals = np.asarray(points, dtype=np.float64), np.asarray(normals, dtype=np.float64)
    assert points.shape == normals.shape and points.ndim == 2 and points.shape[1] == 3, (points.shape, normals.shape)
    if len(points) == 0:
        return 1.0
    centre = points.mean(axis=0)
    columns = []
    for point, normal in zip(points, normals):
        for force in _friction_edges(normal / np.linalg.norm(normal), mu, edges):
            columns.append(np.concatenate([force, np.cross(point - centre, force) / TORQUE_LEVER_M]))
    wrenches = np.array(columns).T  # (6, C * edges)
    # append sum(lambda) = 1 as a heavily weighted row; nnls keeps lambda >= 0
    weight = 100.0
    A = np.vstack([wrenches, weight * np.ones((1, wrenches.shape[1]))])
    b = np.concatenate([np.zeros(6), [weight]])
    lam, _ = nnls(A, b)
    return float(np.linalg.norm(wrenches @ lam))


def score_grasps(energy: GraspEnergy, grasps: GraspBatch) -> dict[str, np.ndarray]:
    """Measure the plausibility scores of each grasp.

    Args:
        energy: the grasp energy (hand, probe, pads).
        grasps: grasps in the probe frame.

    Returns:
        dict of (B,) arrays named as in :data:`SCORE_NAMES`.
    """
    dtype = torch.float64
    with torch.no_grad():
        R = torch.as_tensor(grasps.R_global, dtype=dtype)
        t = torch.as_tensor(grasps.trans, dtype=dtype)
        a = torch.as_tensor(grasps.angles, dtype=dtype)
        keypoints, verts = energy.hand.forward_torch(R, t, a)
        sdf_m = energy.probe.signed_distance_torch(verts)
        forearm = (R @ torch.as_tensor(energy.regions.forearm_points, dtype=dtype).T).transpose(-1, -2) + t[:, None]
        forearm_sdf = energy.probe.signed_distance_torch(forearm)
        terms = energy.terms(R.float(), t.float(), a.float())
    verts, sdf_mm = verts.numpy(), sdf_m.numpy() * 1000.0
    B = len(grasps)
    out = {name: np.zeros(B) for name in SCORE_NAMES}
    out["max_penetration_mm"] = np.maximum(np.clip(-sdf_mm, 0, None).max(axis=1),
                                           np.clip(-forearm_sdf.numpy() * 1000.0, 0, None).max(axis=1))
    pad_dist = np.stack([np.abs(sdf_mm[:, idx]).min(axis=1) for idx in energy.regions.pads.values()], axis=1)
    in_contact = pad_dist <= CONTACT_MM
    out["pads_in_contact"] = in_contact.sum(axis=1)
    out["thumb_contact"] = in_contact[:, PADS.index("thumb")]
    out["self_penetration_mm"] = terms["_overlap_mm"].double().numpy().max(axis=1)
    limits = np.rad2deg(joint_limits_rad())
    poses = anatomical_to_pose(grasps.angles, matrix_to_axis_angle(grasps.R_global))
    angles_deg = np.rad2deg(pose_to_anatomical(poses))
    excess = np.maximum(limits[..., 0] - angles_deg, angles_deg - limits[..., 1])
    out["joint_limit_violation_deg"] = np.clip(excess, 0, None).max(axis=(1, 2))
    lens_points = _lens_points(energy.probe)
    near_lens = np.stack([cKDTree(v).query(lens_points)[0] for v in verts])  # (B, L) metres
    out["lens_coverage"] = (near_lens < LENS_CLEARANCE_MM / 1000.0).mean(axis=1)
    touching = sdf_mm <= CONTACT_MM
    z_mm = verts[..., 2] * 1000.0
    out["min_contact_height_mm"] = np.where(touching.any(axis=1), np.where(touching, z_mm, np.inf).min(axis=1), np.nan)
    # stability: one contact per bone (its closest vertex within CONTACT_MM), as a power grip
    # holds with whole phalanges and the palm, not with the fingertips alone
    owner = energy.hand.weights.argmax(axis=1)
    bone_vertices = [np.flatnonzero(owner == j) for j in range(energy.hand.weights.shape[1])]
    for i in range(B):
        closest = [idx[np.argmin(np.abs(sdf_mm[i, idx]))] for idx in bone_vertices if len(idx)]
        contacts = [j for j in closest if abs(sdf_mm[i, j]) <= CONTACT_MM]
        pts = verts[i, contacts].reshape(-1, 3)
        nrm = -energy.probe.surface_normal(pts) if len(contacts) else np.zeros((0, 3))
        out["force_closure_residual"][i] = force_closure_residual(pts, nrm)
    out["plausible"] = plausible(out)
    return out


def plausible(scores: dict[str, np.ndarray]) -> np.ndarray:
    """(B,) bool: every threshold of :data:`PLAUSIBLE` holds."""
    return (
        (scores["max_penetration_mm"] <= PLAUSIBLE["max_penetration_mm"])
        & (scores["pads_in_contact"] >= PLAUSIBLE["pads_in_contact"])
        & scores["thumb_contact"].astype(bool)
        & (scores["self_penetration_mm"] <= PLAUSIBLE["self_penetration_mm"])
        & (scores["joint_limit_violation_deg"] <= PLAUSIBLE["joint_limit_violation_deg"] + 1e-6)
        & (scores["lens_coverage"] <= PLAUSIBLE["lens_coverage"])
        & (scores["force_closure_residual"] <= PLAUSIBLE["force_closure_residual"])
    )


def _lens_points(probe) -> np.ndarray:
    """(L, 3) centres of the lens faces, metres, probe frame."""
    mesh = probe.mesh
    return mesh.triangles_center[probe.lens_face_mask]


def farthest_point_selection(features: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """Pick n diverse rows by farthest-point sampling.

    Args:
        features: (M, D) float, e.g. flattened joint positions in metres.
        n: how many to pick, 1 <= n <= M.
        rng: picks the first row.

    Returns:
        (n,) int64 row indices in the order picked.
    """
    features = np.asarray(features, dtype=np.float64)
    assert features.ndim == 2 and 1 <= n <= len(features), (features.shape, n)  # select_grasps checked n
    chosen = [int(rng.integers(len(features)))]
    dist = np.linalg.norm(features - features[chosen[0]], axis=1)
    for _ in range(n - 1):
        nxt = int(np.argmax(dist))
        chosen.append(nxt)
        dist = np.minimum(dist, np.linalg.norm(features - features[nxt], axis=1))
    return np.array(chosen, dtype=np.int64)
