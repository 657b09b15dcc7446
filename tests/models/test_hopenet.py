import pytest
import torch

from hupbench.models.hopenet import HOPENet, HOPENetConfig, HOPENetOutput
from hupbench.core.tolerances import (
    BF16_AUTOCAST_REL_2D,
    BF16_AUTOCAST_REL_2D_INIT,
    BF16_AUTOCAST_REL_3D,
    CHANNELS_LAST_REL,
)


def scaled_difference(approx: torch.Tensor, exact: torch.Tensor) -> float:
    """max |approx - exact| / max(1, max |exact|), the measure of CHANNELS_LAST_REL."""
    return ((approx - exact).abs().max() / exact.abs().max().clamp_min(1.0)).item()


def relative_error(approx: torch.Tensor, exact: torch.Tensor) -> float:
    """||approx - exact|| / ||exact||, the measure of the BF16_AUTOCAST_* tolerances."""
    return ((approx.float() - exact).norm() / exact.norm()).item()


@pytest.mark.parametrize("backbone", ["resnet10", "resnet18"])
@pytest.mark.parametrize("batch", [1, 4])
def test_output_shapes(backbone, batch):
    model = HOPENet(HOPENetConfig(backbone=backbone)).eval()
    with torch.no_grad():
        out = model(torch.randn(batch, 3, 64, 64))
    assert isinstance(out, HOPENetOutput)
    assert out.points2d_init.shape == (batch, 29, 2)
    assert out.points2d.shape == (batch, 29, 2)
    assert out.points3d.shape == (batch, 29, 3)
    assert all(torch.isfinite(t).all() for t in out)


def test_other_keypoint_count_and_input_size():
    model = HOPENet(HOPENetConfig(backbone="resnet10", n_keypoints=21)).eval()
    with torch.no_grad():
        out = model(torch.randn(2, 3, 96, 80))
    assert out.points3d.shape == (2, 21, 3) and out.points2d.shape == (2, 21, 2)
    assert model.unet.node_counts == (11, 6, 3, 2, 1)


@pytest.mark.parametrize("backbone", ["resnet10", "resnet18"])
def test_gradients_reach_every_parameter(backbone):
    torch.manual_seed(0)
    model = HOPENet(HOPENetConfig(backbone=backbone)).train()
    out = model(torch.randn(2, 3, 64, 64))
    sum(t.sum() for t in out).backward()
    for name, p in model.named_parameters():
        assert p.grad is not None, name
        assert torch.isfinite(p.grad).all(), name
        # graph layers use a leaky activation, so no unit is cut off at init (with a ReLU the
        # U-Net's 4-channel entry layer was dead in ~1/16 of inits, see hupbench.models.graph)
        assert p.grad.abs().sum() > 0, name


def test_each_stage_feeds_the_next():
    torch.manual_seed(0)
    model = HOPENet(HOPENetConfig(backbone="resnet10")).eval()
    images = torch.randn(2, 3, 64, 64)
    with torch.no_grad():
        out = model(images)
        features = model.backbone.features(images)
        torch.testing.assert_close(out.points2d_init, model.head2d(features).reshape(2, 29, 2))
        torch.testing.assert_close(out.points2d, model.graphnet(out.points2d_init, features))
        torch.testing.assert_close(out.points3d, model.unet(out.points2d))


@pytest.mark.parametrize("backbone", ["resnet10", "resnet18"])
def test_bf16_autocast_agrees_with_fp32(backbone):
    # tolerances measured over 120 random-init models, see core/tolerances.py
    torch.manual_seed(0)
    model = HOPENet(HOPENetConfig(backbone=backbone)).eval()
    images = torch.randn(4, 3, 96, 96)
    with torch.no_grad():
        ref = model(images)
        with torch.autocast("cpu", dtype=torch.bfloat16):
            low = model(images)
    assert low.points3d.dtype == torch.bfloat16  # autocast really ran in bf16
    assert relative_error(low.points3d, ref.points3d) < BF16_AUTOCAST_REL_3D
    assert relative_error(low.points2d_init, ref.points2d_init) < BF16_AUTOCAST_REL_2D_INIT
    assert relative_error(low.points2d, ref.points2d) < BF16_AUTOCAST_REL_2D


def test_channels_last_matches_contiguous():
    torch.manual_seed(0)
    model = HOPENet(HOPENetConfig(backbone="resnet18")).eval()
    images = torch.randn(2, 3, 64, 64)
    with torch.no_grad():
        ref = model(images)
        out = model(images.contiguous(memory_format=torch.channels_last))
    for name, a, b in zip(HOPENetOutput._fields, out, ref):
        assert scaled_difference(a, b) < CHANNELS_LAST_REL, name


def test_channels_last_model_and_input():
    torch.manual_seed(0)
    model = HOPENet(HOPENetConfig(backbone="resnet10")).eval()
    images = torch.randn(2, 3, 64, 64)
    with torch.no_grad():
        ref = model(images)
        model = model.to(memory_format=torch.channels_last)
        out = model(images.contiguous(memory_format=torch.channels_last))
    for name, a, b in zip(HOPENetOutput._fields, out, ref):
        assert scaled_difference(a, b) < CHANNELS_LAST_REL, name


def test_no_device_moves_and_only_parameters_or_bn_buffers():
    model = HOPENet(HOPENetConfig(backbone="resnet10"))
    assert {t.device.type for t in model.state_dict().values()} == {"cpu"}
    buffers = {name.rsplit(".", 1)[-1] for name, _ in model.named_buffers()}
    # batch-norm statistics and the fixed 3D prior (models/prior.py)
    assert buffers == {"running_mean", "running_var", "num_batches_tracked", "mean"}


def test_bad_arguments():
    with pytest.raises(ValueError, match="unknown ResNet 'resnet9'"):
        HOPENetConfig(backbone="resnet9")
    with pytest.raises(ValueError, match="n_keypoints must be a whole number >= 2, got 1"):
        HOPENetConfig(n_keypoints=1)
    with pytest.raises(ValueError, match=r"images must be \(B, 3, H, W\) float, got \(2, 64, 64\)"):
        HOPENet()(torch.randn(2, 64, 64))
