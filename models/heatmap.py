"""HUPNet: 2.5D heatmaps with soft-argmax, lifted to absolute camera-frame 3D through the camera.

What it follows:
    - 2.5D pose (Iqbal et al., "Hand pose estimation via latent 2.5D heatmap regression",
      ECCV 2018): each keypoint is a 2D location plus a depth relative to a root; absolute 3D
      follows from the intrinsics K and the root's depth.
    - Integral regression (Sun et al., "Integral human pose regression", ECCV 2018): the 2D
      location is the expectation of a softmax-normalised heatmap (soft-argmax) and the relative
      depth the same expectation over a per-keypoint depth map, so the network trains end to end
      on coordinate losses, at sub-cell precision.
    - A feature pyramid (Lin et al., FPN, CVPR 2017) brings the ResNet's stride-32 semantics down
      to a stride-8 map, where the heatmaps live.

What is our own: the heatmap canvas extends ``canvas_margin`` of the image width beyond every
edge (zero-padded features plus coordinate channels, CoordConv-style), because the probe's box
corners often lie outside the image; the root depth is one global regression from the pooled
stride-32 feature, added to every keypoint's relative depth and to the training split's mean
depth of that keypoint (the prior of :mod:`hupbench.models.prior`).

With a depth input and ``depth_anchor``, a keypoint's depth is read from the measured surface instead:
each keypoint has an anchor map over the canvas (softmax logits, restricted to cells where the input
depth saw a surface) and an offset map, and its depth is the expectation of (the cell's mean measured
depth + the cell's offset) under its anchor map. A joint lies about a centimetre under the skin and a
probe corner a few centimetres off the probe's surface: the network learns where to look and how far
behind or before the surface the point is, and the absolute distance comes from the measurement, not
from a global regression.

With ``probe_head: rigid`` the last 8 keypoints (the probe's box corners) are the known box posed rigidly
instead of 8 free points: the box (``probe_half_extents``, the training split's) is centred on the mean of
the 8 corners the heatmaps find and turned by a rotation that a small head regresses (the 6D representation
of Zhou et al., "On the continuity of rotation representations", CVPR 2019, as a turn from the mean layout's
box) from the backbone's pooled feature and the pyramid feature pooled where the corner heatmaps look. The
corners' 2D points are the box's projection; the heatmaps' own 2D points are ``points2d_init``, trained
towards the true corners as HOPE-Net's initial 2D points are. Free corners came out 21 mm away from any
rigid box (scripts/diagnose_errors.py on paper_hupnet_rgbd_cpu, test split).

The probe's orientation marker spans 2-4 pixels at 128 px, and on unseen grasps a model that cannot see it
has the probe the wrong way round (the half-turned labels closer on 66-72 % of test frames). With
``backbone_size`` below ``input_size`` the backbone sees the input downsampled (RGB averaged, depth to the
nearest pixel) while ``probe_crop_px`` crops a square of that many input pixels around the probe at full
resolution (the corner heatmaps' 2D centre, no gradient through it) for a second, small ResNet, whose pooled
feature joins the rotation head's: the probe at twice the detail for a fraction of the cost of a backbone
at the full size.

Convention:
    2D points in normalised image coordinates of the input image (models/coords.py: [-1, 1]
    across the image, pixel centres at integers); 3D points in the training target's units
    (metres in training), OpenCV camera frame of the input camera ``K_input``. X and Y of every
    3D point are its 2D point unprojected at its depth: the 3D output moves with the image.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, NamedTuple

import torch
from torch import nn
from torch.nn import functional as F

from hupbench.core.input_checks import check_choice, check_int, check_number
from hupbench.models.model_config import ModelConfig, check_camera
from hupbench.models.hopenet import normalized_intrinsics, unproject_normalized
from hupbench.models.prior import PointPrior
from hupbench.models.resnet import check_backbone, resnet
from hupbench.models.segmentation import segment, segmentation_layers

__all__ = ["HUPNet", "HUPNetConfig", "HUPNetOutput", "heatmap_confidence", "soft_argmax"]



class HUPNetOutput(NamedTuple):
    """What :class:`HUPNet` returns (N = ``n_keypoints``).

    Attributes:
        points2d: (B, N, 2) float, normalised image coordinates of the input (may lie outside
            [-1, 1] by up to the canvas margin).
        points3d: (B, N, 3) float, the training target's units, OpenCV camera frame of K_input.
        points2d_init: (B, N, 2) the heatmaps' own 2D points where the probe head replaces the corners', else None.
        confidence: (B, N) float32 in [0, 1], in eval mode, each keypoint's :func:`heatmap_confidence` (for the probe head's
            corners, their heatmaps'); no gradient flows through it.
        segmentation: (B, 3, S, S) float logits of each input pixel's class (``SEGMENT_CLASSES``: other, hand,
            probe) for a model with ``segmentation``, else None.
    """

    points2d: torch.Tensor
    points3d: torch.Tensor
    points2d_init: torch.Tensor | None = None
    confidence: torch.Tensor | None = None
    segmentation: torch.Tensor | None = None


def soft_argmax(logits: torch.Tensor, grid_x: torch.Tensor, grid_y: torch.Tensor,
                values: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor | None]:
    """Expected location (and value) under a softmax over each heatmap.

    Args:
        logits: (B, N, H, W) float heatmap logits.
        grid_x: (W,) float, x coordinate of each column's cell centre.
        grid_y: (H,) float, y coordinate of each row's cell centre.
        values: optional (B, N, H, W) float maps whose expectation is also returned.

    Returns:
        ((B, N, 2) expected (x, y), (B, N) expected value or None). Softmax is taken in float32
        at least, so bf16 autocast keeps the expectation precise.
    """
    B, N, H, W = logits.shape
    assert grid_x.shape == (W,) and grid_y.shape == (H,), (grid_x.shape, grid_y.shape, logits.shape)
    dtype = torch.promote_types(logits.dtype, torch.float32)
    prob = torch.softmax(logits.to(dtype).reshape(B, N, H * W), dim=-1).reshape(B, N, H, W)
    x = (prob.sum(dim=2) * grid_x.to(dtype)).sum(dim=-1)  # (B, N, W) marginal -> (B, N)
    y = (prob.sum(dim=3) * grid_y.to(dtype)).sum(dim=-1)  # (B, N, H) marginal -> (B, N)
    expected = None if values is None else (prob * values.to(dtype)).sum(dim=(2, 3))
    return torch.stack([x, y], dim=-1), expected


def heatmap_confidence(logits: torch.Tensor) -> torch.Tensor:
    """How peaked each heatmap is: the softmax probability mass of its most probable 3 x 3 cells.

    1 when the whole distribution sits within one cell's neighbours, 9 / (H W) for a flat map; the 2D point
    (soft-argmax) of a spread map lies between its modes, on none of them.

    Args:
        logits: (B, N, H, W) float heatmap logits.

    Returns:
        (B, N) float32 in [0, 1], detached.
    """
    B, N, H, W = logits.shape
    prob = torch.softmax(logits.detach().float().reshape(B, N, H * W), dim=-1).reshape(B * N, 1, H, W)
    window = F.avg_pool2d(prob, 3, stride=1, padding=1, count_include_pad=True) * 9.0  # (B N, 1, H, W) 3x3 sums
    return window.reshape(B, N, H * W).amax(dim=-1).clamp(max=1.0)


def _conv_bn_relu(in_channels: int, out_channels: int) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(in_channels, out_channels, 3, padding=1, bias=False),
                         nn.BatchNorm2d(out_channels), nn.ReLU(inplace=True))


@dataclass(frozen=True)
class HUPNetConfig(ModelConfig):
    """HUPNet's architecture (:class:`hupbench.models.model_config.ModelConfig`'s fields and these).

    Attributes:
        neck_channels: width D of the pyramid and heads.
        canvas_margin: the heatmap canvas reaches this fraction of the input width beyond each
            image edge (rounded to whole stride-8 cells), so points outside the image are found.
        K_input: (3, 3) intrinsics of the model input image, pixels (required; training fills it in).
        input_size: S, side of the square model input, pixels (required, a multiple of 8; training fills
            it in).
        depth_anchor: read each keypoint's depth from the input's depth channel (module docstring); needs
            ``input_channels`` 4 (``data.reader.input_modalities=rgb+depth``).
        probe_head: "corners" (8 free corner keypoints) or "rigid" (the box posed rigidly, module docstring).
        probe_half_extents: (3,) half the probe box's sides along its x, y, z, in the training target's units
            (required by "rigid"; training fills it in from the training split).
        backbone_size: side of the image the backbone sees, pixels: ``input_size`` divided by a whole number
            (None: the input size itself).
        probe_crop_px: side of the full-resolution crop around the probe for the rotation head, input pixels
            (0: none; needs probe_head "rigid"). probe_crop_backbone: the crop's ResNet.
        heatmap_stride: backbone pixels per heatmap cell, 8 (the pyramid down to the stride-8 stage) or 4 (one
            level further, from the first stage: four times the cells, finer 2D where a finger is a few pixels).
        segmentation: a head that labels each input pixel other, hand or probe (``SEGMENT_CLASSES``), for the fits
            to take only their own object's depth: the heatmap canvas's features, upsampled to the input and
            joined with the input image, through a 3 x 3 and a 1 x 1 convolution (trained on the dataset's seg
            maps, ``loss.w_seg``).
    """

    name: ClassVar[str] = "hupnet"
    STRIDE: ClassVar[int] = 8
    neck_channels: int = 128
    canvas_margin: float = 0.25
    K_input: tuple[tuple[float, ...], ...] | None = None
    input_size: int | None = None
    depth_anchor: bool = False
    probe_head: str = "corners"
    probe_half_extents: tuple[float, float, float] | None = None
    backbone_size: int | None = None
    probe_crop_px: int = 0
    probe_crop_backbone: str = "resnet10"
    heatmap_stride: int = 8
    segmentation: bool = False

    def __post_init__(self) -> None:
        super().__post_init__()
        check_int(self.neck_channels, "neck_channels", 1)
        check_choice(self.probe_head, "probe_head", ("corners", "rigid"))
        if self.probe_head == "rigid" and self.n_keypoints < N_CORNERS:
            raise ValueError(f"probe_head 'rigid' poses the last {N_CORNERS} keypoints, the model has {self.n_keypoints}")
        check_int(self.probe_crop_px, "probe_crop_px", 0)
        check_choice(self.heatmap_stride, "heatmap_stride", (4, 8))
        check_backbone(self.probe_crop_backbone)
        if self.probe_crop_px and self.probe_head != "rigid":
            raise ValueError("probe_crop_px feeds the rigid probe head: it needs probe_head 'rigid'")
        if self.backbone_size is not None:
            check_int(self.backbone_size, "backbone_size", 16)
        if self.probe_half_extents is not None:
            extents = torch.as_tensor(self.probe_half_extents, dtype=torch.float64)
            if extents.shape != (3,) or not torch.isfinite(extents).all() or (extents <= 0).any():
                raise ValueError(f"probe_half_extents must be 3 positive finite numbers, got {self.probe_half_extents!r}")
        check_number(self.canvas_margin, "canvas_margin", 0.0, 2.0)  # fractions of the image width
        if self.K_input is not None or self.input_size is not None:
            check_camera(self.K_input, self.input_size, self.STRIDE)
            backbone = self.backbone_size or self.input_size
            if self.input_size % backbone or backbone % self.STRIDE:
                raise ValueError(f"backbone_size must divide input_size {self.input_size} and be a multiple of "
                                 f"{self.STRIDE}, got {backbone}")
            if self.probe_crop_px > self.input_size:
                raise ValueError(f"probe_crop_px must be at most input_size {self.input_size}, got {self.probe_crop_px}")


class HUPNet(nn.Module):
    """ResNet + feature pyramid -> per-keypoint heatmaps and depth maps at stride 8 (or 4) -> 3D via K."""

    STRIDE = HUPNetConfig.STRIDE

    def __init__(self, config: HUPNetConfig) -> None:
        super().__init__()
        if config.K_input is None:
            raise ValueError("HUPNet unprojects through the input camera: it needs K_input (3 x 3, pixels of the "
                             "model input) and input_size")
        if config.depth_anchor and config.input_channels != 4:
            raise ValueError("depth_anchor reads the depth channel: it needs data.reader.input_modalities=rgb+depth")
        self.config = config
        self.n_keypoints = config.n_keypoints
        self.input_size = input_size = config.input_size
        self.factor = input_size // (config.backbone_size or input_size)   # input pixels per backbone pixel
        self.stride = config.heatmap_stride * self.factor                 # input pixels per canvas cell
        self.backbone = resnet(config.backbone, num_classes=None, zero_init_residual=config.zero_init_residual,
                               in_channels=config.input_channels)
        c2, c3, c4, c5 = self.backbone.stage_channels
        D = config.neck_channels
        self.lateral5, self.lateral4, self.lateral3 = nn.Conv2d(c5, D, 1), nn.Conv2d(c4, D, 1), nn.Conv2d(c3, D, 1)
        self.smooth = nn.Sequential(_conv_bn_relu(D + 2, D), _conv_bn_relu(D, D))
        if config.heatmap_stride == 4:  # the stride-8 canvas doubled, the first stage added, one conv to D / 2
            self.lateral2 = nn.Conv2d(c2, D, 1)
            self.fine = _conv_bn_relu(D, D // 2)
            D = D // 2
        self.heatmap = nn.Conv2d(D, config.n_keypoints, 1)
        if config.depth_anchor:
            # where each keypoint reads the surface, and how far behind it (units of points3d_scale); zero at
            # first: every keypoint starts at the mean depth of the surface the camera sees
            self.anchor = nn.Conv2d(D, config.n_keypoints, 1)
            self.anchor_offset = nn.Conv2d(D, config.n_keypoints, 1)
            heads = [self.heatmap, self.anchor, self.anchor_offset]
        else:
            self.depthmap = nn.Conv2d(D, config.n_keypoints, 1)
            self.root_depth = nn.Linear(c5, 1)
            heads = [self.heatmap, self.depthmap, self.root_depth]
        for head in heads:
            nn.init.normal_(head.weight, std=1e-3)
            nn.init.zeros_(head.bias)
        if config.segmentation:
            self.seg_features, self.seg_head = segmentation_layers(D, config.input_channels)
        self.prior3d = PointPrior(config.n_keypoints, config.points3d_mean, config.points3d_scale)
        self.register_buffer("intrinsics", normalized_intrinsics(config.K_input, input_size))
        if config.probe_head == "rigid":
            if config.probe_half_extents is None:
                raise ValueError("probe_head 'rigid' needs probe_half_extents (training fills them in)")
            box = torch.tensor(CORNER_SIGNS, dtype=torch.float32) * torch.tensor(config.probe_half_extents,
                                                                                 dtype=torch.float32)
            self.register_buffer("probe_box", box, persistent=False)                   # (8, 3) centred
            self.register_buffer("probe_rotation0", _fit_rotation(box, self.prior3d.mean[-N_CORNERS:]),
                                 persistent=False)                                       # the mean layout's turn
            crop_features = 0
            if config.probe_crop_px:
                self.crop_net = resnet(config.probe_crop_backbone, num_classes=None, in_channels=config.input_channels)
                crop_features = self.crop_net.feature_dim
                # normalised input coordinates of the crop's pixel centres relative to its centre, (C, C, 2) x, y
                C = config.probe_crop_px
                offsets = ((torch.arange(C, dtype=torch.float32) + 0.5) / C * 2.0 - 1.0) * (C / input_size)
                self.register_buffer("crop_offsets", torch.stack(torch.meshgrid(offsets, offsets, indexing="xy"), -1),
                                     persistent=False)
            self.probe_rotation = nn.Sequential(nn.Linear(c5 + D + crop_features, 256), nn.ReLU(inplace=True),
                                                nn.Linear(256, 6))
            nn.init.normal_(self.probe_rotation[-1].weight, std=1e-3)
            nn.init.zeros_(self.probe_rotation[-1].bias)
        # the canvas at stride 8 (where the coordinate channels join) and at the heatmaps' stride: normalised
        # coordinate of each cell's centre, cell j of the image covering input pixels [s j, s j + s) (s the
        # stride), centre s j + (s - 1) / 2 -> (j + 0.5) / cells * 2 - 1
        cells8 = input_size // (self.STRIDE * self.factor)
        self.margin_cells8 = int(round(float(config.canvas_margin) * cells8))
        up = self.STRIDE // config.heatmap_stride
        cells, self.margin_cells = cells8 * up, self.margin_cells8 * up
        for name, n, margin in (("grid8", cells8, self.margin_cells8), ("grid", cells, self.margin_cells)):
            index = torch.arange(-margin, n + margin, dtype=torch.float32)
            self.register_buffer(name, (index + 0.5) / n * 2.0 - 1.0, persistent=False)

    def forward(self, images: torch.Tensor) -> HUPNetOutput:
        """Predict 2D and 3D keypoints.

        Args:
            images: (B, C, S, S) float, C = ``input_channels`` (RGB in [0, 1], then depth), S = ``input_size``;
                contiguous or channels_last.

        Returns:
            :class:`HUPNetOutput`: points2d (B, N, 2) normalised, points3d (B, N, 3), confidence (B, N).
        """
        if images.ndim != 4 or images.shape[-1] != self.input_size or images.shape[-2] != self.input_size:
            raise ValueError(f"images must be (B, {self.config.input_channels}, {self.input_size}, {self.input_size}) "
                             "(the model's input size), "
                             f"got {tuple(images.shape)}")
        seen = images
        if self.factor > 1:  # RGB averaged, depth to the nearest pixel (no blend of a surface with nothing)
            f = self.factor
            seen = F.avg_pool2d(images[:, :3], f)
            if images.shape[1] > 3:
                seen = torch.cat([seen, images[:, 3:, f // 2::f, f // 2::f]], dim=1)
        c2, c3, c4, c5 = self.backbone.feature_maps(seen)
        p = self.lateral5(c5)                                                        # (B, D, S/32, S/32)
        p = self.lateral4(c4) + F.interpolate(p, size=c4.shape[-2:], mode="nearest")  # (B, D, S/16, S/16)
        p = self.lateral3(c3) + F.interpolate(p, size=c3.shape[-2:], mode="nearest")  # (B, D, S/8, S/8)
        m = self.margin_cells8
        p = F.pad(p, (m, m, m, m))                                                   # the canvas beyond the image
        B, _, H, W = p.shape
        grid = self.grid8.to(p.dtype)
        coords = torch.stack([grid.view(1, W).expand(H, W), grid.view(H, 1).expand(H, W)])  # (2, H, W)
        p = self.smooth(torch.cat([p, coords.unsqueeze(0).expand(B, -1, -1, -1)], dim=1))
        if self.config.heatmap_stride == 4:                                          # (B, D / 2, 2 H, 2 W)
            p = self.fine(F.interpolate(p, scale_factor=2, mode="nearest") + F.pad(self.lateral2(c2), (2 * m,) * 4))
        grid = self.grid.to(p.dtype)
        logits = self.heatmap(p)                                                     # (B, N, H, W)
        # for predict only: the loss never reads it, so training skips the second softmax
        confidence = None if self.training else heatmap_confidence(logits)          # (B, N)
        if self.config.depth_anchor:
            points2d, _ = soft_argmax(logits, grid, grid)                            # (B, N, 2)
            depth = self._anchored_depth(images, p)                                  # (B, N)
        else:
            points2d, relative = soft_argmax(logits, grid, grid, self.depthmap(p))   # (B, N, 2), (B, N)
            root = self.root_depth(torch.flatten(self.backbone.avgpool(c5), 1))          # (B, 1)
            depth = (self.prior3d.mean[:, 2].to(relative.dtype)
                     + (root.to(relative.dtype) + relative) * self.prior3d.scale)
        points3d = unproject_normalized(points2d, depth, self.intrinsics)
        segmentation = self._segmentation(p, images) if self.config.segmentation else None
        if self.config.probe_head == "rigid":
            pooled = torch.flatten(self.backbone.avgpool(c5), 1)
            rigid2d, rigid3d = self._rigid_probe(p, pooled, points3d[:, -N_CORNERS:], images, points2d[:, -N_CORNERS:])
            heatmap2d = points2d
            points2d = torch.cat([points2d[:, :-N_CORNERS], rigid2d.to(points2d.dtype)], dim=1)
            points3d = torch.cat([points3d[:, :-N_CORNERS], rigid3d.to(points3d.dtype)], dim=1)
            return HUPNetOutput(points2d.to(images.dtype), points3d.to(images.dtype), heatmap2d.to(images.dtype),
                                confidence, segmentation)
        return HUPNetOutput(points2d.to(images.dtype), points3d.to(images.dtype), confidence=confidence,
                            segmentation=segmentation)

    def _segmentation(self, p: torch.Tensor, images: torch.Tensor) -> torch.Tensor:
        """(B, 3, S, S) float32 class logits of each input pixel from the canvas features ``p`` (B, D, H, W) (the
        image's cells, without the margin, upsampled bilinearly to the input) and the input images."""
        m, cells = self.margin_cells, p.shape[-1] - 2 * self.margin_cells
        return segment(self.seg_features, self.seg_head, p[:, :, m:m + cells, m:m + cells], images)

    def _rigid_probe(self, p: torch.Tensor, pooled: torch.Tensor, corners3d: torch.Tensor, images: torch.Tensor,
                     corners2d: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The probe box posed rigidly: ((B, 8, 2) normalised 2D, (B, 8, 3) 3D) in float32 (class docstring).

        Args:
            p: (B, D, H, W) canvas features. pooled: (B, C5) the backbone's pooled feature.
            corners3d: (B, 8, 3) the heatmaps' corners, whose mean is the box's centre.
            images: (B, C, S, S) the model input, cropped around the probe when ``probe_crop_px`` is set.
            corners2d: (B, 8, 2) the heatmaps' corners, normalised: the crop's centre is their mean.
        """
        B, D, H, W = p.shape
        look = torch.softmax(self.heatmap(p)[:, -N_CORNERS:].float().reshape(B, N_CORNERS, H * W), dim=-1)
        look = look.mean(dim=1)                                                     # (B, H W) where corners are
        local = torch.bmm(p.float().reshape(B, D, H * W), look.unsqueeze(-1)).squeeze(-1)    # (B, D)
        features = [pooled.float(), local]
        if self.config.probe_crop_px:
            centre2d = corners2d.detach().float().mean(dim=1)                        # (B, 2) normalised
            where = centre2d[:, None, None, :] + self.crop_offsets                   # (B, C, C, 2)
            crop = F.grid_sample(images.float(), where, mode="bilinear", padding_mode="zeros", align_corners=False)
            features.append(self.crop_net.features(crop.to(images.dtype)).float())  # (B, F)
        six = self.probe_rotation(torch.cat(features, dim=1)).float()                # (B, 6)
        identity = torch.tensor([1.0, 0.0, 0.0, 0.0, 1.0, 0.0], device=six.device)
        rotation = rotation_from_6d(six + identity) @ self.probe_rotation0          # (B, 3, 3)
        centre = corners3d.float().mean(dim=1, keepdim=True)                        # (B, 1, 3)
        box3d = centre + self.probe_box @ rotation.transpose(1, 2)                   # (B, 8, 3)
        f, c = self.intrinsics[:2], self.intrinsics[2:]
        box2d = box3d[..., :2] / box3d[..., 2:].clamp(min=1e-3) * f + c              # x_n = fx X / Z + cx
        return box2d, box3d


    def _anchored_depth(self, images: torch.Tensor, p: torch.Tensor) -> torch.Tensor:
        """(B, N) depth of each keypoint read from the depth channel (class docstring), float32, metres.

        The depth channel is pooled to the canvas cells: each cell's mean over the pixels with a surface
        (0 where none), and the log of the fraction of such pixels added to every anchor logit, so that
        cells without a surface weigh nothing (a softmax over cells that all lack one stays uniform and
        finite)."""
        depth = images[:, 3:4].float()                                          # (B, 1, S, S) metres, 0 = none
        surface = (depth > 0).float()
        k, m = self.stride, self.margin_cells
        covered = F.avg_pool2d(surface, k)                                      # (B, 1, S/8, S/8) fraction
        mean_depth = F.avg_pool2d(depth, k) / covered.clamp(min=1e-6)           # mean over surface pixels
        covered, mean_depth = F.pad(covered, (m, m, m, m)), F.pad(mean_depth, (m, m, m, m))
        logits = self.anchor(p).float() + torch.log(covered.clamp(min=1e-4))    # (B, N, H, W)
        values = mean_depth + self.anchor_offset(p).float() * self.prior3d.scale
        grid = self.grid.float()
        _, expected = soft_argmax(logits, grid, grid, values)
        return expected


#: the last N_CORNERS keypoints are the probe box's corners, in the order of hupbench.core.keypoints.CORNER_BITS
#: (index 4 ix + 2 iy + iz, each bit 0 = the min side): their signs along the box's x, y, z
N_CORNERS = 8
CORNER_SIGNS = tuple(tuple(2.0 * ((k >> shift) & 1) - 1.0 for shift in (2, 1, 0)) for k in range(N_CORNERS))


def rotation_from_6d(six: torch.Tensor) -> torch.Tensor:
    """(B, 3, 3) rotations from (B, 6) pairs of vectors by Gram-Schmidt (Zhou et al. 2019): the columns are
    a / |a|, the part of b orthogonal to it, normalised, and their cross product."""
    a, b = six[:, :3], six[:, 3:]
    x = a / a.norm(dim=1, keepdim=True).clamp(min=1e-6)
    b = b - (x * b).sum(dim=1, keepdim=True) * x
    y = b / b.norm(dim=1, keepdim=True).clamp(min=1e-6)
    return torch.stack([x, y, torch.cross(x, y, dim=1)], dim=2)


def _fit_rotation(box: torch.Tensor, corners: torch.Tensor) -> torch.Tensor:
    """(3, 3) proper rotation R minimising |corners - mean - box R^T| (Kabsch), float32; identity for an empty or
    degenerate layout."""
    x = box.double()
    y = corners.double() - corners.double().mean(dim=0)
    if not torch.isfinite(y).all() or y.abs().max() == 0:
        return torch.eye(3)
    u, _, vt = torch.linalg.svd(y.T @ x)
    d = torch.sign(torch.linalg.det(u @ vt))
    return (u @ torch.diag(torch.tensor([1.0, 1.0, float(d)], dtype=torch.float64)) @ vt).float()
