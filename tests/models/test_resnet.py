import pytest
import torch

from hupbench.models.resnet import RESNET_SPECS, ResNetOutput, resnet, strip_classifier
from hupbench.core.tolerances import CHANNELS_LAST_REL


def scaled_difference(approx: torch.Tensor, exact: torch.Tensor) -> float:
    """max |approx - exact| / max(1, max |exact|), the measure of CHANNELS_LAST_REL."""
    return ((approx - exact).abs().max() / exact.abs().max().clamp_min(1.0)).item()



def torchvision_style_state(kind: str, layers: tuple[int, ...], num_classes: int = 1000) -> dict:
    """A state dict with torchvision's ResNet key names and shapes, written from its layout.

    Built independently of hupbench.models.resnet: stem conv1 7x7/bn1, four stages of BasicBlocks
    (conv1/bn1/conv2/bn2) or v1.5 Bottlenecks (conv1/bn1/conv2/bn2/conv3/bn3), a
    ``downsample.0`` (1x1 conv) / ``downsample.1`` (BN) in the first block of a stage whose
    shape changes, and ``fc``. Every BN has weight, bias, running_mean, running_var and an
    int64 num_batches_tracked.
    """
    gen = torch.Generator().manual_seed(0)
    state = {}

    def conv(name, out_ch, in_ch, k):
        state[f"{name}.weight"] = torch.randn(out_ch, in_ch, k, k, generator=gen)

    def bn(name, ch):
        state[f"{name}.weight"] = torch.rand(ch, generator=gen) + 0.5
        state[f"{name}.bias"] = torch.randn(ch, generator=gen)
        state[f"{name}.running_mean"] = torch.randn(ch, generator=gen)
        state[f"{name}.running_var"] = torch.rand(ch, generator=gen) + 0.5
        state[f"{name}.num_batches_tracked"] = torch.tensor(123, dtype=torch.int64)

    conv("conv1", 64, 3, 7)
    bn("bn1", 64)
    expansion = 1 if kind == "basic" else 4
    in_ch = 64
    for stage, (planes, n_blocks) in enumerate(zip((64, 128, 256, 512), layers), start=1):
        for b in range(n_blocks):
            prefix = f"layer{stage}.{b}"
            stride = 2 if stage > 1 and b == 0 else 1
            if kind == "basic":
                conv(f"{prefix}.conv1", planes, in_ch, 3)
                bn(f"{prefix}.bn1", planes)
                conv(f"{prefix}.conv2", planes, planes, 3)
                bn(f"{prefix}.bn2", planes)
            else:
                conv(f"{prefix}.conv1", planes, in_ch, 1)
                bn(f"{prefix}.bn1", planes)
                conv(f"{prefix}.conv2", planes, planes, 3)
                bn(f"{prefix}.bn2", planes)
                conv(f"{prefix}.conv3", planes * 4, planes, 1)
                bn(f"{prefix}.bn3", planes * 4)
            if stride != 1 or in_ch != planes * expansion:
                conv(f"{prefix}.downsample.0", planes * expansion, in_ch, 1)
                bn(f"{prefix}.downsample.1", planes * expansion)
            in_ch = planes * expansion
    state["fc.weight"] = torch.randn(num_classes, in_ch, generator=gen)
    state["fc.bias"] = torch.randn(num_classes, generator=gen)
    return state


@pytest.mark.parametrize(
    "name, kind, layers, fc_in",
    [
        ("resnet18", "basic", (2, 2, 2, 2), 512),
        ("resnet34", "basic", (3, 4, 6, 3), 512),
        ("resnet50", "bottleneck", (3, 4, 6, 3), 2048),
    ],
)
def test_torchvision_state_dict_loads_strictly(name, kind, layers, fc_in):
    state = torchvision_style_state(kind, layers)
    assert state["conv1.weight"].shape == (64, 3, 7, 7)
    assert state["fc.weight"].shape == (1000, fc_in)
    assert "layer2.0.downsample.0.weight" in state and "bn1.num_batches_tracked" in state
    model = resnet(name, num_classes=1000)
    result = model.load_state_dict(state, strict=True)
    assert not result.missing_keys and not result.unexpected_keys
    loaded = model.state_dict()
    assert set(loaded) == set(state)
    for key, value in state.items():
        assert torch.equal(loaded[key], value), key


def test_resnet10_follows_the_same_naming():
    state = torchvision_style_state("basic", (1, 1, 1, 1), num_classes=7)
    resnet("resnet10", num_classes=7).load_state_dict(state, strict=True)


def test_parameter_counts_match_torchvision():
    # published sizes of torchvision's ImageNet ResNets
    assert sum(p.numel() for p in resnet("resnet18", 1000).parameters()) == 11_689_512
    assert sum(p.numel() for p in resnet("resnet34", 1000).parameters()) == 21_797_672
    assert sum(p.numel() for p in resnet("resnet50", 1000).parameters()) == 25_557_032


def test_classifier_checkpoint_into_backbone_after_strip():
    state = torchvision_style_state("basic", (2, 2, 2, 2))
    backbone = resnet("resnet18")
    with pytest.raises(RuntimeError, match="fc.weight"):
        backbone.load_state_dict(state, strict=True)
    stripped = strip_classifier(state)
    assert set(state) - set(stripped) == {"fc.weight", "fc.bias"}
    backbone.load_state_dict(stripped, strict=True)


@pytest.mark.parametrize(
    "name, width", [("resnet10", 512), ("resnet18", 512), ("resnet34", 512), ("resnet50", 2048)]
)
@pytest.mark.parametrize("batch", [1, 2])
def test_feature_and_logit_shapes(name, width, batch):
    model = resnet(name, num_classes=10).eval()
    assert model.feature_dim == width
    with torch.no_grad():
        out = model(torch.randn(batch, 3, 64, 64))
    assert isinstance(out, ResNetOutput)
    assert out.features.shape == (batch, width)
    assert out.logits.shape == (batch, 10)
    assert torch.equal(model.fc(out.features), out.logits)


def test_backbone_without_fc():
    model = resnet("resnet18").eval()
    assert model.fc is None
    assert not any(key.startswith("fc.") for key in model.state_dict())
    with torch.no_grad():
        out = model(torch.randn(2, 3, 40, 56))
    assert out.features.shape == (2, 512) and out.logits is None


def test_unknown_name_lists_known_ones():
    with pytest.raises(ValueError, match="resnet101") as info:
        resnet("resnet101")
    for known in RESNET_SPECS:
        assert known in str(info.value)


@pytest.mark.parametrize(
    "bad, message",
    [
        (torch.randn(3, 64, 64), r"\(B, 3, H, W\) float, got \(3, 64, 64\)"),
        (torch.randn(1, 1, 64, 64), r"got \(1, 1, 64, 64\)"),
        (torch.zeros(1, 3, 64, 64, dtype=torch.uint8), "torch.uint8"),
    ],
)
def test_bad_images(bad, message):
    with pytest.raises(ValueError, match=message):
        resnet("resnet10")(bad)


@pytest.mark.parametrize("name, last_bn", [("resnet18", "bn2"), ("resnet50", "bn3")])
def test_zero_init_residual_makes_blocks_start_as_identity_branches(name, last_bn):
    zeroed = resnet(name, zero_init_residual=True)
    plain = resnet(name)
    for model, expect_zero in ((zeroed, True), (plain, False)):
        for stage in (model.layer1, model.layer2, model.layer3, model.layer4):
            for block in stage:
                weight = getattr(block, last_bn).weight
                assert bool((weight == 0).all()) is expect_zero
    # a block whose branch is zeroed returns relu(shortcut(x))
    block = zeroed.layer1[0].eval()
    x = torch.randn(2, block.conv1.in_channels, 8, 8)
    with torch.no_grad():
        shortcut = x if block.downsample is None else block.downsample(x)
        assert torch.allclose(block(x), torch.relu(shortcut), atol=1e-6)


def test_channels_last_matches_contiguous():
    torch.manual_seed(0)
    model = resnet("resnet50", num_classes=5).eval()
    images = torch.randn(2, 3, 64, 64)
    with torch.no_grad():
        ref = model(images)
        out = model(images.contiguous(memory_format=torch.channels_last))
    assert scaled_difference(out.features, ref.features) < CHANNELS_LAST_REL
    assert scaled_difference(out.logits, ref.logits) < CHANNELS_LAST_REL
