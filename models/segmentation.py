"""The segmentation head the fits read: each input pixel labelled other, hand or probe (``SEGMENT_CLASSES``).

A model's feature map, reduced to :data:`SEG_FEATURES` channels by a 1 x 1 convolution, is upsampled bilinearly to
the input, joined with the input image, and classified by a 3 x 3 and a 1 x 1 convolution (trained on the dataset's
seg maps, ``loss.w_seg``). HUPNet reads its heatmap canvas (:mod:`hupbench.models.heatmap`), the ResNet regressor its
backbone's stride-8 stage (:mod:`hupbench.models.baseline`); the fits then take only their own object's depth
(:func:`hupbench.fits.after_network`).
"""

from __future__ import annotations

import torch
from torch import nn
from torch.nn import functional as F

from hupbench.core.contract import SEGMENT_CLASSES

__all__ = ["SEG_FEATURES", "segmentation_layers", "segment"]

#: channels of the features the head upsamples to the input
SEG_FEATURES = 8


def segmentation_layers(feature_channels: int, input_channels: int) -> tuple[nn.Conv2d, nn.Sequential]:
    """(the 1 x 1 reduction of ``feature_channels`` features, the classifier over them and the ``input_channels``
    image): a model keeps them as ``seg_features`` and ``seg_head``."""
    reduce = nn.Conv2d(feature_channels, SEG_FEATURES, 1)
    head = nn.Sequential(nn.Conv2d(SEG_FEATURES + input_channels, 2 * SEG_FEATURES, 3, padding=1),
                         nn.ReLU(inplace=True), nn.Conv2d(2 * SEG_FEATURES, len(SEGMENT_CLASSES), 1))
    return reduce, head


def segment(reduce: nn.Conv2d, head: nn.Sequential, features: torch.Tensor, images: torch.Tensor) -> torch.Tensor:
    """(B, 3, S, S) float32 class logits of each input pixel from ``features`` (B, D, H, W), covering the image,
    and the input ``images`` (B, C, S, S)."""
    reduced = F.interpolate(reduce(features), size=images.shape[-2:], mode="bilinear", align_corners=False)
    return head(torch.cat([reduced, images.to(reduced.dtype)], dim=1)).float()
