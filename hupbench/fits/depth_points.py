"""The depth input as the fits read it: its pixels with a surface, unprojected to camera-frame points, a fixed sample of
those a fit uses, and fitted points projected back to the model input. Numpy only (a fit unprojects only the pixels
it looks at: at batch 1 every array operation over the whole map costs).

Convention: the camera of the model input (``K_input``, pixels, OpenCV axes), depth in metres along its optical
axis, 0 where the map has no surface (no depth: unknown, never far).
"""

from __future__ import annotations

import functools

import numpy as np

from hupbench.input_geometry import pixels_to_normalized

__all__ = ["MIN_PROJECTION_Z_M", "input_pixels", "input_points2d", "pixel_order", "sample_points", "surface_pixels",
           "unproject_pixels", "unproject_uv"]

#: points nearer the camera than this are projected as if at it, metres (a fit that moved a point behind the
#: camera keeps finite 2D points)
MIN_PROJECTION_Z_M = 1e-3


def unproject_uv(u: np.ndarray, v: np.ndarray, z: np.ndarray, K: np.ndarray) -> np.ndarray:
    """(..., 3) float64 camera-frame points, metres, of the pixels (u, v) (...) at depths ``z`` (...) metres along the
    optical axis; ``K``: (3, 3). The inverse of :func:`input_pixels` for z at least :data:`MIN_PROJECTION_Z_M`."""
    K = np.asarray(K, dtype=np.float64)
    return np.stack([(u - K[0, 2]) / K[0, 0] * z, (v - K[1, 2]) / K[1, 1] * z, z], -1)


def unproject_pixels(depth: np.ndarray, K: np.ndarray, index: np.ndarray) -> np.ndarray:
    """(N, 3) float64 camera-frame points, metres, of the pixels ``index`` (N,) int (row by row: v * S + u) of the
    depth map ``depth`` (S, S) metres; a pixel without a surface is the camera's centre (z = 0). ``K``: (3, 3)."""
    z = np.asarray(depth, dtype=np.float64).reshape(-1)[index]
    v, u = np.divmod(index, depth.shape[-1])
    return unproject_uv(u, v, z, K)


def surface_pixels(depth: np.ndarray, allowed: np.ndarray | None = None) -> np.ndarray:
    """(B, S * S) bool: the pixels of the depth maps ``depth`` (B, S, S) with a surface (depth above 0), among
    ``allowed`` (B, S, S) bool where given (a segmentation's pixels of one object)."""
    wanted = np.asarray(depth).reshape(len(depth), -1) > 0
    return wanted if allowed is None else wanted & np.asarray(allowed, dtype=bool).reshape(len(depth), -1)


@functools.lru_cache(maxsize=8)
def pixel_order(count: int) -> np.ndarray:
    """(count,) int64: the fixed pseudo-random order in which :func:`sample_points` takes a frame's points."""
    order = np.random.default_rng(0).permutation(count)
    order.flags.writeable = False
    return order


def sample_points(depth: np.ndarray, K: np.ndarray, wanted: np.ndarray, max_points: int
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Up to ``max_points`` of the ``wanted`` (B, S * S) bool pixels of the depth maps ``depth`` (B, S, S), in a fixed
    pseudo-random order that is the same for every frame (a fit's result does not depend on the batch), unprojected
    with ``K`` (:func:`unproject_pixels`): (B, M, 3) points and their (B, M) float64 weights (1 a wanted pixel's
    point, 0 padding at the end), M = min(``max_points``, S * S)."""
    B, P = wanted.shape
    M = min(max_points, P)
    order = pixel_order(P)
    chosen, weight = np.zeros((B, M, 3)), np.zeros((B, M))
    for b in range(B):
        take = order[wanted[b, order]][:M]
        chosen[b, :len(take)], weight[b, :len(take)] = unproject_pixels(depth[b], K, take), 1.0
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
