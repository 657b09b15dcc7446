"""Normalised image coordinates: the 2D unit of every model in this package.

Convention:
    Pixel coordinates follow OpenCV (and :class:`datagen.camera.Intrinsics`):
    pixel centres at integers, so a W-pixel-wide image spans
    [-0.5, W - 0.5]. Normalised coordinates map that span to [-1, 1]:
    x_norm = (2 u + 1) / W - 1, y_norm = (2 v + 1) / H - 1, so -1 is the
    left (top) edge of the image and +1 the right (bottom) edge, as in
    ``torch.nn.functional.grid_sample(..., align_corners=False)``. A point
    keeps its normalised coordinates when the image is resized, which is why
    the models predict them: labels cannot be left in the pixels of another
    image size. Points outside the image fall outside [-1, 1].
"""

from __future__ import annotations

import torch

__all__ = ["normalized_to_pixels", "pixels_to_normalized"]


def _check(points: torch.Tensor, width: int, height: int, name: str) -> None:
    if not isinstance(points, torch.Tensor):
        raise TypeError(f"{name} must be a torch.Tensor, got {type(points).__name__}")
    if points.ndim < 1 or points.shape[-1] != 2:
        raise ValueError(f"{name} must be (..., 2), got {tuple(points.shape)}")
    if not points.is_floating_point():
        raise TypeError(f"{name} must be a floating-point tensor, got {points.dtype}")
    for label, size in (("width", width), ("height", height)):
        if not isinstance(size, int) or isinstance(size, bool) or size < 1:
            raise ValueError(f"{label} must be a positive int (pixels), got {size!r}")


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
    _check(points_px, width, height, "points_px")
    size = points_px.new_tensor([width, height])
    return (2.0 * points_px + 1.0) / size - 1.0


def normalized_to_pixels(points_norm: torch.Tensor, width: int, height: int) -> torch.Tensor:
    """Normalised image coordinates -> pixel coordinates of a ``width`` x ``height`` image.

    Args:
        points_norm: (..., 2) float, (x, y), [-1, 1] across the image.
        width: W, image width in pixels.
        height: H, image height in pixels.

    Returns:
        (..., 2) float, (u, v) pixels, pixel centres at integers.
    """
    _check(points_norm, width, height, "points_norm")
    size = points_norm.new_tensor([width, height])
    return ((points_norm + 1.0) * size - 1.0) / 2.0
