"""Normalised image coordinates: the 2D unit of every model in this package.

Convention:
    Pixel coordinates follow OpenCV (and :class:`hupbench.core.camera.Intrinsics`):
    pixel centres at integers, so a W-pixel-wide image spans
    [-0.5, W - 0.5]. Normalised coordinates map that span to [-1, 1]:
    x_norm = (2 u + 1) / W - 1, y_norm = (2 v + 1) / H - 1, so -1 is the
    left (top) edge of the image and +1 the right (bottom) edge, as in
    ``torch.nn.functional.grid_sample(..., align_corners=False)``. A point
    keeps its normalised coordinates when the image is resized, which is why
    the models predict them: labels cannot be left in the pixels of another
    image size. Points outside the image fall outside [-1, 1].

The torch twin of :mod:`hupbench.input_geometry` (models import nothing of hupbench); a test holds the
two equal.
"""

from __future__ import annotations

import torch

__all__ = ["normalized_to_pixels", "pixels_to_normalized"]


def _size(points: torch.Tensor, width: int, height: int) -> torch.Tensor:
    """(2,) tensor (W, H) beside ``points``, a (..., 2) floating-point tensor."""
    assert points.is_floating_point() and points.shape[-1:] == (2,), (points.dtype, tuple(points.shape))
    return points.new_tensor([width, height])


def pixels_to_normalized(points_px: torch.Tensor, width: int, height: int) -> torch.Tensor:
    """Pixel coordinates of an image -> normalised image coordinates.

    Args:
        points_px: (..., 2) float, (u, v) pixels of a ``width`` x ``height`` image,
            pixel centres at integers.
        width: W, image width in pixels.
        height: H, image height in pixels.

    Returns:
        (..., 2) float, (x, y) in [-1, 1] inside the image.
    """
    return (2.0 * points_px + 1.0) / _size(points_px, width, height) - 1.0


def normalized_to_pixels(points_norm: torch.Tensor, width: int, height: int) -> torch.Tensor:
    """Normalised image coordinates -> pixel coordinates of a ``width`` x ``height`` image.

    Args:
        points_norm: (..., 2) float, (x, y), [-1, 1] across the image.
        width: W, image width in pixels.
        height: H, image height in pixels.

    Returns:
        (..., 2) float, (u, v) pixels, pixel centres at integers.
    """
    return ((points_norm + 1.0) * _size(points_norm, width, height) - 1.0) / 2.0
