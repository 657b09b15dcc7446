"""HOPE-Net (Doosti et al., CVPR 2020): image -> 2D keypoints -> refined 2D -> 3D keypoints.

A ResNet backbone pools the image into a feature (B, F); a linear layer
reads 29 initial 2D points from it; :class:`models.graph.GraphNet2D` refines
them with the feature appended to every node; the adaptive Graph U-Net
(:class:`models.graph.GraphUNet`) lifts the refined 2D points to 3D.

Convention:
    2D points are in normalised image coordinates of the input image:
    [-1, 1] from the left (top) edge to the right (bottom) edge, pixel
    centres at integers (:mod:`models.coords` converts to and from pixels).
    3D points are in the training target's units and frame: the network
    regresses whatever it is trained on (the training code uses metres; see
    its docs for the frame and origin). Keypoint order is the dataset's
    (21 hand joints, then 8 probe box corners).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, NamedTuple

import torch
from torch import nn

from models.graph import GraphNet2D, GraphUNet
from models.prior import PointPrior
from models.resnet import resnet

__all__ = ["HOPENet", "HOPENetOutput"]


class HOPENetOutput(NamedTuple):
    """What :class:`HOPENet` returns (N = ``n_keypoints``, 29 by default).

    Attributes:
        points2d_init: (B, N, 2) float, the backbone's initial 2D keypoints,
            normalised image coordinates ([-1, 1] across the input image).
        points2d: (B, N, 2) float, the graph-refined 2D keypoints, same coordinates.
        points3d: (B, N, 3) float, 3D keypoints in the training target's units and frame.
    """

    points2d_init: torch.Tensor
    points2d: torch.Tensor
    points3d: torch.Tensor


class HOPENet(nn.Module):
    """HOPE-Net with a ResNet backbone written in this package.

    Args:
        backbone: ResNet name, one of "resnet10" (the paper), "resnet18", "resnet34", "resnet50"
            (the public code).
        n_keypoints: N, keypoints predicted (29 = 21 hand joints + 8 probe corners).
        graph_hidden: widths of the two hidden graph convolutions of the 2D refinement.
        unet_channels: encoder widths of the Graph U-Net, one per pooling.
        unet_node_counts: nodes after each pooling of the Graph U-Net; None for HOPE-Net's
            (15, 7, 4, 2, 1) at 29 keypoints, halving otherwise.
        unet_bottleneck: hidden width of the U-Net's bottleneck MLP.
        zero_init_residual: zero the last BN of each residual branch of the backbone.
        points3d_mean: (N, 3) prior keypoint layout added to the 3D output (see
            :mod:`models.prior`), e.g. the training split's mean in metres; None for zeros.
        points3d_scale: target units per raw 3D output unit.
    """

    def __init__(
        self,
        backbone: str = "resnet10",
        n_keypoints: int = 29,
        graph_hidden: Sequence[int] = (128, 16),
        unet_channels: Sequence[int] = (4, 8, 16, 32, 64),
        unet_node_counts: Sequence[int] | None = None,
        unet_bottleneck: int = 20,
        zero_init_residual: bool = False,
        points3d_mean: Sequence[Sequence[float]] | None = None,
        points3d_scale: float = 1.0,
    ) -> None:
        super().__init__()
        if not isinstance(n_keypoints, int) or isinstance(n_keypoints, bool) or n_keypoints < 2:
            raise ValueError(f"n_keypoints must be an int >= 2, got {n_keypoints!r}")
        self._config: dict[str, Any] = {
            "name": "hopenet",
            "backbone": backbone,
            "n_keypoints": n_keypoints,
            "graph_hidden": list(graph_hidden),
            "unet_channels": list(unet_channels),
            "unet_node_counts": None if unet_node_counts is None else list(unet_node_counts),
            "unet_bottleneck": unet_bottleneck,
            "zero_init_residual": zero_init_residual,
            "points3d_mean": PointPrior.config_value(points3d_mean),
            "points3d_scale": float(points3d_scale),
        }
        self.n_keypoints = n_keypoints
        self.backbone = resnet(backbone, num_classes=None, zero_init_residual=zero_init_residual)
        feature_dim = self.backbone.feature_dim
        self.head2d = nn.Linear(feature_dim, n_keypoints * 2)
        self.graphnet = GraphNet2D(feature_dim, n_keypoints, hidden=graph_hidden)
        self.unet = GraphUNet(
            in_features=2,
            out_features=3,
            n_nodes=n_keypoints,
            node_counts=unet_node_counts,
            channels=unet_channels,
            bottleneck=unet_bottleneck,
        )
        self.prior3d = PointPrior(n_keypoints, points3d_mean, points3d_scale)

    @property
    def config(self) -> dict[str, Any]:
        """The plain dict that :func:`models.build.build_model` rebuilds this model from."""
        return {key: list(value) if isinstance(value, list) else value for key, value in self._config.items()}

    def forward(self, images: torch.Tensor) -> HOPENetOutput:
        """Predict 2D and 3D keypoints.

        Args:
            images: (B, 3, H, W) float, contiguous or channels_last.

        Returns:
            :class:`HOPENetOutput`: ``points2d_init`` (B, N, 2) and ``points2d`` (B, N, 2) in
            normalised image coordinates, ``points3d`` (B, N, 3) in the training target's units.
        """
        features = self.backbone.features(images)  # (B, F)
        points2d_init = self.head2d(features).reshape(-1, self.n_keypoints, 2)  # (B, N * 2) -> (B, N, 2)
        points2d = self.graphnet(points2d_init, features)  # (B, N, 2)
        points3d = self.prior3d(self.unet(points2d))  # (B, N, 3)
        return HOPENetOutput(points2d_init, points2d, points3d)
