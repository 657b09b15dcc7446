import math

import pytest
import torch

from hupbench.models.graph import (
    ACTIVATION_SLOPE,
    HOPENET_NODE_COUNTS,
    GraphConv,
    GraphNet2D,
    GraphPool,
    GraphUNet,
    GraphUnpool,
    default_node_counts,
    normalized_adjacency,
)
from hupbench.core.tolerances import ADJACENCY_DEGREE_EPS


def textbook(adjacency: torch.Tensor) -> torch.Tensor:
    """D^-1/2 A D^-1/2 with D the row sums, for a positive A."""
    d = adjacency.sum(-1).rsqrt()
    return d[..., :, None] * adjacency * d[..., None, :]


# ---------------------------------------------------------------- normalized_adjacency


def test_known_values_path_graph():
    a = torch.tensor([[1.0, 1.0, 0.0], [1.0, 1.0, 1.0], [0.0, 1.0, 1.0]])
    s6 = 1 / math.sqrt(6)
    expected = torch.tensor([[0.5, s6, 0.0], [s6, 1 / 3, s6], [0.0, s6, 0.5]])
    torch.testing.assert_close(normalized_adjacency(a), expected)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("batch", [None, 3])
def test_equals_textbook_for_positive(dtype, batch):
    gen = torch.Generator().manual_seed(1)
    shape = (7, 7) if batch is None else (batch, 7, 7)
    a = (torch.rand(shape, generator=gen) + 0.1).to(dtype)  # positive, not symmetric
    out = normalized_adjacency(a)
    assert out.dtype == dtype and out.shape == shape
    torch.testing.assert_close(out, textbook(a))


def test_identity_is_a_fixed_point():
    eye = torch.eye(29)
    torch.testing.assert_close(normalized_adjacency(eye), eye)


def test_scale_invariant():
    a = torch.rand(5, 5) + 0.1
    for scale in (1e-20, 3.0, 1e20):
        torch.testing.assert_close(normalized_adjacency(a * scale), normalized_adjacency(a))


def test_negative_entries_use_absolute_degree_and_keep_sign():
    # row sums are 0: the textbook form divides by zero here
    a = torch.tensor([[1.0, -1.0], [-1.0, 1.0]])
    torch.testing.assert_close(normalized_adjacency(a), torch.tensor([[0.5, -0.5], [-0.5, 0.5]]))
    # a negative row sum: the textbook form takes the root of a negative number
    b = torch.tensor([[-3.0, 1.0], [1.0, 1.0]])
    d = torch.tensor([4.0, 2.0])
    torch.testing.assert_close(normalized_adjacency(b), b / torch.sqrt(d[:, None] * d[None, :]))


def test_zero_row_gives_zero_row():
    a = torch.tensor([[0.0, 0.0, 0.0], [0.0, 2.0, 1.0], [0.0, 1.0, 2.0]])
    out = normalized_adjacency(a)
    assert torch.isfinite(out).all()
    assert torch.equal(out[0], torch.zeros(3)) and torch.equal(out[:, 0], torch.zeros(3))
    torch.testing.assert_close(out[1:, 1:], textbook(a[1:, 1:]))


def test_non_symmetric_zero_row_stays_bounded():
    # row 1 is empty but column 1 is not: the clamped degree bounds the entry by 1/sqrt(eps)
    a = torch.tensor([[1.0, 1.0], [0.0, 0.0]])
    out = normalized_adjacency(a)
    assert torch.isfinite(out).all()
    assert out.abs().max() <= 1 / math.sqrt(ADJACENCY_DEGREE_EPS) * (1 + 1e-6)


@pytest.mark.parametrize(
    "a",
    [
        torch.zeros(4, 4),
        torch.full((4, 4), 1e30),
        torch.full((4, 4), -1e30),
        torch.full((4, 4), 3e38),  # the sum of a row overflows float32
        torch.tensor([[1e30, 1.0], [1.0, 1e-30]]),
        torch.tensor([[-1e30, 1e30], [0.0, -5.0]]),
        torch.tensor([[0.0, -2.0, 0.0], [0.0, 0.0, 0.0], [7.0, 0.0, -1e-38]]),
    ],
    ids=["zeros", "huge", "huge-negative", "float32-max", "mixed", "signed-huge", "sparse-signed"],
)
def test_finite_values_and_gradients_in_hard_cases(a):
    a = a.clone().requires_grad_(True)
    out = normalized_adjacency(a)
    assert torch.isfinite(out).all()
    assert out.abs().max() <= 1 / math.sqrt(ADJACENCY_DEGREE_EPS) * (1 + 1e-6)
    (out * torch.randn_like(out)).sum().backward()
    assert torch.isfinite(a.grad).all()


def test_all_zero_is_zero_and_huge_equals_unit():
    assert torch.equal(normalized_adjacency(torch.zeros(3, 3)), torch.zeros(3, 3))
    torch.testing.assert_close(normalized_adjacency(torch.full((4, 4), 1e30)), torch.full((4, 4), 0.25))


def test_batched_matches_per_matrix():
    a = torch.randn(4, 6, 6)
    a[1] = 0.0
    a[2, 3] = 0.0
    out = normalized_adjacency(a)
    for i in range(4):
        torch.testing.assert_close(out[i], normalized_adjacency(a[i]))


@pytest.mark.parametrize("dtype", [torch.float16, torch.bfloat16])
def test_low_precision_keeps_dtype(dtype):
    a = torch.rand(5, 5) + 0.1
    out = normalized_adjacency(a.to(dtype))
    assert out.dtype == dtype
    torch.testing.assert_close(out.float(), textbook(a.to(dtype).float()), atol=1e-2, rtol=1e-2)


@pytest.mark.parametrize(
    "bad, message",
    [
        (torch.ones(3, 4), r"\(N, N\) or \(B, N, N\) float, got \(3, 4\)"),
        (torch.ones(2, 2, 2, 2), r"got \(2, 2, 2, 2\)"),
        (torch.ones(3, 3, dtype=torch.int64), "torch.int64"),
    ],
)
def test_adjacency_bad_input(bad, message):
    with pytest.raises(ValueError, match=message):
        normalized_adjacency(bad)


# ---------------------------------------------------------------- GraphConv, pooling


def test_graph_conv_at_identity_is_a_per_node_linear():
    conv = GraphConv(5, 3, n_nodes=4)
    assert torch.equal(conv.adjacency.detach(), torch.eye(4))
    x = torch.randn(2, 4, 5)
    torch.testing.assert_close(conv(x), torch.nn.functional.leaky_relu(conv.linear(x), ACTIVATION_SLOPE))
    plain = GraphConv(5, 3, n_nodes=4, activation=False)
    torch.testing.assert_close(plain(x), plain.linear(x))


def test_graph_conv_mixes_nodes_with_the_normalised_adjacency():
    conv = GraphConv(2, 2, n_nodes=3, activation=False)
    with torch.no_grad():
        conv.adjacency.copy_(torch.tensor([[1.0, 1.0, 0.0], [1.0, 1.0, 1.0], [0.0, 1.0, 1.0]]))
        conv.linear.weight.copy_(torch.eye(2))
        conv.linear.bias.zero_()
    x = torch.randn(1, 3, 2)
    torch.testing.assert_close(conv(x), normalized_adjacency(conv.adjacency) @ x)


def test_graph_conv_bad_input():
    conv = GraphConv(5, 3, n_nodes=4)
    with pytest.raises(ValueError, match=r"\(B, 4, 5\), got \(2, 3, 5\)"):
        conv(torch.randn(2, 3, 5))
    with pytest.raises(ValueError, match="n_nodes must be a whole number >= 1"):
        GraphConv(5, 3, n_nodes=0)


@pytest.mark.parametrize("cls, n_in, n_out", [(GraphPool, 29, 15), (GraphUnpool, 15, 29)])
def test_pool_and_unpool_map_nodes(cls, n_in, n_out):
    layer = cls(n_in, n_out)
    assert layer.linear.weight.shape == (n_out, n_in)
    x = torch.randn(3, n_in, 8)
    out = layer(x)
    assert out.shape == (3, n_out, 8)
    # every channel is pooled by the same node map: out[:, k, c] = sum_j W[k, j] x[:, j, c] + b[k]
    expected = torch.einsum("kj,bjc->bkc", layer.linear.weight, x) + layer.linear.bias[None, :, None]
    torch.testing.assert_close(out, expected)
    with pytest.raises(ValueError, match=rf"\(B, {n_in}, C\), got \(3, {n_in + 1}, 8\)"):
        layer(torch.randn(3, n_in + 1, 8))


# ---------------------------------------------------------------- Graph U-Net, GraphNet2D


def test_default_node_counts():
    assert default_node_counts(29) == HOPENET_NODE_COUNTS == (15, 7, 4, 2, 1)
    assert default_node_counts(21) == (11, 6, 3, 2, 1)
    assert default_node_counts(2) == (1,)
    with pytest.raises(ValueError, match=">= 2"):
        default_node_counts(1)


def test_unet_node_counts_visible_in_parameter_shapes():
    unet = GraphUNet()
    levels = [29, 15, 7, 4, 2, 1]
    assert [tuple(c.adjacency.shape) for c in unet.encoder] == [(n, n) for n in levels[:-1]]
    assert [tuple(p.linear.weight.shape) for p in unet.pools] == [
        (15, 29), (7, 15), (4, 7), (2, 4), (1, 2)
    ]
    assert [tuple(u.linear.weight.shape) for u in unet.unpools] == [
        (2, 1), (4, 2), (7, 4), (15, 7), (29, 15)
    ]
    assert [tuple(c.adjacency.shape) for c in unet.decoder] == [(n, n) for n in (2, 4, 7, 15, 29)]
    # channels 2 -> 4 -> 8 -> 16 -> 32 -> 64 on the way down
    widths = [(c.in_features, c.out_features) for c in unet.encoder]
    assert widths == [(2, 4), (4, 8), (8, 16), (16, 32), (32, 64)]
    # up: unpooled + skip (+ the 2D input at the top), ending at 3 without activation
    assert [(c.in_features, c.out_features) for c in unet.decoder] == [
        (128, 32), (64, 16), (32, 8), (16, 4), (4 + 4 + 2, 3)
    ]
    assert isinstance(unet.decoder[-1].activation, torch.nn.Identity)
    shapes = {tuple(p.shape) for p in unet.parameters()}
    assert {(15, 29), (7, 15), (4, 7), (2, 4), (1, 2), (2, 1), (4, 2), (7, 4), (15, 7), (29, 15)} <= shapes


@pytest.mark.parametrize("batch", [1, 4])
def test_unet_shapes_and_gradients(batch):
    unet = GraphUNet()
    x = torch.randn(batch, 29, 2)
    out = unet(x)
    assert out.shape == (batch, 29, 3)
    out.sum().backward()
    for name, p in unet.named_parameters():
        assert p.grad is not None and torch.isfinite(p.grad).all(), name


def test_unet_other_node_counts_and_errors():
    assert GraphUNet(n_nodes=21)(torch.randn(2, 21, 2)).shape == (2, 21, 3)
    custom = GraphUNet(n_nodes=10, node_counts=(4, 1), channels=(6, 12))
    assert custom(torch.randn(2, 10, 2)).shape == (2, 10, 3)
    with pytest.raises(ValueError, match="decrease strictly"):
        GraphUNet(node_counts=(15, 15, 4, 2, 1))
    with pytest.raises(ValueError, match="end at 1"):
        GraphUNet(node_counts=(15, 7, 4, 2))
    with pytest.raises(ValueError, match="one entry per pooling"):
        GraphUNet(channels=(4, 8, 16))
    with pytest.raises(ValueError, match=r"\(B, 29, 2\), got \(1, 29, 3\)"):
        GraphUNet()(torch.randn(1, 29, 3))


def test_graphnet2d_shapes_and_feature_use():
    net = GraphNet2D(feature_dim=512)
    assert net.conv1.linear.in_features == 514
    widths = [(c.in_features, c.out_features) for c in (net.conv1, net.conv2, net.conv3)]
    assert widths == [(514, 128), (128, 16), (16, 2)]
    assert isinstance(net.conv3.activation, torch.nn.Identity)
    points = torch.randn(4, 29, 2)
    features = torch.randn(4, 512)
    out = net(points, features)
    assert out.shape == (4, 29, 2)
    with pytest.raises(ValueError, match=r"features must be \(B=4, 512\), got \(3, 512\)"):
        net(points, features[:3])
    with pytest.raises(ValueError, match=r"points2d must be \(B, 29, 2\)"):
        net(points[:, :21], features)
