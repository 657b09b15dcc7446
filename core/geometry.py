"""Rotations and rigid transforms (numpy, batched).

Convention:
    Rotation matrices act on column vectors: ``p_a = R_a_b @ p_b``.
    Axis-angle vectors ``r`` rotate right-handed by ``|r|`` radians about
    ``r / |r|``. 4x4 transforms are named by frame: ``T_a_b`` maps points in
    frame b into frame a.
"""

from __future__ import annotations

import numpy as np

from hupbench.core import tolerances as tol
from hupbench.core.errors import BadValueError


def check_last_axes(x: np.ndarray, shape: tuple[int, ...], name: str) -> np.ndarray:
    x = np.asarray(x, dtype=np.float64)
    if x.ndim < len(shape) or x.shape[x.ndim - len(shape):] != shape:
        want = "(..., " + ", ".join(map(str, shape)) + ")"
        raise BadValueError(f"{name} must be {want}, got {tuple(x.shape)}")
    if not np.all(np.isfinite(x)):
        raise BadValueError(f"{name} contains NaN or inf")
    return x


def skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrices.

    Args:
        v: (..., 3) float.

    Returns:
        (..., 3, 3) float64 with ``skew(v) @ u == cross(v, u)``.
    """
    v = check_last_axes(v, (3,), "v")
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out


def axis_angle_to_matrix(axis_angle: np.ndarray) -> np.ndarray:
    """Rodrigues' formula, stable at zero angle.

    Args:
        axis_angle: (..., 3) float, radians.

    Returns:
        (..., 3, 3) float64 rotation matrices.
    """
    r = check_last_axes(axis_angle, (3,), "axis_angle")
    theta = np.linalg.norm(r, axis=-1)[..., None, None]
    K = skew(r)
    small = theta < tol.SMALL_ANGLE_RAD
    safe = np.where(small, 1.0, theta)
    # sin(t)/t and (1-cos t)/t^2, with their Taylor limits near zero
    a = np.where(small, 1.0 - theta**2 / 6.0, np.sin(safe) / safe)
    b = np.where(small, 0.5 - theta**2 / 24.0, (1.0 - np.cos(safe)) / safe**2)
    return np.eye(3) + a * K + b * (K @ K)


def as_rotation(R: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation matrices as float64; every caller hands in rotations this package made."""
    R = check_last_axes(R, (3, 3), "R")
    assert np.abs(np.swapaxes(R, -1, -2) @ R - np.eye(3)).max(initial=0.0) <= tol.ROTATION_ORTHONORMAL
    assert np.all(np.linalg.det(R) > 0), "a rotation, not a reflection"
    return R


def matrix_to_axis_angle(R: np.ndarray) -> np.ndarray:
    """Inverse of :func:`axis_angle_to_matrix`, stable near 0 and near pi.

    Args:
        R: (..., 3, 3) float rotation matrices.

    Returns:
        (..., 3) float64 axis-angle with angle in [0, pi].
    """
    R = as_rotation(R)
    trace = np.trace(R, axis1=-2, axis2=-1)
    vee = np.stack(
        [R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], axis=-1
    )
    # atan2 of (sin, cos) keeps full precision near 0 and pi, where arccos of the trace loses it
    sin_t = 0.5 * np.linalg.norm(vee, axis=-1)
    theta = np.arctan2(sin_t, (trace - 1.0) / 2.0)
    small = theta < tol.SMALL_ANGLE_RAD
    near_pi = (np.pi - theta) < tol.NEAR_PI_RAD
    generic = ~(small | near_pi)
    out = np.zeros(R.shape[:-2] + (3,))
    # generic: axis from the skew-symmetric part
    scale = np.where(generic, theta / (2.0 * np.where(generic, sin_t, 1.0)), 0.5)
    out = np.where((generic | small)[..., None], scale[..., None] * vee, out)
    if np.any(near_pi):
        # near pi the skew part vanishes; the symmetric part is cos(t) I + (1 - cos(t)) n n^T,
        # so read n from the largest column of n n^T, then fix its sign with the skew part
        Rp = R[near_pi]
        cos_t = np.cos(theta[near_pi])[:, None, None]
        B = ((Rp + np.swapaxes(Rp, -1, -2)) / 2.0 - cos_t * np.eye(3)) / (1.0 - cos_t)
        col = np.argmax(np.diagonal(B, axis1=-2, axis2=-1), axis=-1)
        n = B[np.arange(len(Rp)), :, col]
        n /= np.linalg.norm(n, axis=-1, keepdims=True)
        sign = np.sign(np.einsum("ni,ni->n", n, vee[near_pi]))
        n *= np.where(sign == 0, 1.0, sign)[:, None]
        out[near_pi] = n * theta[near_pi][:, None]
    return out


def make_transform(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Stack rotations and translations into 4x4 transforms.

    Args:
        R: (..., 3, 3) float rotation.
        t: (..., 3) float translation.

    Returns:
        (..., 4, 4) float64.
    """
    R = check_last_axes(R, (3, 3), "R")
    t = check_last_axes(t, (3,), "t")
    batch = np.broadcast_shapes(R.shape[:-2], t.shape[:-1])
    T = np.zeros(batch + (4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = t
    T[..., 3, 3] = 1.0
    return T


def invert_transform(T_a_b: np.ndarray) -> np.ndarray:
    """Inverse of rigid 4x4 transforms: returns ``T_b_a``.

    Args:
        T_a_b: (..., 4, 4) float rigid transforms.

    Returns:
        (..., 4, 4) float64.
    """
    T_a_b = check_last_axes(T_a_b, (4, 4), "T_a_b")
    R = T_a_b[..., :3, :3]
    Rt = np.swapaxes(R, -1, -2)
    return make_transform(Rt, -np.einsum("...ij,...j->...i", Rt, T_a_b[..., :3, 3]))


def transform_points(T_a_b: np.ndarray, points_b: np.ndarray) -> np.ndarray:
    """Apply rigid transforms to points.

    Args:
        T_a_b: (4, 4) or (B, 4, 4) float.
        points_b: (N, 3) or (B, N, 3) float, points in frame b.

    Returns:
        (..., N, 3) float64 points in frame a.
    """
    T_a_b = check_last_axes(T_a_b, (4, 4), "T_a_b")
    points_b = check_last_axes(points_b, (3,), "points_b")
    return np.einsum("...ij,...nj->...ni", T_a_b[..., :3, :3], points_b) + T_a_b[..., None, :3, 3]


def euler_to_matrix(angles: np.ndarray, order: str = "xyz") -> np.ndarray:
    """Intrinsic Euler angles to rotation matrices.

    Args:
        angles: (..., 3) float, radians, applied about the moving axes in ``order``.
        order: three letters from "xyz", e.g. "xyz" means R = Rx(a0) Ry(a1) Rz(a2).

    Returns:
        (..., 3, 3) float64.
    """
    assert len(order) == 3 and not set(order) - set("xyz"), order
    angles = check_last_axes(angles, (3,), "angles")
    R = np.broadcast_to(np.eye(3), angles.shape[:-1] + (3, 3)).copy()
    for k, axis in enumerate(order):
        v = np.zeros(angles.shape[:-1] + (3,))
        v[..., "xyz".index(axis)] = angles[..., k]
        R = R @ axis_angle_to_matrix(v)
    return R


def matrix_to_euler_xyz(R: np.ndarray) -> np.ndarray:
    """Inverse of ``euler_to_matrix(angles, "xyz")``.

    Args:
        R: (..., 3, 3) float rotation matrices.

    Returns:
        (..., 3) float64 angles (a, b, c), radians, with R = Rx(a) Ry(b) Rz(c),
        b in [-pi/2, pi/2]. At b = +-pi/2 (gimbal lock) c is set to 0.
    """
    R = as_rotation(R)
    cos_b = np.hypot(R[..., 0, 0], R[..., 0, 1])
    b = np.arctan2(R[..., 0, 2], cos_b)
    locked = cos_b < tol.SMALL_ANGLE_RAD
    a = np.where(locked, np.arctan2(R[..., 2, 1], R[..., 1, 1]), np.arctan2(-R[..., 1, 2], R[..., 2, 2]))
    c = np.where(locked, 0.0, np.arctan2(-R[..., 0, 1], R[..., 0, 0]))
    return np.stack([a, b, c], axis=-1)


def proper_rotation(cov: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Kabsch on (N, 3, 3) Y^T X: the proper rotations R (N, 3, 3) minimising |Y - X R^T|, the singular values
    (N, 3) and the reflection fix d (N,) of the SVD."""
    u, s, vt = np.linalg.svd(cov)
    d = np.where(np.linalg.det(u) * np.linalg.det(vt) < 0.0, -1.0, 1.0)         # (N,) reflection fix
    u[:, :, 2] *= d[:, None]                                                     # U D
    return u @ vt, s, d


def rotation_onto(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """(N, 3, 3) float64 proper rotations R turning each centred (N, K, 3) ``src`` onto its centred ``dst``
    (minimising |dst_c - src_c R^T|, no scale: Kabsch, "A solution for the best rotation to relate two sets of
    vectors", Acta Crystallographica A32, 1976)."""
    x = np.asarray(src, np.float64) - np.asarray(src, np.float64).mean(axis=1, keepdims=True)
    y = np.asarray(dst, np.float64) - np.asarray(dst, np.float64).mean(axis=1, keepdims=True)
    return proper_rotation(np.einsum("nki,nkj->nij", y, x))[0]


def fit_rigid_pose(points_obj_m: np.ndarray, points_cam_m: np.ndarray) -> np.ndarray:
    """(N, 4, 4) float64 T_cam_obj: the rotation and translation (Kabsch, :func:`rotation_onto`, no scale) that
    best map object-frame points onto each frame's (N, K, 3) observed camera-frame points (metres, K >= 3 not
    collinear) in the least-squares sense. ``points_obj_m``: (K, 3), the same known points for every frame, or
    (N, K, 3), one set per frame (e.g. a prediction aligned onto the truth)."""
    cam = np.asarray(points_cam_m, np.float64)
    obj = np.broadcast_to(np.asarray(points_obj_m, np.float64), cam.shape)
    assert cam.ndim == 3 and cam.shape[-1] == 3, (np.shape(points_obj_m), cam.shape)
    rot = rotation_onto(obj, cam)                                                # (N, 3, 3)
    T = np.tile(np.eye(4), (len(cam), 1, 1))
    T[:, :3, :3] = rot
    # t = mean(cam) - R mean(obj)
    T[:, :3, 3] = cam.mean(axis=1) - np.einsum("nij,nj->ni", rot, obj.mean(axis=1))
    return T
