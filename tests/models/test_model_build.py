import pytest
import torch

from hupbench.models.baseline import ResNetRegressor, ResNetRegressorConfig
from hupbench.models.build import MODELS, build_model, load_checkpoint_state
from hupbench.models.heatmap import HUPNet, HUPNetConfig
from hupbench.models.hopenet import HOPENet, HOPENetConfig


def test_every_model_has_its_config():
    assert MODELS == {"hopenet": (HOPENetConfig, HOPENet), "hupnet": (HUPNetConfig, HUPNet),
                      "resnet_regressor": (ResNetRegressorConfig, ResNetRegressor)}


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
    saved = model.config.saved()
    for key, value in cfg.items():
        assert saved[key] == value
    # what a checkpoint stores: the plain config and the state dict
    state = {k: v.clone() for k, v in model.state_dict().items()}
    torch.manual_seed(1)
    rebuilt = load_checkpoint_state(build_model(saved), state)
    assert rebuilt.config == model.config and rebuilt.config.saved() == saved
    model.eval()
    rebuilt.eval()
    images = torch.randn(2, 3, 64, 64)
    with torch.no_grad():
        for a, b in zip(model(images), rebuilt(images)):
            assert (a is None and b is None) or torch.equal(a, b)


def test_saved_config_is_plain_and_a_copy():
    """Lists, not tuples (JSON and torch.load(weights_only=True) keep them as written), and editing one
    saved dict changes neither the model nor the next one."""
    model = build_model({"name": "hopenet", "points3d_mean": [[0.0, 0.0, 0.5]] * 29})
    saved = model.config.saved()
    assert saved["graph_hidden"] == [128, 16] and saved["points3d_mean"][0] == [0.0, 0.0, 0.5]
    saved["graph_hidden"].append(3)
    assert model.config.saved()["graph_hidden"] == [128, 16] and model.config.graph_hidden == (128, 16)


def test_checkpoint_config_of_the_code_before_loads():
    """A published HOPE-Net's saved config of the code before this config class named no lift, K_input,
    input_size or unet_image_channels: it rebuilds with their defaults."""
    old = {"name": "hopenet", "backbone": "resnet10", "n_keypoints": 29, "graph_hidden": [128, 16],
           "unet_channels": [4, 8, 16, 32, 64], "unet_node_counts": None, "unet_bottleneck": 20,
           "zero_init_residual": False, "points3d_mean": None, "points3d_scale": 0.01}
    model = build_model(old)
    assert model.config.lift == "direct" and model.config.unet_image_channels == 0
    assert {k: v for k, v in model.config.saved().items() if k in old} == old


def test_unknown_name_names_it_and_the_known_ones():
    with pytest.raises(ValueError, match=r"unknown model 'posenet'; known: hopenet, hupnet, resnet_regressor"):
        build_model({"name": "posenet"})


def test_missing_name_and_bad_keys():
    with pytest.raises(ValueError, match="unknown model None; known: hopenet"):
        build_model({"backbone": "resnet10"})
    with pytest.raises(ValueError, match=r"does not take dropout.*backbone, n_keypoints"):
        build_model({"name": "hopenet", "dropout": 0.1})


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


@pytest.mark.parametrize(("key", "part"), [("probe_fit", "the probe"), ("hand_fit", "the hand")])
def test_the_fits_are_checked_where_the_model_is_built(key, part):
    with pytest.raises(ValueError, match=f"{key} must be 'none' or 'depth', got 'icp'"):
        build_model({"name": "hopenet", "backbone": "resnet10", key: "icp"})
    with pytest.raises(ValueError, match=f"{key} 'depth' fits {part} to the depth input: it needs "
                                         "data.reader.input_modalities=rgb\\+depth"):
        build_model({"name": "hopenet", "backbone": "resnet10", key: "depth"})
    built = build_model({"name": "hopenet", "backbone": "resnet10", key: "depth", "input_channels": 4})
    assert built.config.saved()[key] == "depth"


@pytest.mark.parametrize("hands,message", [
    ([[[0.0, 0.0, 0.5]] * 21] * 2, None),
    ([[[0.0, 0.0, 0.5]] * 20], r"hand_templates must be \(T, 21, 3\), got \(1, 20, 3\)"),
    ([[[0.0, 0.0, float("nan")]] * 21], "hand_templates must hold finite numbers"),
])
def test_hand_templates_are_a_finite_set_of_hands_saved_as_lists(hands, message):
    """A fitting model's training hands (the hand fit's starts, set by training) are checked where the config is
    built; a config without them (every model file before) has None."""
    if message is not None:
        with pytest.raises(ValueError, match=message):
            HUPNetConfig(hand_templates=hands)
        return
    config = HUPNetConfig(hand_templates=hands)
    assert config.saved()["hand_templates"] == hands and HUPNetConfig().hand_templates is None
