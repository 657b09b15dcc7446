"""HOPE-Net (Doosti et al., CVPR 2020): image -> 2D keypoints -> refined 2D -> 3D keypoints.

A ResNet backbone pools the image into a feature (B, F); a linear layer
reads 29 initial 2D points from it; :class:`hupbench.models.graph.GraphNet2D` refines
them with the feature appended to every node; the adaptive Graph U-Net
(:class:`hupbench.models.graph.GraphUNet`) lifts the refined 2D points to 3D.

Convention:
    2D points are in normalised image coordinates of the input image:
    [-1, 1] from the left (top) edge to the right (bottom) edge, pixel
    centres at integers (:mod:`hupbench.models.coords` converts to and from pixels).
    3D points are in the training target's units and frame: the network
    regresses whatever it is trained on (the training code uses metres; see
    its docs for the frame and origin). Keypoint order is the dataset's
    (21 hand joints, then 8 probe box corners).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import ClassVar, NamedTuple

import torch
from torch import nn

from hupbench.models.coords import pixels_to_normalized
from hupbench.core.input_checks import check_choice, check_int
from hupbench.models.model_config import ModelConfig, check_camera
from hupbench.models.graph import GraphNet2D, GraphUNet
from hupbench.models.prior import PointPrior
from hupbench.models.resnet import resnet

__all__ = ["LIFTS", "GraphLifter", "HOPENet", "HOPENetConfig", "HOPENetOutput", "normalized_intrinsics",
           "unproject_normalized"]

#: how the Graph U-Net's output becomes camera-frame 3D (see :class:`GraphLifter`)
LIFTS = ("direct", "camera")
#: normalised image units per raw unit of the camera lift's 2D correction (0.64 px at 128 px)
CAMERA_LIFT_UV_SCALE = 0.01


def normalized_intrinsics(K_input, input_size: int) -> torch.Tensor:
    """(4,) float32 (fx, fy, cx, cy) of a pixel-unit K in normalised image units (models/coords.py).

    With x_norm = (2 u + 1) / S - 1: fx_norm = 2 fx / S and cx_norm = (2 cx + 1) / S - 1, so that
    x_norm = fx_norm * X / Z + cx_norm for a camera-frame point (X, Y, Z).

    Args:
        K_input: (3, 3) intrinsics of the model input image, pixels (nested lists or array), as
            :func:`hupbench.models.model_config.check_camera` takes them.
        input_size: S, side of the square model input, pixels.
    """
    K = torch.as_tensor(K_input, dtype=torch.float64)
    centre = pixels_to_normalized(K[:2, 2], input_size, input_size)
    return torch.cat([2 * torch.diagonal(K)[:2] / input_size, centre]).float()


def unproject_normalized(points2d: torch.Tensor, depth: torch.Tensor, intrinsics: torch.Tensor) -> torch.Tensor:
    """Camera-frame points from normalised image points and their depths.

    Args:
        points2d: (B, N, 2) float, normalised image coordinates of the input image.
        depth: (B, N) float, Z of each point (any length unit; the output has the same).
        intrinsics: (4,) float, (fx, fy, cx, cy) in normalised units (:func:`normalized_intrinsics`).

    Returns:
        (B, N, 3) float: (X, Y, Z) with X = (x_norm - cx) / fx * Z, Y likewise, OpenCV camera frame.
    """
    f, c = intrinsics[:2].to(points2d.dtype), intrinsics[2:].to(points2d.dtype)
    xy = (points2d - c) / f * depth.unsqueeze(-1)  # (B, N, 2)
    return torch.cat([xy, depth.unsqueeze(-1)], dim=-1)


def set_lift(module: nn.Module, lift: str, K_input, input_size) -> None:
    """Give ``module`` its ``lift`` and ``intrinsics`` (a buffer of the normalised input camera for
    lift="camera", None for "direct"), as :func:`lift_points` takes them."""
    module.lift = lift
    if lift == "camera":
        if K_input is None or input_size is None:
            raise ValueError("lift='camera' needs K_input (3 x 3, pixels of the model input) and input_size")
        module.register_buffer("intrinsics", normalized_intrinsics(K_input, input_size))
    else:
        module.intrinsics = None


class GraphLifter(nn.Module):
    """HOPE-Net's adaptive Graph U-Net lifting 2D keypoints to camera-frame 3D, in one of two ways.

    lift="direct" (HOPE-Net as published): the U-Net's 3 output channels are the 3D point, an offset
    from the prior layout (``points3d = raw * scale + mean``).
    lift="camera": the U-Net's output channels are a 2D correction (``CAMERA_LIFT_UV_SCALE``
    normalised units per raw unit) and the depth (``Z = raw * scale + mean Z``); X and Y follow from
    the corrected 2D point, its depth and the input camera (:func:`unproject_normalized`), so the 3D
    point moves with the 2D point by construction (a pinhole camera, as the dataset's).

    Args:
        lift: "direct" or "camera".
        n_keypoints, unet_channels, unet_node_counts, unet_bottleneck: the Graph U-Net's (see
            :class:`hupbench.models.graph.GraphUNet`).
        points3d_mean: (N, 3) prior layout, target units (metres in training); None for zeros.
        points3d_scale: target units per raw output unit.
        K_input: (3, 3) intrinsics of the model input image, pixels; needed by lift="camera".
        input_size: S, side of the square model input, pixels; needed by lift="camera".

    Forward: points2d (B, N, 2) normalised -> points3d (B, N, 3) target units, camera frame.
    """

    def __init__(self, lift: str = "direct", n_keypoints: int = 29, unet_channels: Sequence[int] = (4, 8, 16, 32, 64),
                 unet_node_counts: Sequence[int] | None = None, unet_bottleneck: int = 20,
                 points3d_mean: Sequence[Sequence[float]] | None = None, points3d_scale: float = 1.0,
                 K_input: Sequence[Sequence[float]] | None = None, input_size: int | None = None) -> None:
        super().__init__()
        set_lift(self, lift, K_input, input_size)
        self.unet = GraphUNet(in_features=2, out_features=3, n_nodes=n_keypoints, node_counts=unet_node_counts,
                              channels=unet_channels, bottleneck=unet_bottleneck)
        self.prior3d = PointPrior(n_keypoints, points3d_mean, points3d_scale)

    def forward(self, points2d: torch.Tensor) -> torch.Tensor:
        """(B, N, 2) normalised 2D -> (B, N, 3) camera-frame 3D (target units)."""
        return lift_points(self.unet(points2d), points2d, self.prior3d, self.lift, self.intrinsics)


def lift_points(raw: torch.Tensor, points2d: torch.Tensor, prior3d: PointPrior, lift: str,
                intrinsics: torch.Tensor | None) -> torch.Tensor:
    """The Graph U-Net's raw output (B, N, 3) -> camera-frame 3D (B, N, 3) (see :class:`GraphLifter`)."""
    if lift == "direct":
        return prior3d(raw)
    depth = prior3d.mean[:, 2].to(raw.dtype) + raw[..., 2] * prior3d.scale  # (B, N)
    return unproject_normalized(points2d + raw[..., :2] * CAMERA_LIFT_UV_SCALE, depth, intrinsics)


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


@dataclass(frozen=True)
class HOPENetConfig(ModelConfig):
    """HOPE-Net's architecture (:class:`hupbench.models.model_config.ModelConfig`'s fields and these).

    Attributes:
        graph_hidden: widths of the two hidden graph convolutions of the 2D refinement.
        unet_channels: encoder widths of the Graph U-Net, one per pooling.
        unet_node_counts: nodes after each pooling of the Graph U-Net; None for HOPE-Net's
            (15, 7, 4, 2, 1) at 29 keypoints, halving otherwise.
        unet_bottleneck: hidden width of the U-Net's bottleneck MLP.
        lift: "direct" (the published HOPE-Net: the U-Net outputs 3D points) or "camera" (the U-Net
            outputs depth and a 2D correction, unprojected through the input camera; see
            :class:`GraphLifter`).
        K_input: (3, 3) intrinsics of the model input image, pixels (lift="camera"; training fills it in).
        input_size: S, side of the square model input, pixels (lift="camera"; training fills it in).
        unet_image_channels: the U-Net also sees the pooled image feature squeezed to this many
            channels per node (0: only the 2D points, as published).
    """

    name: ClassVar[str] = "hopenet"
    min_keypoints: ClassVar[int] = 2
    backbone: str = "resnet10"
    graph_hidden: tuple[int, ...] = (128, 16)
    unet_channels: tuple[int, ...] = (4, 8, 16, 32, 64)
    unet_node_counts: tuple[int, ...] | None = None
    unet_bottleneck: int = 20
    lift: str = "direct"
    K_input: tuple[tuple[float, ...], ...] | None = None
    input_size: int | None = None
    unet_image_channels: int = 0

    def __post_init__(self) -> None:
        super().__post_init__()
        check_choice(self.lift, "lift", LIFTS)
        check_int(self.unet_image_channels, "unet_image_channels", 0)
        if self.K_input is not None or self.input_size is not None:
            check_camera(self.K_input, self.input_size)


class HOPENet(nn.Module):
    """HOPE-Net with a ResNet backbone written in this package, built from its config."""

    def __init__(self, config: HOPENetConfig = HOPENetConfig()) -> None:
        super().__init__()
        self.config = config
        self.n_keypoints = n = config.n_keypoints
        self.backbone = resnet(config.backbone, num_classes=None, zero_init_residual=config.zero_init_residual,
                               in_channels=config.input_channels)
        feature_dim = self.backbone.feature_dim
        self.head2d = nn.Linear(feature_dim, n * 2)
        self.graphnet = GraphNet2D(feature_dim, n, hidden=config.graph_hidden)
        # optionally the U-Net also sees the image: the pooled feature squeezed to a few channels per node
        image_channels = config.unet_image_channels
        self.unet_image = nn.Linear(feature_dim, image_channels) if image_channels else None
        self.unet = GraphUNet(in_features=2 + image_channels, out_features=3, n_nodes=n,
                              node_counts=config.unet_node_counts, channels=config.unet_channels,
                              bottleneck=config.unet_bottleneck)
        self.prior3d = PointPrior(n, config.points3d_mean, config.points3d_scale)
        set_lift(self, config.lift, config.K_input, config.input_size)

    def forward(self, images: torch.Tensor) -> HOPENetOutput:
        """Predict 2D and 3D keypoints.

        Args:
            images: (B, C, H, W) float, C = ``input_channels`` (RGB in [0, 1], then depth), contiguous or
                channels_last.

        Returns:
            :class:`HOPENetOutput`: ``points2d_init`` (B, N, 2) and ``points2d`` (B, N, 2) in
            normalised image coordinates, ``points3d`` (B, N, 3) in the training target's units.
        """
        features = self.backbone.features(images)  # (B, F)
        points2d_init = self.head2d(features).reshape(-1, self.n_keypoints, 2)  # (B, N * 2) -> (B, N, 2)
        points2d = self.graphnet(points2d_init, features)  # (B, N, 2)
        return HOPENetOutput(points2d_init, points2d, self.lift_to_3d(points2d, features))

    def lift_to_3d(self, points2d: torch.Tensor, features: torch.Tensor) -> torch.Tensor:
        """The Graph U-Net stage: (B, N, 2) refined 2D points and (B, F) pooled feature -> (B, N, 3) 3D.

        The feature enters only when the model was built with ``unet_image_channels``.
        """
        unet_in = points2d
        if self.unet_image is not None:
            tiled = self.unet_image(features).unsqueeze(1).expand(-1, self.n_keypoints, -1)  # (B, C) -> (B, N, C)
            unet_in = torch.cat([points2d, tiled], dim=-1)
        return lift_points(self.unet(unet_in), points2d, self.prior3d, self.lift, self.intrinsics)  # (B, N, 3)
