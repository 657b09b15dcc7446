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

from collections.abc import Sequence

import torch
from torch import nn

__all__ = ["PointPrior"]


class PointPrior(nn.Module):
    """``raw * scale + mean``, per keypoint.

    Args:
        n_keypoints: N.
        mean: (N, 3) nested sequence of finite floats (target units, e.g. metres), or None for zeros.
        scale: positive finite float, target units per raw output unit.
    """

    def __init__(self, n_keypoints: int, mean: Sequence[Sequence[float]] | None = None, scale: float = 1.0) -> None:
        super().__init__()
        # checked by the model's config (hupbench.models.model_config.ModelConfig)
        self.register_buffer("mean", torch.zeros(n_keypoints, 3) if mean is None else
                             torch.as_tensor(mean, dtype=torch.float32))
        self.scale = float(scale)

    def forward(self, raw: torch.Tensor) -> torch.Tensor:
        """(B, N, 3) raw output -> (B, N, 3) points in the target's units."""
        return raw * self.scale + self.mean.to(raw.dtype)
