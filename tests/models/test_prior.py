import pytest
import torch

from hupbench.models.build import build_model, load_checkpoint_state
from hupbench.models.hopenet import HOPENetConfig


@pytest.mark.parametrize("name,backbone", [("hopenet", "resnet10"), ("resnet_regressor", "resnet10")])
def test_prior_shifts_and_scales_the_3d_output(name, backbone):
    torch.manual_seed(0)
    mean = torch.linspace(-0.1, 0.9, 29 * 3).reshape(29, 3)
    plain = build_model({"name": name, "backbone": backbone}).eval()
    shifted = build_model({"name": name, "backbone": backbone, "points3d_mean": mean.tolist(),
                           "points3d_scale": 0.1}).eval()
    shifted.load_state_dict(plain.state_dict() | {"prior3d.mean": mean}, strict=True)
    images = torch.rand(2, 3, 64, 64)
    with torch.no_grad():
        raw = plain(images).points3d
        out = shifted(images).points3d
    torch.testing.assert_close(out, raw * 0.1 + mean, rtol=1e-5, atol=1e-6)


def test_prior_survives_config_and_state_round_trip():
    mean = [[0.01 * i, -0.02 * i, 0.6] for i in range(29)]
    model = build_model({"name": "hopenet", "backbone": "resnet10", "points3d_mean": mean, "points3d_scale": 0.1})
    rebuilt = load_checkpoint_state(build_model(model.config.saved()), model.state_dict())
    assert rebuilt.config.saved()["points3d_mean"] == [[float(v) for v in row] for row in mean]
    assert rebuilt.config.points3d_scale == 0.1
    torch.testing.assert_close(rebuilt.prior3d.mean, torch.tensor(mean))


@pytest.mark.parametrize("mean,scale,match", [
    ([[0.0, 0.0, 0.0]] * 28, 1.0, r"points3d_mean must be a finite \(29, 3\) layout, got shape \(28, 3\)"),
    ([[0.0, 0.0, float("nan")]] * 29, 1.0, r"points3d_mean must be a finite \(29, 3\) layout"),
    (None, 0.0, "points3d_scale must be a finite number > 0, got 0.0"),
    (None, float("inf"), "points3d_scale must be a finite number > 0"),
])
def test_bad_prior(mean, scale, match):
    with pytest.raises(ValueError, match=match):
        HOPENetConfig(points3d_mean=mean, points3d_scale=scale)
