"""The geometry of the model input: normalised coordinates, the inside-the-input test, pad-and-resize and
the in-plane rotation, each written once for the reader, the augmentation, export, metrics and predict.

Convention:
    Pixels follow OpenCV (:mod:`hupbench.core.camera`): pixel centres at integers, so an S-pixel side spans
    [-0.5, S - 0.5]. Normalised coordinates map that span to [-1, 1]: x_n = (2 u + 1) / S - 1, as
    ``grid_sample(..., align_corners=False)``; a point keeps them when the image is resized, which is
    why the models predict them. A 3 x 3 "pixel map" A sends homogeneous pixels (u, v, 1) to A (u, v, 1)
    and intrinsics K to A @ K. An in-plane rotation by ``angle`` radians turns the image content
    counter-clockwise on screen (y down) about a centre, and the camera-frame points by -angle about +z.

Numpy and OpenCV only (the torch-free predict path imports it); :func:`pixels_to_normalized`,
:func:`normalized_to_pixels` and :func:`inside_input` use operators only, so torch tensors pass through
them too. ``hupbench.models.coords`` holds the torch twin, tested against this module.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from hupbench.core.camera import resize_intrinsics

__all__ = ["DEPTH_CLIP_M", "INPUT_MODALITIES", "INPUT_SIZE_RANGE", "InputGeometry", "apply_affine", "camera_rotation",
           "depth_channel", "inside_input",
           "normalized_to_pixels", "pad_and_resize", "pixels_to_normalized", "rotation_pixel_map"]

#: the model input side S, pixels: below 16 the backbones' five stride-2 stages leave nothing; above 2048 a
#: split's frame cache (N x S x S x 3 bytes) outgrows any disk long before a model could use the detail
INPUT_SIZE_RANGE = (16, 2048)
#: what a model reads (``data.reader.input_modalities``) -> the channels of its input tensor: RGB in [0, 1],
#: then the depth channel (:func:`depth_channel`)
INPUT_MODALITIES = {"rgb": 3, "rgb+depth": 4}
#: the depth channel's ceiling, metres: a camera 0.45-0.8 m from the hand sees nothing of it beyond 2 m
DEPTH_CLIP_M = 2.0


def depth_channel(depth: np.ndarray, scale_m: float) -> np.ndarray:
    """The model's depth channel from a stored depth map: (H, W) float32 metres, ``depth * scale_m`` clipped to
    [0, DEPTH_CLIP_M], 0 where no surface was rendered (the dataset's 0).

    Metres as they are, not a per-image min-max: the absolute distance is what pins a keypoint's depth, and
    at the dataset's 0.45-0.8 m the values span the same order as the RGB channels' [0, 1]. A depth map is
    resized with ``cv2.INTER_NEAREST`` (:func:`pad_and_resize`), so every value is that of a real surface.
    """
    return np.clip(np.asarray(depth, dtype=np.float32) * np.float32(scale_m), 0.0, DEPTH_CLIP_M)


def _size(size):
    """S as is (a scalar), or (W, H) as a float64 (2,) array for non-square images."""
    return size if np.ndim(size) == 0 else np.asarray(size, dtype=np.float64)


def pixels_to_normalized(uv, size):
    """(..., 2) float pixels (numpy, or a torch tensor with an int ``size``) of an image of side ``size``
    (S, or (W, H)) -> (..., 2) normalised coordinates, x_n = (2 u + 1) / S - 1."""
    return (2.0 * uv + 1.0) / _size(size) - 1.0


def normalized_to_pixels(xy_norm, size):
    """(..., 2) normalised coordinates -> (..., 2) pixels, u = ((x_n + 1) S - 1) / 2 (the inverse of
    :func:`pixels_to_normalized`)."""
    return ((xy_norm + 1.0) * _size(size) - 1.0) / 2.0


def inside_input(uv, size):
    """(...,) bool: whether (..., 2) input pixels (numpy or torch) lie on the S x S input, in [-0.5, S - 0.5)."""
    return ((uv >= -0.5) & (uv < size - 0.5)).all(axis=-1)


def apply_affine(matrix: np.ndarray, uv) -> np.ndarray:
    """(..., 2) float64 pixels: ``uv`` (..., 2) through a (3, 3) pixel map, or (B, N, 2) through (B, 3, 3)."""
    uv = np.asarray(uv, dtype=np.float64)
    if matrix.ndim == 2:
        return uv @ matrix[:2, :2].T + matrix[:2, 2]
    return uv @ np.swapaxes(matrix[:, :2, :2], 1, 2) + matrix[:, None, :2, 2]


def rotation_pixel_map(angle, centre) -> np.ndarray:
    """(3, 3) or (B, 3, 3) float64 pixel map of the in-plane rotation by a scalar or (B,) ``angle`` (radians,
    counter-clockwise on screen) about a (2,) or (B, 2) ``centre`` (pixels, the principal point):
    ``cv2.getRotationMatrix2D(centre, degrees(angle), 1)`` plus the row (0, 0, 1)."""
    c, s = np.cos(angle), np.sin(angle)
    centre = np.asarray(centre, dtype=np.float64)
    cx, cy = centre[..., 0], centre[..., 1]
    zero, one = np.zeros_like(c), np.ones_like(c)
    return np.stack([np.stack([c, s, (1 - c) * cx - s * cy], -1), np.stack([-s, c, s * cx + (1 - c) * cy], -1),
                     np.stack([zero, zero, one], -1)], -2)


def camera_rotation(angle) -> np.ndarray:
    """(3, 3) or (B, 3, 3) float64: the camera-frame rotation matching :func:`rotation_pixel_map` of a scalar
    or (B,) ``angle`` (radians), -angle about +z; exact for square pixels (fx == fy) about the principal point."""
    return rotation_pixel_map(angle, np.zeros(np.shape(angle) + (2,)))


@dataclass(frozen=True)
class InputGeometry:
    """How an H x W image becomes the S x S model input: centred padding to a square, then a resize.

    With L = max(H, W), s = S / L and pad = (pad_left, pad_top):
    ``u_in = (u + pad_left + 0.5) s - 0.5`` (:func:`hupbench.core.camera.resize_intrinsics`). Padding keeps
    every pixel, so a hand near the border of a wide photo stays in view.

    Attributes:
        width: W, image width, pixels. height: H, pixels. input_size: S, pixels.
    """

    width: int
    height: int
    input_size: int

    def __post_init__(self) -> None:
        assert min(self.width, self.height, self.input_size) >= 1, self

    @property
    def side(self) -> int:
        """L = max(H, W), side of the padded square, image pixels."""
        return max(self.width, self.height)

    @property
    def pad_left(self) -> int:
        return (self.side - self.width) // 2

    @property
    def pad_top(self) -> int:
        return (self.side - self.height) // 2

    @property
    def scale(self) -> float:
        """s = S / L, input pixels per image pixel."""
        return self.input_size / self.side

    @property
    def image_to_input(self) -> np.ndarray:
        """(3, 3) pixel map, image -> input pixels: the identity's intrinsics under ``resize_intrinsics``."""
        return resize_intrinsics(np.eye(3), self.scale, (self.pad_left, self.pad_top))

    @property
    def input_to_image(self) -> np.ndarray:
        """(3, 3) pixel map, input -> image pixels."""
        return np.linalg.inv(self.image_to_input)

    def normalized_to_input_px(self, xy_norm) -> np.ndarray:
        """(..., 2) normalised input coordinates -> (..., 2) input pixels."""
        return normalized_to_pixels(np.asarray(xy_norm, dtype=np.float64), self.input_size)

    def normalized_to_image_px(self, xy_norm) -> np.ndarray:
        """(..., 2) normalised input coordinates -> (..., 2) image pixels."""
        return apply_affine(self.input_to_image, self.normalized_to_input_px(xy_norm))

    def intrinsics_to_input(self, K: np.ndarray) -> np.ndarray:
        """(3, 3) intrinsics of the image -> (3, 3) float64 intrinsics of the input."""
        return self.image_to_input @ np.asarray(K, dtype=np.float64)

    def intrinsics_to_image(self, K_in: np.ndarray) -> np.ndarray:
        """(3, 3) intrinsics of the input -> (3, 3) float64 intrinsics of the image."""
        return self.input_to_image @ np.asarray(K_in, dtype=np.float64)

    def as_dict(self) -> dict[str, Any]:
        return {"side": self.side, "pad_left": self.pad_left, "pad_top": self.pad_top, "scale": self.scale}


def pad_and_resize(image: np.ndarray, input_size: int, pad_value: float = 0.0,
                   interpolation: int = cv2.INTER_AREA) -> tuple[np.ndarray, InputGeometry]:
    """(S, S, C) image of the same dtype, and its :class:`InputGeometry`: an (H, W, C) or (H, W) uint8, uint16 or
    float32 image (C <= 4) padded to a centred square with ``pad_value`` (in its own unit) and resized
    (``cv2.INTER_AREA`` for colours; ``cv2.INTER_NEAREST`` keeps a depth map's values those of real surfaces)."""
    height, width = image.shape[:2]
    geometry = InputGeometry(width=width, height=height, input_size=input_size)
    if width != height:
        square = cv2.copyMakeBorder(image, geometry.pad_top, geometry.side - height - geometry.pad_top,
                                    geometry.pad_left, geometry.side - width - geometry.pad_left,
                                    cv2.BORDER_CONSTANT, value=(pad_value,) * 4)
        image = square.reshape(geometry.side, geometry.side, *image.shape[2:])
    if geometry.side != input_size:
        image = cv2.resize(image, (input_size, input_size), interpolation=interpolation).reshape(
            input_size, input_size, *image.shape[2:])
    return image, geometry
