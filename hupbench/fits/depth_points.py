"""The depth input as the fits read it: its pixels unprojected to camera-frame points, a fixed sample of those a fit
uses, and fitted points projected back to the model input.

Convention: the camera of the model input (``K_input``, pixels, OpenCV axes), depth in metres along its optical
axis, 0 where the map has no surface.
"""

from __future__ import annotations

import numpy as np
import torch

from hupbench.input_geometry import pixels_to_normalized

__all__ = ["MIN_PROJECTION_Z_M", "input_points2d", "sample_points", "unproject_depth"]

#: points nearer the camera than this are projected as if at it, metres (a fit that moved a point behind the
#: camera keeps finite 2D points)
MIN_PROJECTION_Z_M = 1e-3


def unproject_depth(depth: torch.Tensor, K: torch.Tensor) -> torch.Tensor:
    """(B, S * S, 3) float32 camera-frame points, metres, of every pixel of the depth maps ``depth`` (B, S, S) float32
    metres, row by row; a pixel without a surface is the camera's centre (z = 0). ``K``: (3, 3) float32."""
    B, S, _ = depth.shape
    v, u = torch.meshgrid(torch.arange(S, dtype=torch.float32), torch.arange(S, dtype=torch.float32), indexing="ij")
    z = depth.reshape(B, -1)
    return torch.stack([(u.reshape(-1) - K[0, 2]) / K[0, 0] * z, (v.reshape(-1) - K[1, 2]) / K[1, 1] * z, z], -1)


def sample_points(points: torch.Tensor, wanted: torch.Tensor, max_points: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Up to ``max_points`` of the ``wanted`` (B, P) bool of ``points`` (B, P, 3), in a fixed pseudo-random order that
    is the same for every frame (a fit's result does not depend on the batch): (B, M, 3) points and their (B, M)
    float32 weights (1 a wanted point, 0 padding), M = min(``max_points``, P)."""
    order = torch.rand(points.shape[1], generator=torch.Generator().manual_seed(0))
    keys = torch.where(wanted, order + 1.0, torch.zeros_like(order))
    top = keys.topk(min(max_points, points.shape[1]), dim=1).indices
    return torch.gather(points, 1, top[..., None].expand(-1, -1, 3)), torch.gather(wanted, 1, top).float()


def input_points2d(points_cam: np.ndarray, K_input: np.ndarray, size: int) -> np.ndarray:
    """(..., 2) float64 normalised input coordinates of camera-frame points (..., 3) metres, projected with the
    (3, 3) ``K_input`` of the ``size`` px model input (z at least :data:`MIN_PROJECTION_Z_M`)."""
    K = np.asarray(K_input, dtype=np.float64)
    z = np.maximum(points_cam[..., 2], MIN_PROJECTION_Z_M)
    uv = np.stack([K[0, 0] * points_cam[..., 0] / z + K[0, 2], K[1, 1] * points_cam[..., 1] / z + K[1, 2]], -1)
    return pixels_to_normalized(uv, size)
