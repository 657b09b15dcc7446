import pytest
import torch

from models.baseline import ResNetRegressor
from models.build import MODEL_REGISTRY, build_model, load_checkpoint_state
from models.heatmap import HUPNet
from models.hopenet import HOPENet


def test_registry():
    assert MODEL_REGISTRY == {"hopenet": HOPENet, "hupnet": HUPNet, "resnet_regressor": ResNetRegressor}


@pytest.mark.parametrize(
    "cfg, cls",
    [
        ({"name": "hopenet", "backbone": "resnet10", "n_keypoints": 29}, HOPENet),
        ({"name": "hopenet", "backbone": "resnet18", "graph_hidden": [64, 8]}, HOPENet),
        ({"name": "resnet_regressor", "backbone": "resnet18", "predict_2d": True}, ResNetRegressor),
    ],
)
def test_round_trip_through_config_and_state(cfg, cls):
    torch.manual_seed(0)
    model = build_model(cfg)
    assert isinstance(model, cls)
    for key, value in cfg.items():
        assert model.config[key] == value
    # what a checkpoint stores: the plain config and the state dict
    config = model.config
    state = {k: v.clone() for k, v in model.state_dict().items()}
    torch.manual_seed(1)
    rebuilt = load_checkpoint_state(build_model(config), state)
    assert rebuilt.config == config
    model.eval()
    rebuilt.eval()
    images = torch.randn(2, 3, 64, 64)
    with torch.no_grad():
        for a, b in zip(model(images), rebuilt(images)):
            assert (a is None and b is None) or torch.equal(a, b)


def test_config_is_a_copy():
    model = build_model({"name": "hopenet"})
    model.config["graph_hidden"].append(3)
    assert model.config["graph_hidden"] == [128, 16]


def test_unknown_name_names_it_and_the_known_ones():
    with pytest.raises(ValueError, match=r"unknown model 'posenet'; known: hopenet, hupnet, resnet_regressor"):
        build_model({"name": "posenet"})


def test_missing_name_and_bad_keys():
    with pytest.raises(ValueError, match="no 'name'.*hopenet"):
        build_model({"backbone": "resnet10"})
    with pytest.raises(ValueError, match=r"does not take dropout.*backbone, n_keypoints"):
        build_model({"name": "hopenet", "dropout": 0.1})
    with pytest.raises(TypeError, match="mapping"):
        build_model("hopenet")


def test_checkpoint_of_another_model_names_missing_and_unexpected_keys():
    hopenet = build_model({"name": "hopenet", "backbone": "resnet10"})
    regressor = build_model({"name": "resnet_regressor", "backbone": "resnet10"})
    with pytest.raises(ValueError) as info:
        load_checkpoint_state(hopenet, regressor.state_dict())
    message = str(info.value)
    assert "missing keys" in message and "unexpected keys" in message
    assert "head3d.weight" in message  # unexpected: only the regressor has it
    assert "graphnet.conv1.adjacency" in message  # missing: only HOPE-Net has it
    assert "shape mismatches" not in message


def test_shape_mismatch_is_named():
    small = build_model({"name": "hopenet", "backbone": "resnet10", "n_keypoints": 21})
    full = build_model({"name": "hopenet", "backbone": "resnet10", "n_keypoints": 29})
    expected = r"shape mismatches .*head2d.weight \(checkpoint \(42, 512\), model \(58, 512\)\)"
    with pytest.raises(ValueError, match=expected):
        load_checkpoint_state(full, small.state_dict())


def test_backbone_mismatch_and_bad_state():
    r10 = build_model({"name": "resnet_regressor", "backbone": "resnet10"})
    r18 = build_model({"name": "resnet_regressor", "backbone": "resnet18"})
    with pytest.raises(ValueError, match=r"missing keys \(\d+\): backbone.layer1.1.bn1.bias"):
        load_checkpoint_state(r18, r10.state_dict())
    state = dict(r10.state_dict())
    state["head3d.bias"] = [0.0] * 87
    with pytest.raises(ValueError, match="head3d.bias \\(not a tensor: list\\)"):
        load_checkpoint_state(r10, state)
    with pytest.raises(TypeError, match="mapping"):
        load_checkpoint_state(r10, list(state.items()))
    with pytest.raises(TypeError, match="torch.nn.Module"):
        load_checkpoint_state(state, state)
