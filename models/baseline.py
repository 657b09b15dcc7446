"""The ResNet regression baseline: image -> pooled feature -> linear -> 3D keypoints.

HUP-3D's second model: a ResNet-50 whose head regresses the 29 x 3
coordinates directly, with no graph stage. A 29 x 2 side output can be
switched on so that the baseline trains with the same 2D terms as HOPE-Net.

Convention:
    As :mod:`models.hopenet`: 2D points in normalised image coordinates
    ([-1, 1] across the input image, pixel centres at integers, see
    :mod:`models.coords`); 3D points in the training target's units and
    frame (the training code uses metres).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, NamedTuple

import torch
from torch import nn

from models.prior import PointPrior
from models.resnet import resnet

__all__ = ["RegressorOutput", "ResNetRegressor"]


class RegressorOutput(NamedTuple):
    """What :class:`ResNetRegressor` returns (N = ``n_keypoints``).

    Attributes:
        points2d: (B, N, 2) float in normalised image coordinates, or None when the model
            was built with ``predict_2d=False``. Same meaning as ``HOPENetOutput.points2d``.
        points3d: (B, N, 3) float in the training target's units and frame.
    """

    points2d: torch.Tensor | None
    points3d: torch.Tensor


class ResNetRegressor(nn.Module):
    """ResNet backbone + linear heads regressing keypoints directly.

    Args:
        backbone: ResNet name: "resnet10", "resnet18", "resnet34" or "resnet50" (HUP-3D).
        n_keypoints: N, keypoints predicted (29 = 21 hand joints + 8 probe corners).
        predict_2d: also regress (B, N, 2) 2D keypoints from the same feature.
        zero_init_residual: zero the last BN of each residual branch of the backbone.
        points3d_mean: (N, 3) prior keypoint layout added to the 3D output (see
            :mod:`models.prior`), e.g. the training split's mean in metres; None for zeros.
        points3d_scale: target units per raw 3D output unit.
    """

    def __init__(
        self,
        backbone: str = "resnet50",
        n_keypoints: int = 29,
        predict_2d: bool = False,
        zero_init_residual: bool = False,
        points3d_mean: Sequence[Sequence[float]] | None = None,
        points3d_scale: float = 1.0,
    ) -> None:
        super().__init__()
        if not isinstance(n_keypoints, int) or isinstance(n_keypoints, bool) or n_keypoints < 1:
            raise ValueError(f"n_keypoints must be a positive int, got {n_keypoints!r}")
        if not isinstance(predict_2d, bool):
            raise TypeError(f"predict_2d must be a bool, got {type(predict_2d).__name__}")
        self._config: dict[str, Any] = {
            "name": "resnet_regressor",
            "backbone": backbone,
            "n_keypoints": n_keypoints,
            "predict_2d": predict_2d,
            "zero_init_residual": zero_init_residual,
            "points3d_mean": PointPrior.config_value(points3d_mean),
            "points3d_scale": float(points3d_scale),
        }
        self.n_keypoints = n_keypoints
        self.backbone = resnet(backbone, num_classes=None, zero_init_residual=zero_init_residual)
        self.head3d = nn.Linear(self.backbone.feature_dim, n_keypoints * 3)
        self.head2d = nn.Linear(self.backbone.feature_dim, n_keypoints * 2) if predict_2d else None
        self.prior3d = PointPrior(n_keypoints, points3d_mean, points3d_scale)

    @property
    def config(self) -> dict[str, Any]:
        """The plain dict that :func:`models.build.build_model` rebuilds this model from."""
        return dict(self._config)

    def forward(self, images: torch.Tensor) -> RegressorOutput:
        """Regress keypoints.

        Args:
            images: (B, 3, H, W) float, contiguous or channels_last.

        Returns:
            :class:`RegressorOutput`: ``points2d`` (B, N, 2) or None, ``points3d`` (B, N, 3).
        """
        features = self.backbone.features(images)  # (B, F)
        points3d = self.prior3d(self.head3d(features).reshape(-1, self.n_keypoints, 3))  # (B, N * 3) -> (B, N, 3)
        points2d = None
        if self.head2d is not None:
            points2d = self.head2d(features).reshape(-1, self.n_keypoints, 2)  # (B, N * 2) -> (B, N, 2)
        return RegressorOutput(points2d, points3d)
