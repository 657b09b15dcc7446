"""The ResNet regression baseline: image -> pooled feature -> linear -> 3D keypoints.

HUP-3D's second model: a ResNet-50 whose head regresses the 29 x 3
coordinates directly, with no graph stage. A 29 x 2 side output can be
switched on so that the baseline trains with the same 2D terms as HOPE-Net, and a segmentation head
(:mod:`hupbench.models.segmentation`, on the backbone's stride-8 stage) so that its fits take only their own
object's depth, as HUPNet's do.

Convention:
    As :mod:`hupbench.models.hopenet`: 2D points in normalised image coordinates
    ([-1, 1] across the input image, pixel centres at integers, see
    :mod:`hupbench.models.coords`); 3D points in the training target's units and
    frame (the training code uses metres).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, NamedTuple

import torch
from torch import nn

from hupbench.models.model_config import ModelConfig
from hupbench.models.prior import PointPrior
from hupbench.models.resnet import resnet
from hupbench.models.segmentation import segment, segmentation_layers

__all__ = ["RegressorOutput", "ResNetRegressor", "ResNetRegressorConfig"]


class RegressorOutput(NamedTuple):
    """What :class:`ResNetRegressor` returns (N = ``n_keypoints``).

    Attributes:
        points2d: (B, N, 2) float in normalised image coordinates, or None when the model
            was built with ``predict_2d=False``. Same meaning as ``HOPENetOutput.points2d``.
        points3d: (B, N, 3) float in the training target's units and frame.
        segmentation: (B, 3, S, S) float logits of each input pixel's class (other, hand, probe) for a model
            with ``segmentation``, else None.
    """

    points2d: torch.Tensor | None
    points3d: torch.Tensor
    segmentation: torch.Tensor | None = None


@dataclass(frozen=True)
class ResNetRegressorConfig(ModelConfig):
    """The baseline's architecture (:class:`hupbench.models.model_config.ModelConfig`'s fields and these).

    Attributes:
        predict_2d: also regress (B, N, 2) 2D keypoints from the same feature.
        segmentation: a head that labels each input pixel other, hand or probe from the backbone's stride-8
            stage and the input image (:mod:`hupbench.models.segmentation`), for the fits.
    """

    name: ClassVar[str] = "resnet_regressor"
    backbone: str = "resnet50"
    predict_2d: bool = False
    segmentation: bool = False


class ResNetRegressor(nn.Module):
    """ResNet backbone + linear heads regressing keypoints directly, built from its config."""

    def __init__(self, config: ResNetRegressorConfig = ResNetRegressorConfig()) -> None:
        super().__init__()
        self.config = config
        self.n_keypoints = n = config.n_keypoints
        self.backbone = resnet(config.backbone, num_classes=None, zero_init_residual=config.zero_init_residual,
                               in_channels=config.input_channels)
        self.head3d = nn.Linear(self.backbone.feature_dim, n * 3)
        self.head2d = nn.Linear(self.backbone.feature_dim, n * 2) if config.predict_2d else None
        self.prior3d = PointPrior(n, config.points3d_mean, config.points3d_scale)
        if config.segmentation:
            self.seg_features, self.seg_head = segmentation_layers(self.backbone.stage_channels[1],
                                                                   config.input_channels)

    def forward(self, images: torch.Tensor) -> RegressorOutput:
        """Regress keypoints.

        Args:
            images: (B, C, H, W) float, C = ``input_channels`` (RGB in [0, 1], then depth), contiguous or
                channels_last.

        Returns:
            :class:`RegressorOutput`: ``points2d`` (B, N, 2) or None, ``points3d`` (B, N, 3), ``segmentation``
            (B, 3, H, W) or None.
        """
        segmentation = None
        if self.config.segmentation:
            c2, c3, c4, c5 = self.backbone.feature_maps(images)
            features = torch.flatten(self.backbone.avgpool(c5), 1)                      # (B, F)
            segmentation = segment(self.seg_features, self.seg_head, c3, images)
        else:
            features = self.backbone.features(images)  # (B, F)
        points3d = self.prior3d(self.head3d(features).reshape(-1, self.n_keypoints, 3))  # (B, N * 3) -> (B, N, 3)
        points2d = None
        if self.head2d is not None:
            points2d = self.head2d(features).reshape(-1, self.n_keypoints, 2)  # (B, N * 2) -> (B, N, 2)
        return RegressorOutput(points2d, points3d, segmentation)
