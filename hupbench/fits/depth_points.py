"""The depth input as the fits read it: its pixels unprojected to camera-frame points, a fixed sample of those a fit
uses, and fitted points projected back to the model input. Numpy only.

Convention: the camera of the model input (``K_input``, pixels, OpenCV axes), depth in metres along its optical
axis, 0 where the map has no surface (no depth: unknown, never far).
"""

from __future__ import annotations

import functools

import numpy as np

from hupbench.input_geometry import pixels_to_normalized

__all__ = ["MIN_PROJECTION_Z_M", "input_pixels", "input_points2d", "pixel_order", "sample_points", "unproject_depth"]

#: points nearer the camera than this are projected as if at it, metres (a fit that moved a point behind the
#: camera keeps finite 2D points)
MIN_PROJECTION_Z_M = 1e-3


def unproject_depth(depth: np.ndarray, K: np.ndarray) -> np.ndarray:
    """(B, S * S, 3) float64 camera-frame points, metres, of every pixel of the depth maps ``depth`` (B, S, S) metres,
    row by row; a pixel without a surface is the camera's centre (z = 0). ``K``: (3, 3)."""
    B, S, _ = depth.shape
    K = np.asarray(K, dtype=np.float64)
    v, u = np.mgrid[0:S, 0:S].astype(np.float64)
    z = np.asarray(depth, dtype=np.float64).reshape(B, -1)
    return np.stack([(u.ravel() - K[0, 2]) / K[0, 0] * z, (v.ravel() - K[1, 2]) / K[1, 1] * z, z], -1)


@functools.lru_cache(maxsize=8)
def pixel_order(count: int) -> np.ndarray:
    """(count,) int64: the fixed pseudo-random order in which :func:`sample_points` takes a frame's points."""
    order = np.random.default_rng(0).permutation(count)
    order.flags.writeable = False
    return order


def sample_points(points: np.ndarray, wanted: np.ndarray, max_points: int) -> tuple[np.ndarray, np.ndarray]:
    """Up to ``max_points`` of the ``wanted`` (B, P) bool of ``points`` (B, P, 3), in a fixed pseudo-random order that
    is the same for every frame (a fit's result does not depend on the batch): (B, M, 3) points and their (B, M)
    float64 weights (1 a wanted point, 0 padding at the end), M = min(``max_points``, P)."""
    B, P, _ = points.shape
    M = min(max_points, P)
    order = pixel_order(P)
    chosen, weight = np.zeros((B, M, 3)), np.zeros((B, M))
    for b in range(B):
        take = order[wanted[b, order]][:M]
        chosen[b, :len(take)], weight[b, :len(take)] = points[b, take], 1.0
    return chosen, weight


def input_pixels(points_cam: np.ndarray, K_input: np.ndarray) -> np.ndarray:
    """(..., 2) float64 pixels (u, v) of camera-frame points (..., 3) metres, projected with the (3, 3) ``K_input``
    (z at least :data:`MIN_PROJECTION_Z_M`)."""
    K = np.asarray(K_input, dtype=np.float64)
    z = np.maximum(points_cam[..., 2], MIN_PROJECTION_Z_M)
    return np.stack([K[0, 0] * points_cam[..., 0] / z + K[0, 2], K[1, 1] * points_cam[..., 1] / z + K[1, 2]], -1)


def input_points2d(points_cam: np.ndarray, K_input: np.ndarray, size: int) -> np.ndarray:
    """(..., 2) float64 normalised input coordinates of camera-frame points (..., 3) metres, projected with the
    (3, 3) ``K_input`` of the ``size`` px model input (:func:`input_pixels`)."""
    return pixels_to_normalized(input_pixels(points_cam, K_input), size)
