"""The grasp parameter vector shared by the refinement optimiser and the CVAE sampler.

A grasp in the generator frame is 54 numbers:
``[rot6d (6) | trans (3) | joint_unit (15 x 3 = 45)]``:

- rot6d: the hand's global rotation (hand frame -> generator frame), first
  two columns of the matrix;
- trans: wrist position in the generator frame, metres;
- joint_unit: each anatomical angle (flexion, abduction, twist) of MANO
  joints 1..15 mapped linearly from its [min, max] limit to [0, 1].

Convention:
    Generator frame: the probe rotated by its Euler angles Theta_Vol and
    centred at its volume centroid (GrabNet's object-centric frame); see
    :mod:`hupbench.datagen.grasps.frames`. Radians and metres.
"""

from __future__ import annotations

import torch

from hupbench.core.rotations_torch import matrix_to_rot6d, rot6d_to_matrix

PARAM_DIM = 54
ROT, TRANS, JOINTS = slice(0, 6), slice(6, 9), slice(9, 54)


def pack(R_global: torch.Tensor, trans: torch.Tensor, joint_unit: torch.Tensor) -> torch.Tensor:
    """(..., 3, 3), (..., 3), (..., 15, 3) -> (..., 54)."""
    return torch.cat([matrix_to_rot6d(R_global), trans, joint_unit.flatten(-2)], dim=-1)


def unpack(x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(..., 54) -> R_global (..., 3, 3), trans (..., 3), joint_unit (..., 15, 3) clamped to [0, 1]."""
    assert x.shape[-1] == PARAM_DIM, x.shape
    joint_unit = x[..., JOINTS].reshape(x.shape[:-1] + (15, 3)).clamp(0.0, 1.0)
    return rot6d_to_matrix(x[..., ROT]), x[..., TRANS], joint_unit


def unit_to_angles(joint_unit: torch.Tensor, limits: torch.Tensor) -> torch.Tensor:
    """(..., 15, 3) in [0, 1] -> anatomical angles, radians; limits (15, 3, 2)."""
    return limits[..., 0] + joint_unit * (limits[..., 1] - limits[..., 0])
