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


def test_field_names_shared_with_hopenet_and_hupnet():
    """Its points as HOPE-Net names them, its segmentation as HUPNet does (eval, export and the loss read them)."""
    from hupbench.models.heatmap import HUPNetOutput

    assert set(RegressorOutput._fields) - {"segmentation"} <= set(HOPENetOutput._fields)
    assert "segmentation" in HUPNetOutput._fields


def test_the_segmentation_head_labels_every_input_pixel_and_is_trained_through():
    """With ``segmentation``: (B, 3, S, S) logits from the stride-8 stage and the RGB-D input, the gradient of a
    cross-entropy on them reaching the head and the backbone below the stage; the export's wrapper hands the fits
    each pixel's class."""
    from hupbench.inference.export import ContractModule

    torch.manual_seed(0)
    model = ResNetRegressor(ResNetRegressorConfig(backbone="resnet18", input_channels=4, segmentation=True)).train()
    images = torch.rand(2, 4, 64, 64)
    out = model(images)
    assert out.segmentation.shape == (2, 3, 64, 64) and out.segmentation.dtype == torch.float32
    torch.nn.functional.cross_entropy(out.segmentation, torch.randint(0, 3, (2, 64, 64))).backward()
    for name in ("seg_features.weight", "seg_head.0.weight", "seg_head.2.weight", "backbone.layer2.0.conv1.weight"):
        grad = dict(model.named_parameters())[name].grad
        assert grad is not None and grad.abs().sum() > 0, name
    assert dict(model.named_parameters())["backbone.layer4.0.conv1.weight"].grad is None   # the stage above: not
    wrapped = ContractModule(model.eval(), [[60.0, 0, 32], [0, 60.0, 32], [0, 0, 1]], 64)
    assert wrapped.outputs[-1] == "segmentation"
    with torch.no_grad():
        classes = wrapped(images[:, :3], images[:, 3:])[-1]
    assert classes.shape == (2, 64, 64) and torch.equal(classes, model(images).segmentation.argmax(dim=1))
    assert ResNetRegressor(ResNetRegressorConfig(backbone="resnet18")).eval()(images[:, :3]).segmentation is None


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
