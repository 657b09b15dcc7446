"""The probe's symmetry and size, read from points in its own frame or from a dataset's annotations.

Convention:
    Metres. Probe frame as in :mod:`hupbench.datagen.assets.probe`: origin at the lens apex, +z along the
    long axis. Rotations act on column vectors about the probe frame's origin. Box corners are keypoints
    21..28 in :data:`hupbench.core.keypoints.CORNER_BITS` order.
"""

from __future__ import annotations

import numpy as np

from hupbench.core import keypoints as kp
from hupbench.core import tolerances as tol
from hupbench.core.errors import BadValueError

__all__ = ["HALF_TURN_Z", "object_diameter_m", "probe_symmetry_group", "symmetry_permutation"]

#: the half turn about the probe frame's long axis z: (x, y, z) -> (-x, -y, z)
HALF_TURN_Z = np.diag([-1.0, -1.0, 1.0])
_MM_PER_M = 1000.0


def symmetry_permutation(points_m, rotation, rel_tol: float = tol.SYMMETRY_REL_TOL) -> tuple[int, ...]:
    """``perm`` (python ints) with ``rotation @ points[k] == points[perm[k]]`` within ``rel_tol`` of the
    set's size, for (K, 3) points in metres in the object's own frame and a (3, 3) proper rotation about
    its origin (e.g. :data:`HALF_TURN_Z`); a set the rotation does not map onto itself is an error."""
    p = np.asarray(points_m, np.float64)
    r = np.asarray(rotation, np.float64)
    assert p.ndim == 2 and p.shape[-1] == 3 and len(p) >= 1, p.shape
    assert np.allclose(r @ r.T, np.eye(3), atol=1e-9) and np.linalg.det(r) > 0, r
    moved = p @ r.T
    dist = np.linalg.norm(moved[:, None] - p[None], axis=-1)  # (K, K): rotated point k to point j
    perm = dist.argmin(axis=1)
    size = max(float(np.linalg.norm(p - p.mean(axis=0), axis=-1).max()), 1e-12)
    worst = float(dist[np.arange(len(p)), perm].max())
    if worst > rel_tol * size or len(set(perm.tolist())) != len(p):
        raise BadValueError(f"the points are not symmetric under the rotation: a rotated point lies "
                            f"{worst * _MM_PER_M:.3g} mm from the nearest point "
                            f"(allowed {rel_tol * size * _MM_PER_M:.3g} mm)")
    return tuple(int(k) for k in perm)


def probe_symmetry_group(keypoints_3d_cam: np.ndarray, T_cam_world: np.ndarray) -> tuple[tuple[int, ...], ...]:
    """The probe corners' symmetry group read from a dataset's annotations.

    The true corners, taken back to the world frame (the probe frame in every hupbench dataset), must agree
    between frames within ``CORNER_FRAME_TOL_M`` and map onto each other under the half turn about z.

    Args:
        keypoints_3d_cam: (N, 29, 3) metres, OpenCV camera frame.
        T_cam_world: (N, 4, 4) world -> camera.

    Returns:
        ((0, ..., 7), the half turn's permutation of the 8 corners), as ``hupbench.metrics.PROBE_SYMMETRIES``.
    """
    corners_cam = np.asarray(keypoints_3d_cam, np.float64)[:, kp.CORNER_SLICE]       # (N, 8, 3)
    T = np.asarray(T_cam_world, np.float64)
    # world = R^T (cam - t)
    corners_world = np.einsum("nji,nkj->nki", T[:, :3, :3], corners_cam - T[:, None, :3, 3])
    drift = float(np.abs(corners_world - corners_world[:1]).max())
    if drift > tol.CORNER_FRAME_TOL_M:
        raise BadValueError(f"the probe's box corners differ between frames by {drift * 1e3:.3f} mm in the world "
                            f"(probe) frame: the dataset does not place the probe at the world origin")
    half_turn = symmetry_permutation(corners_world.mean(axis=0), HALF_TURN_Z, rel_tol=tol.CORNER_SYMMETRY_REL_TOL)
    return (tuple(range(kp.NUM_CORNERS)), half_turn)


def object_diameter_m(points_obj_m: np.ndarray) -> float:
    """The largest distance between two of the (V, 3) points, metres (BOP's ``models_info`` diameter)."""
    from scipy.spatial import ConvexHull
    from scipy.spatial.distance import pdist

    pts = np.asarray(points_obj_m, np.float64)
    assert pts.ndim == 2 and pts.shape[-1] == 3 and len(pts) >= 2, pts.shape
    if len(pts) > 4096:  # the farthest pair lies on the convex hull: a few hundred points instead of thousands
        pts = pts[ConvexHull(pts).vertices]
    return float(pdist(pts).max())
