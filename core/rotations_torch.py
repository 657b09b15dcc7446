"""Differentiable rotations in torch (the counterparts of :mod:`hupbench.core.geometry`).

Convention:
    As in :mod:`hupbench.core.geometry`: matrices act on column vectors, axis-angle
    rotates right-handed by its norm in radians, intrinsic Euler "xyz" means
    R = Rx(a) Ry(b) Rz(c). The 6D representation is the first two columns of
    R (Zhou et al.), turned back into R by Gram-Schmidt.
"""

from __future__ import annotations

import torch

# added under the square root so that the angle's gradient stays finite at zero rotation
_EPS2 = 1e-24


def skew(v: torch.Tensor) -> torch.Tensor:
    """(..., 3) -> (..., 3, 3) cross-product matrices."""
    zero = torch.zeros_like(v[..., 0])
    x, y, z = v.unbind(-1)
    return torch.stack([zero, -z, y, z, zero, -x, -y, x, zero], dim=-1).reshape(v.shape[:-1] + (3, 3))


def axis_angle_to_matrix(axis_angle: torch.Tensor) -> torch.Tensor:
    """Rodrigues' formula with finite values and gradients at zero angle.

    Args:
        axis_angle: (..., 3) float, radians.

    Returns:
        (..., 3, 3) rotation matrices, same dtype and device.
    """
    theta = torch.sqrt((axis_angle * axis_angle).sum(-1) + _EPS2)[..., None, None]
    K = skew(axis_angle)
    eye = torch.eye(3, dtype=axis_angle.dtype, device=axis_angle.device)
    return eye + torch.sin(theta) / theta * K + (1.0 - torch.cos(theta)) / theta**2 * (K @ K)


def euler_xyz_to_matrix(angles: torch.Tensor) -> torch.Tensor:
    """Intrinsic x-y-z Euler angles (..., 3), radians -> (..., 3, 3)."""
    a, b, c = angles.unbind(-1)
    ca, sa, cb, sb, cc, sc = torch.cos(a), torch.sin(a), torch.cos(b), torch.sin(b), torch.cos(c), torch.sin(c)
    rows = [
        cb * cc, -cb * sc, sb,
        ca * sc + sa * sb * cc, ca * cc - sa * sb * sc, -sa * cb,
        sa * sc - ca * sb * cc, sa * cc + ca * sb * sc, ca * cb,
    ]
    return torch.stack(rows, dim=-1).reshape(angles.shape[:-1] + (3, 3))


def rot6d_to_matrix(rot6d: torch.Tensor) -> torch.Tensor:
    """6D rotation (..., 6) = two stacked columns -> (..., 3, 3) by Gram-Schmidt."""
    a1, a2 = rot6d[..., :3], rot6d[..., 3:]
    b1 = a1 / torch.linalg.norm(a1, dim=-1, keepdim=True).clamp_min(1e-12)
    a2 = a2 - (b1 * a2).sum(-1, keepdim=True) * b1
    b2 = a2 / torch.linalg.norm(a2, dim=-1, keepdim=True).clamp_min(1e-12)
    b3 = torch.linalg.cross(b1, b2, dim=-1)
    return torch.stack([b1, b2, b3], dim=-1)


def matrix_to_rot6d(R: torch.Tensor) -> torch.Tensor:
    """(..., 3, 3) -> (..., 6): the first two columns."""
    return torch.cat([R[..., :, 0], R[..., :, 1]], dim=-1)
