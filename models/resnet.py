"""ResNet-10/18/34/50 backbones with torchvision-compatible parameter names.

The modules are named as in torchvision's ResNet (``conv1``, ``bn1``,
``layer1.0.conv1``, ``layer2.0.downsample.0``, ``fc``, ...), with the same
shapes and buffers, so a torchvision ResNet state dict loads into
``resnet("resnet18", num_classes=1000)`` with ``strict=True``. The blocks are
the "v1.5" variant: a bottleneck downsamples in its 3x3 convolution.
ResNet-10 (one block per stage) is not in torchvision; it follows the same
naming.

Convention:
    Input images are (B, 3, H, W) float, normalised however the training code
    normalises them; any H, W >= 1 works (global average pooling at the end).
    Contiguous and ``torch.channels_last`` inputs give the same result.
"""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import nn

__all__ = [
    "RESNET_SPECS",
    "BasicBlock",
    "Bottleneck",
    "ResNet",
    "ResNetOutput",
    "check_backbone",
    "resnet",
    "strip_classifier",
]


def _conv3x3(in_channels: int, out_channels: int, stride: int = 1) -> nn.Conv2d:
    return nn.Conv2d(in_channels, out_channels, kernel_size=3, stride=stride, padding=1, bias=False)


def _conv1x1(in_channels: int, out_channels: int, stride: int = 1) -> nn.Conv2d:
    return nn.Conv2d(in_channels, out_channels, kernel_size=1, stride=stride, bias=False)


def _shortcut(in_channels: int, out_channels: int, stride: int) -> nn.Sequential | None:
    """1x1 projection + BN where the residual changes shape (torchvision's ``downsample``)."""
    if stride == 1 and in_channels == out_channels:
        return None
    return nn.Sequential(_conv1x1(in_channels, out_channels, stride), nn.BatchNorm2d(out_channels))


class BasicBlock(nn.Module):
    """Two 3x3 convolutions with an identity (or projected) shortcut.

    Args:
        in_channels: channels of the block's input.
        planes: channels of both convolutions; the output has ``planes * expansion``.
        stride: stride of the first convolution (2 halves H and W).
    """

    expansion = 1

    def __init__(self, in_channels: int, planes: int, stride: int = 1) -> None:
        super().__init__()
        self.conv1 = _conv3x3(in_channels, planes, stride)
        self.bn1 = nn.BatchNorm2d(planes)
        self.relu = nn.ReLU(inplace=True)
        self.conv2 = _conv3x3(planes, planes)
        self.bn2 = nn.BatchNorm2d(planes)
        self.downsample = _shortcut(in_channels, planes * self.expansion, stride)

    @property
    def last_bn(self) -> nn.BatchNorm2d:
        """The BN that closes the residual branch (zeroed by ``zero_init_residual``)."""
        return self.bn2

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(B, C_in, H, W) -> (B, planes, H / stride, W / stride)."""
        identity = x if self.downsample is None else self.downsample(x)
        out = self.relu(self.bn1(self.conv1(x)))
        out = self.bn2(self.conv2(out))
        return self.relu(out + identity)


class Bottleneck(nn.Module):
    """1x1 reduce, 3x3 (strided), 1x1 expand (x4), with an identity or projected shortcut.

    Args:
        in_channels: channels of the block's input.
        planes: channels of the inner convolutions; the output has ``planes * 4``.
        stride: stride of the 3x3 convolution (torchvision's "v1.5" placement).
    """

    expansion = 4

    def __init__(self, in_channels: int, planes: int, stride: int = 1) -> None:
        super().__init__()
        self.conv1 = _conv1x1(in_channels, planes)
        self.bn1 = nn.BatchNorm2d(planes)
        self.conv2 = _conv3x3(planes, planes, stride)
        self.bn2 = nn.BatchNorm2d(planes)
        self.conv3 = _conv1x1(planes, planes * self.expansion)
        self.bn3 = nn.BatchNorm2d(planes * self.expansion)
        self.relu = nn.ReLU(inplace=True)
        self.downsample = _shortcut(in_channels, planes * self.expansion, stride)

    @property
    def last_bn(self) -> nn.BatchNorm2d:
        """The BN that closes the residual branch (zeroed by ``zero_init_residual``)."""
        return self.bn3

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(B, C_in, H, W) -> (B, 4 * planes, H / stride, W / stride)."""
        identity = x if self.downsample is None else self.downsample(x)
        out = self.relu(self.bn1(self.conv1(x)))
        out = self.relu(self.bn2(self.conv2(out)))
        out = self.bn3(self.conv3(out))
        return self.relu(out + identity)


#: name -> (block type, blocks per stage)
RESNET_SPECS: dict[str, tuple[type[BasicBlock | Bottleneck], tuple[int, int, int, int]]] = {
    "resnet10": (BasicBlock, (1, 1, 1, 1)),
    "resnet18": (BasicBlock, (2, 2, 2, 2)),
    "resnet34": (BasicBlock, (3, 4, 6, 3)),
    "resnet50": (Bottleneck, (3, 4, 6, 3)),
}


class ResNetOutput(NamedTuple):
    """What :class:`ResNet` returns.

    Attributes:
        features: (B, F) float, the globally average-pooled output of ``layer4``;
            F = 512 for BasicBlock ResNets, 2048 for ResNet-50.
        logits: (B, num_classes) float from ``fc``, or None when the network has no ``fc``.
    """

    features: torch.Tensor
    logits: torch.Tensor | None


class ResNet(nn.Module):
    """A ResNet with torchvision's module names.

    Args:
        block: :class:`BasicBlock` or :class:`Bottleneck`.
        layers: number of blocks in each of the four stages, e.g. (2, 2, 2, 2).
        num_classes: size of the ``fc`` head; None builds no head (a pure backbone).
        zero_init_residual: start the last BN of every residual branch at weight 0, so each
            block starts as the identity (Goyal et al., "Accurate, large minibatch SGD").

    Attributes:
        feature_dim: F, the width of the pooled feature (512 or 2048).
        stage_channels: channels of the four stages' outputs (:meth:`feature_maps`).
    """

    def __init__(
        self,
        block: type[BasicBlock | Bottleneck],
        layers: tuple[int, int, int, int] | list[int],
        num_classes: int | None = None,
        zero_init_residual: bool = False,
        in_channels: int = 3,
    ) -> None:
        super().__init__()
        assert block in (BasicBlock, Bottleneck) and len(layers) == 4 and min(layers) >= 1, (block, layers)
        assert num_classes is None or num_classes >= 1, num_classes
        assert in_channels >= 1, in_channels

        self.in_channels = in_channels
        self.conv1 = nn.Conv2d(in_channels, 64, kernel_size=7, stride=2, padding=3, bias=False)
        self.bn1 = nn.BatchNorm2d(64)
        self.relu = nn.ReLU(inplace=True)
        self.maxpool = nn.MaxPool2d(kernel_size=3, stride=2, padding=1)
        in_channels = 64  # from here on: each block's input
        stages = []
        for index, (planes, n_blocks) in enumerate(zip((64, 128, 256, 512), layers)):
            stride = 1 if index == 0 else 2
            blocks = []
            for b in range(n_blocks):
                blocks.append(block(in_channels, planes, stride if b == 0 else 1))
                in_channels = planes * block.expansion
            stages.append(nn.Sequential(*blocks))
        self.layer1, self.layer2, self.layer3, self.layer4 = stages
        self.avgpool = nn.AdaptiveAvgPool2d(1)
        self.feature_dim = in_channels
        self.stage_channels = tuple(planes * block.expansion for planes in (64, 128, 256, 512))
        self.fc = None if num_classes is None else nn.Linear(in_channels, num_classes)

        for module in self.modules():
            if isinstance(module, nn.Conv2d):
                nn.init.kaiming_normal_(module.weight, mode="fan_out", nonlinearity="relu")
            elif isinstance(module, nn.BatchNorm2d):
                nn.init.ones_(module.weight)
                nn.init.zeros_(module.bias)
        if zero_init_residual:
            for module in self.modules():
                if isinstance(module, (BasicBlock, Bottleneck)):
                    nn.init.zeros_(module.last_bn.weight)

    def features(self, images: torch.Tensor) -> torch.Tensor:
        """The pooled feature, without the ``fc`` head.

        Args:
            images: (B, C, H, W) float (C = ``in_channels``), contiguous or channels_last.

        Returns:
            (B, F) float, F = ``feature_dim``.
        """
        _check_images(images, self.in_channels)
        x = self.maxpool(self.relu(self.bn1(self.conv1(images))))
        x = self.layer4(self.layer3(self.layer2(self.layer1(x))))
        return torch.flatten(self.avgpool(x), 1)  # (B, F, 1, 1) -> (B, F)

    def feature_maps(self, images: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """The outputs of the four stages, for dense heads.

        Args:
            images: (B, C, H, W) float (C = ``in_channels``), contiguous or channels_last.

        Returns:
            (C2, C3, C4, C5): (B, C_k, H / s, W / s) at strides s = 4, 8, 16, 32 (rounded up), with
            C_k = 64, 128, 256, 512 times the block's expansion (1 basic, 4 bottleneck).
        """
        _check_images(images, self.in_channels)
        x = self.maxpool(self.relu(self.bn1(self.conv1(images))))
        c2 = self.layer1(x)
        c3 = self.layer2(c2)
        c4 = self.layer3(c3)
        return c2, c3, c4, self.layer4(c4)

    def forward(self, images: torch.Tensor) -> ResNetOutput:
        """Pooled feature and, when there is an ``fc``, class logits.

        Args:
            images: (B, C, H, W) float (C = ``in_channels``), contiguous or channels_last.

        Returns:
            :class:`ResNetOutput` with ``features`` (B, F) and ``logits`` (B, num_classes) or None.
        """
        features = self.features(images)
        logits = None if self.fc is None else self.fc(features)
        return ResNetOutput(features, logits)


def _check_images(images: torch.Tensor, channels: int) -> None:
    if images.ndim != 4 or images.shape[1] != channels or not images.is_floating_point():
        raise ValueError(f"images must be (B, {channels}, H, W) float, got {tuple(images.shape)} {images.dtype}")


def check_backbone(name: str) -> None:
    """Refuse a ResNet name that is not in :data:`RESNET_SPECS`, listing the known ones."""
    if name not in RESNET_SPECS:
        raise ValueError(f"unknown ResNet {name!r}; known: {', '.join(sorted(RESNET_SPECS))}")


def resnet(name: str, num_classes: int | None = None, zero_init_residual: bool = False, in_channels: int = 3) -> ResNet:
    """Build a ResNet by name.

    Args:
        name: one of ``RESNET_SPECS``: "resnet10", "resnet18", "resnet34", "resnet50".
        num_classes: size of the ``fc`` head (1000 to load an ImageNet checkpoint); None for
            a backbone without ``fc``.
        zero_init_residual: zero the last BN weight of every residual branch.
        in_channels: channels of the input image (3: RGB; 4: RGB and depth).

    Returns:
        The :class:`ResNet`, pooled feature width 512 (10/18/34) or 2048 (50).
    """
    check_backbone(name)
    block, layers = RESNET_SPECS[name]
    return ResNet(block, layers, num_classes=num_classes, zero_init_residual=zero_init_residual, in_channels=in_channels)


def strip_classifier(state_dict: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """Drop ``fc.weight`` and ``fc.bias`` so a classifier checkpoint loads into a backbone.

    A torchvision ImageNet checkpoint has an ``fc`` head; a backbone built with
    ``num_classes=None`` has none, so the strict load needs the head removed first. Nothing
    else is renamed or dropped.

    Args:
        state_dict: name -> tensor, torchvision's naming.

    Returns:
        A new dict without the ``fc.`` entries.
    """
    return {key: value for key, value in state_dict.items() if not key.startswith("fc.")}
