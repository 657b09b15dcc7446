"""Graph layers of HOPE-Net: graph convolution, learned node pooling, the adaptive Graph U-Net.

Node features are (B, N, C): batch, nodes (keypoints), channels. Every graph
convolution learns its own dense adjacency A (N, N), initialised to the
identity, and mixes nodes with the symmetric normalisation D^-1/2 A D^-1/2
(:func:`normalized_adjacency`).

Convention:
    Layers are unit-agnostic: they carry whatever the input carries (the 2D
    input of :class:`GraphUNet` is in normalised image coordinates, its 3D
    output in the training target's units; see :mod:`hupbench.models.hopenet`).
"""

from __future__ import annotations

from collections.abc import Sequence
from itertools import pairwise

import torch
from torch import nn

from hupbench.core.input_checks import check_int
from hupbench.core.tolerances import ADJACENCY_DEGREE_EPS

__all__ = [
    "ACTIVATION_SLOPE",
    "HOPENET_NODE_COUNTS",
    "GraphConv",
    "GraphNet2D",
    "GraphPool",
    "GraphUNet",
    "GraphUnpool",
    "default_node_counts",
    "normalized_adjacency",
]

#: HOPE-Net's pooling schedule below the 29 input nodes
HOPENET_NODE_COUNTS = (15, 7, 4, 2, 1)

#: negative slope of the graph layers' activation. Leaky, not a plain ReLU: the U-Net's entry
#: layer has only 4 channels fed by near-constant 2D points at initialisation, and with a ReLU
#: 5 of 80 random inits measured had all 4 off at every node, cutting the encoder off for good
#: (zero gradient, never revived). The slope keeps a gradient through every unit.
ACTIVATION_SLOPE = 0.01


def normalized_adjacency(adjacency: torch.Tensor) -> torch.Tensor:
    """Symmetric normalisation D^-1/2 A D^-1/2 that stays finite for any finite A.

    A learned adjacency is unconstrained: entries turn negative, rows go to
    zero, values grow large. The textbook form divides by the square root of
    the row sums, which is NaN for a negative sum, inf for a zero one, and
    overflows for huge entries. Three choices keep it finite while equalling
    the textbook form on a non-negative A whose row sums all exceed
    ``ADJACENCY_DEGREE_EPS`` times its largest entry:

    1. Degrees are row sums of |A| (the "absolute degree" of signed graphs):
       a negative edge adds its magnitude to the degree instead of cancelling
       a positive one, so a degree is zero only when its whole row is zero,
       and the sign of each edge is kept in the numerator, so a learned
       inhibitory edge still subtracts.
    2. A is first divided by its largest |entry| (per matrix). The result is
       invariant to a positive scale of A, so this changes nothing
       mathematically, but no sum can overflow, even at 1e30 or 1e38.
    3. Degrees are clamped from below at ``ADJACENCY_DEGREE_EPS`` (relative to
       the largest |entry|, after step 2): an all-zero row gives a zero
       output row instead of 0/0, and every output entry is bounded by
       1 / sqrt(eps) (|A_ij| is at most 1 and at most d_i after step 2).
       An all-zero A gives all zeros.

    Gradients are finite wherever the output is. Non-finite input (NaN,
    inf) is not repaired: it marks a training that has already diverged and
    propagates to the output. Lower-precision input (fp16, bf16) is
    normalised in fp32 and returned in its own dtype.

    Args:
        adjacency: (N, N) or (B, N, N) float, any sign.

    Returns:
        Same shape and dtype: entry (i, j) is A_ij / sqrt(d_i d_j),
        d_i = max(sum_k |A_ik|, eps * max|A|).
    """
    if adjacency.ndim not in (2, 3) or adjacency.shape[-1] != adjacency.shape[-2] or not adjacency.is_floating_point():
        raise ValueError(f"adjacency must be (N, N) or (B, N, N) float, got {tuple(adjacency.shape)} {adjacency.dtype}")
    work = adjacency.to(torch.promote_types(adjacency.dtype, torch.float32))
    scale = work.abs().amax(dim=(-2, -1), keepdim=True)  # (..., 1, 1)
    # an all-zero matrix keeps scale 0 -> divide by 1 instead and return zeros
    scaled = work / torch.where(scale > 0, scale, torch.ones_like(scale))
    degree = scaled.abs().sum(dim=-1).clamp_min(ADJACENCY_DEGREE_EPS)  # (..., N)
    inv_sqrt = degree.rsqrt()
    out = inv_sqrt.unsqueeze(-1) * scaled * inv_sqrt.unsqueeze(-2)
    return out.to(adjacency.dtype)


def _check_nodes(x: torch.Tensor, n_nodes: int, channels: int | str, name: str) -> None:
    if x.ndim != 3 or x.shape[1] != n_nodes or (channels != "C" and x.shape[2] != channels):
        raise ValueError(f"{name} must be (B, {n_nodes}, {channels}), got {tuple(x.shape)}")


def _check_positive(**values: int) -> None:
    for name, value in values.items():
        check_int(value, name, 1)


class GraphConv(nn.Module):
    """act(Linear(norm(A) X)) with a learned adjacency A initialised to the identity.

    Args:
        in_features: C_in, channels per node of the input.
        out_features: C_out, channels per node of the output.
        n_nodes: N, number of graph nodes.
        activation: apply the activation (LeakyReLU, slope ``ACTIVATION_SLOPE``) after the
            linear map; False for an output layer.

    Attributes:
        adjacency: (N, N) learned parameter, any sign; normalised by
            :func:`normalized_adjacency` at every call.
    """

    def __init__(self, in_features: int, out_features: int, n_nodes: int, activation: bool = True) -> None:
        super().__init__()
        _check_positive(in_features=in_features, out_features=out_features, n_nodes=n_nodes)
        self.in_features = in_features
        self.out_features = out_features
        self.n_nodes = n_nodes
        self.adjacency = nn.Parameter(torch.eye(n_nodes))
        self.linear = nn.Linear(in_features, out_features)
        self.activation = nn.LeakyReLU(ACTIVATION_SLOPE) if activation else nn.Identity()

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Mix nodes, then channels.

        Args:
            x: (B, N, C_in) float node features.

        Returns:
            (B, N, C_out) float.
        """
        _check_nodes(x, self.n_nodes, self.in_features, "x")
        mixed = torch.matmul(normalized_adjacency(self.adjacency), x)  # (N, N) @ (B, N, C_in)
        return self.activation(self.linear(mixed))

    def extra_repr(self) -> str:
        return f"{self.in_features} -> {self.out_features}, n_nodes={self.n_nodes}"


class _NodeLinear(nn.Module):
    """A learned linear map over the node dimension: (B, n_in, C) -> (B, n_out, C)."""

    def __init__(self, n_in: int, n_out: int) -> None:
        super().__init__()
        _check_positive(n_in=n_in, n_out=n_out)
        self.n_in = n_in
        self.n_out = n_out
        self.linear = nn.Linear(n_in, n_out)  # weight (n_out, n_in): row k = how node k is made

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(B, n_in, C) -> (B, n_out, C): every output node is a learned mix of the input nodes."""
        _check_nodes(x, self.n_in, "C", "x")
        return self.linear(x.transpose(1, 2)).transpose(1, 2)  # (B, C, n_in) -> (B, C, n_out)

    def extra_repr(self) -> str:
        return f"nodes {self.n_in} -> {self.n_out}"


class GraphPool(_NodeLinear):
    """Learned pooling to fewer nodes (HOPE-Net's adaptive pooling).

    Args:
        n_in: nodes of the input.
        n_out: nodes of the output, normally fewer than ``n_in``.

    Forward: (B, n_in, C) -> (B, n_out, C); ``linear.weight`` is (n_out, n_in).
    """


class GraphUnpool(_NodeLinear):
    """Learned unpooling to more nodes (the U-Net's way back up).

    Args:
        n_in: nodes of the input.
        n_out: nodes of the output, normally more than ``n_in``.

    Forward: (B, n_in, C) -> (B, n_out, C); ``linear.weight`` is (n_out, n_in).
    """


def default_node_counts(n_nodes: int) -> tuple[int, ...]:
    """The node counts below ``n_nodes`` down to 1 for :class:`GraphUNet`.

    Args:
        n_nodes: nodes of the input graph, >= 2.

    Returns:
        HOPE-Net's (15, 7, 4, 2, 1) for 29 nodes; otherwise halving (rounded up) down to 1,
        e.g. 21 -> (11, 6, 3, 2, 1).
    """
    check_int(n_nodes, "n_nodes", 2)  # fewer nodes do not pool
    if n_nodes == 29:
        return HOPENET_NODE_COUNTS
    counts = []
    n = n_nodes
    while n > 1:
        n = (n + 1) // 2
        counts.append(n)
    return tuple(counts)


class GraphUNet(nn.Module):
    """HOPE-Net's adaptive Graph U-Net: lifts per-node 2D points to 3D.

    Encoder: at each level a graph convolution widens the channels, then a
    learned pooling shrinks the nodes (29 -> 15 -> 7 -> 4 -> 2 -> 1, channels
    2 -> 4 -> 8 -> 16 -> 32 -> 64 by default). A two-layer bottleneck MLP acts
    on the single remaining node. Decoder: at each level a learned unpooling
    grows the nodes back (1 -> 2 -> 4 -> 7 -> 15 -> 29), the encoder feature of
    that level is concatenated (skip), and a graph convolution narrows the
    channels to those of the level above. The last level also concatenates
    the raw input and ends in a graph convolution to ``out_features`` without
    activation. Every graph convolution has its own learned adjacency of its
    level's size, so each level's adjacency appears twice (encoder and
    decoder), both initialised to the identity.

    Args:
        in_features: channels of the input per node (2 for 2D points).
        out_features: channels of the output per node (3 for 3D points).
        n_nodes: N, nodes of the input and output graph.
        node_counts: nodes after each pooling, strictly decreasing, ending at 1; None for
            :func:`default_node_counts` (HOPE-Net's (15, 7, 4, 2, 1) for 29).
        channels: output channels of the encoder's graph convolutions, one per pooling
            (same length as ``node_counts``).
        bottleneck: width of the hidden layer of the bottleneck MLP.
    """

    def __init__(
        self,
        in_features: int = 2,
        out_features: int = 3,
        n_nodes: int = 29,
        node_counts: Sequence[int] | None = None,
        channels: Sequence[int] = (4, 8, 16, 32, 64),
        bottleneck: int = 20,
    ) -> None:
        super().__init__()
        _check_positive(
            in_features=in_features, out_features=out_features, n_nodes=n_nodes, bottleneck=bottleneck
        )
        node_counts = default_node_counts(n_nodes) if node_counts is None else tuple(node_counts)
        channels = tuple(channels)
        levels = (n_nodes,) + node_counts  # nodes at each level, top to bottom
        if not node_counts or node_counts[-1] != 1 or any(a <= b for a, b in pairwise(levels)):
            raise ValueError(
                f"node_counts must decrease strictly from n_nodes={n_nodes} and end at 1, got {node_counts}"
            )
        if len(channels) != len(node_counts):
            raise ValueError(
                f"channels needs one entry per pooling ({len(node_counts)}), got {len(channels)}: {channels}"
            )
        _check_positive(**{f"channels[{i}]": c for i, c in enumerate(channels)})
        self.in_features = in_features
        self.out_features = out_features
        self.n_nodes = n_nodes
        self.node_counts = node_counts
        self.channels = channels

        widths = (in_features,) + channels  # channels entering each encoder convolution
        self.encoder = nn.ModuleList(
            GraphConv(widths[i], widths[i + 1], levels[i]) for i in range(len(channels))
        )
        self.pools = nn.ModuleList(GraphPool(levels[i], levels[i + 1]) for i in range(len(channels)))
        self.bottleneck = nn.Sequential(
            nn.Linear(channels[-1], bottleneck),
            nn.LeakyReLU(ACTIVATION_SLOPE),
            nn.Linear(bottleneck, channels[-1]),
            nn.LeakyReLU(ACTIVATION_SLOPE),
        )
        # decoder, bottom to top: unpool level k+1 -> k, concat the skip of level k, convolve
        self.unpools = nn.ModuleList()
        self.decoder = nn.ModuleList()
        for k in reversed(range(len(channels))):
            self.unpools.append(GraphUnpool(levels[k + 1], levels[k]))
            # what arrives has channels[k] (the bottleneck's width, or the level below's output)
            if k == 0:
                conv = GraphConv(2 * channels[0] + in_features, out_features, levels[0], activation=False)
            else:
                conv = GraphConv(2 * channels[k], channels[k - 1], levels[k])
            self.decoder.append(conv)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Lift node features through the U-Net.

        Args:
            x: (B, N, in_features) float, e.g. 2D keypoints in normalised image coordinates.

        Returns:
            (B, N, out_features) float, e.g. 3D keypoints in the training target's units.
        """
        _check_nodes(x, self.n_nodes, self.in_features, "x")
        skips = []
        h = x
        for conv, pool in zip(self.encoder, self.pools):
            h = conv(h)  # (B, N_k, C_k)
            skips.append(h)
            h = pool(h)  # (B, N_{k+1}, C_k)
        h = self.bottleneck(h)  # (B, 1, C_last)
        for unpool, conv, skip in zip(self.unpools, self.decoder, reversed(skips)):
            h = unpool(h)  # (B, N_k, C_k)
            is_top = conv is self.decoder[-1]
            parts = [h, skip, x] if is_top else [h, skip]
            h = conv(torch.cat(parts, dim=-1))  # (B, N_k, 2 C_k [+ in_features]) -> (B, N_k, C_{k-1})
        return h


class GraphNet2D(nn.Module):
    """HOPE-Net's 2D refinement: graph convolutions over (2D point + image feature) per node.

    The pooled image feature is appended to every node's 2D point; three graph
    convolutions (F + 2) -> 128 -> 16 -> 2 follow, the last without activation.

    Args:
        feature_dim: F, width of the pooled image feature.
        n_nodes: N, number of keypoints.
        hidden: widths of the two hidden graph convolutions.

    Convention:
        The output is in the same coordinates as the input points (normalised image
        coordinates in HOPE-Net); it is predicted directly, not as an offset.
    """

    def __init__(self, feature_dim: int, n_nodes: int = 29, hidden: Sequence[int] = (128, 16)) -> None:
        super().__init__()
        _check_positive(feature_dim=feature_dim, n_nodes=n_nodes)
        hidden = tuple(hidden)
        if len(hidden) != 2:
            raise ValueError(f"hidden must hold two widths, got {hidden}")
        _check_positive(**{f"hidden[{i}]": h for i, h in enumerate(hidden)})
        self.feature_dim = feature_dim
        self.n_nodes = n_nodes
        self.conv1 = GraphConv(feature_dim + 2, hidden[0], n_nodes)
        self.conv2 = GraphConv(hidden[0], hidden[1], n_nodes)
        self.conv3 = GraphConv(hidden[1], 2, n_nodes, activation=False)

    def forward(self, points2d: torch.Tensor, features: torch.Tensor) -> torch.Tensor:
        """Refine 2D keypoints with the image feature.

        Args:
            points2d: (B, N, 2) float, initial 2D keypoints.
            features: (B, F) float, pooled image feature.

        Returns:
            (B, N, 2) float, refined 2D keypoints.
        """
        _check_nodes(points2d, self.n_nodes, 2, "points2d")
        batch = points2d.shape[0]
        if features.ndim != 2 or features.shape[0] != batch or features.shape[1] != self.feature_dim:
            raise ValueError(
                f"features must be (B={batch}, {self.feature_dim}), got {tuple(features.shape)}"
            )
        tiled = features.unsqueeze(1).expand(-1, self.n_nodes, -1)  # (B, F) -> (B, N, F)
        h = torch.cat([points2d, tiled], dim=-1)  # (B, N, 2 + F)
        return self.conv3(self.conv2(self.conv1(h)))
