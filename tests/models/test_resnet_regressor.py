import pytest
import torch

from hupbench.models.baseline import RegressorOutput, ResNetRegressor, ResNetRegressorConfig
from hupbench.models.hopenet import HOPENetOutput
from hupbench.core.tolerances import CHANNELS_LAST_REL


def scaled_difference(approx: torch.Tensor, exact: torch.Tensor) -> float:
    """max |approx - exact| / max(1, max |exact|), the measure of CHANNELS_LAST_REL."""
    return ((approx - exact).abs().max() / exact.abs().max().clamp_min(1.0)).item()



@pytest.mark.parametrize("backbone", ["resnet18", "resnet50"])
@pytest.mark.parametrize("batch", [1, 4])
def test_output_shapes(backbone, batch):
    model = ResNetRegressor(ResNetRegressorConfig(backbone=backbone)).eval()
    with torch.no_grad():
        out = model(torch.randn(batch, 3, 64, 64))
    assert isinstance(out, RegressorOutput)
    assert out.points2d is None
    assert out.points3d.shape == (batch, 29, 3)


@pytest.mark.parametrize("batch", [1, 4])
def test_side_output_2d(batch):
    model = ResNetRegressor(ResNetRegressorConfig(backbone="resnet18", predict_2d=True)).eval()
    with torch.no_grad():
        out = model(torch.randn(batch, 3, 64, 64))
    assert out.points2d.shape == (batch, 29, 2) and out.points3d.shape == (batch, 29, 3)


def test_field_names_shared_with_hopenet():
    assert set(RegressorOutput._fields) <= set(HOPENetOutput._fields)


@pytest.mark.parametrize("backbone, predict_2d", [("resnet50", False), ("resnet18", True)])
def test_gradients_reach_every_parameter(backbone, predict_2d):
    torch.manual_seed(0)
    model = ResNetRegressor(ResNetRegressorConfig(backbone=backbone, predict_2d=predict_2d)).train()
    out = model(torch.randn(2, 3, 64, 64))
    sum(t.sum() for t in out if t is not None).backward()
    for name, p in model.named_parameters():
        assert p.grad is not None, name
        assert torch.isfinite(p.grad).all(), name
        assert p.grad.abs().sum() > 0, name


def test_channels_last_matches_contiguous():
    torch.manual_seed(0)
    model = ResNetRegressor(ResNetRegressorConfig(backbone="resnet50", predict_2d=True)).eval()
    images = torch.randn(2, 3, 64, 64)
    with torch.no_grad():
        ref = model(images)
        out = model(images.contiguous(memory_format=torch.channels_last))
    assert scaled_difference(out.points3d, ref.points3d) < CHANNELS_LAST_REL
    assert scaled_difference(out.points2d, ref.points2d) < CHANNELS_LAST_REL


def test_bad_arguments():
    with pytest.raises(ValueError, match="n_keypoints must be a whole number >= 1, got 0"):
        ResNetRegressorConfig(n_keypoints=0)
    with pytest.raises(ValueError, match="predict_2d must be true or false, got 'yes'"):
        ResNetRegressorConfig(predict_2d="yes")
    with pytest.raises(ValueError, match="unknown ResNet 'resnet152'"):
        ResNetRegressorConfig(backbone="resnet152")
