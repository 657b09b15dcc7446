"""The fixed affine map from a network's raw 3D output to the training target's units.

Absolute camera-frame keypoints sit 0.4-0.9 m in front of the camera and span
a few centimetres; a head that starts at zero would spend hundreds of Adam
steps just moving its bias to the mean depth. Models therefore predict an
offset from a prior keypoint layout (e.g. the training split's mean), in
units of ``scale``: ``points3d = raw * scale + mean``. Both are fixed buffers
saved in the model's config, so a checkpoint or an ONNX export reproduces
them without the training data.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from torch import nn

__all__ = ["PointPrior"]


class PointPrior(nn.Module):
    """``raw * scale + mean``, per keypoint.

    Args:
        n_keypoints: N.
        mean: (N, 3) nested sequence of floats (target units, e.g. metres), or None for zeros.
        scale: positive float, target units per raw output unit.
    """

    def __init__(self, n_keypoints: int, mean: Sequence[Sequence[float]] | None = None, scale: float = 1.0) -> None:
        super().__init__()
        if isinstance(scale, bool) or not isinstance(scale, (int, float)) or not math.isfinite(scale) or scale <= 0:
            raise ValueError(f"points3d_scale must be a positive finite number, got {scale!r}")
        if mean is None:
            mean_tensor = torch.zeros(n_keypoints, 3)
        else:
            mean_tensor = torch.as_tensor([[float(v) for v in row] for row in mean], dtype=torch.float32)
            if mean_tensor.shape != (n_keypoints, 3):
                raise ValueError(f"points3d_mean must be ({n_keypoints}, 3), got {tuple(mean_tensor.shape)}")
            if not torch.isfinite(mean_tensor).all():
                raise ValueError("points3d_mean must be finite")
        self.register_buffer("mean", mean_tensor)
        self.scale = float(scale)

    def forward(self, raw: torch.Tensor) -> torch.Tensor:
        """(B, N, 3) raw output -> (B, N, 3) points in the target's units."""
        return raw * self.scale + self.mean.to(raw.dtype)

    @staticmethod
    def config_value(mean: Sequence[Sequence[float]] | None) -> list[list[float]] | None:
        """``mean`` as a plain nested list for a model config (None stays None)."""
        return None if mean is None else [[float(v) for v in row] for row in mean]
