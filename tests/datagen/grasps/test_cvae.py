"""Tests for the grasp sampler's conditional VAE (datagen/grasps/cvae.py)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch

import hupbench.datagen.grasps.cvae as cvae_module
from hupbench.datagen.grasps.cvae import (
    CVAEConfig,
    CVAEOutput,
    GraspCVAE,
    cvae_loss,
    grasp_to_residual,
    load_cvae,
    load_shipped_cvae,
    residual_to_grasp,
    save_cvae,
)
from hupbench.datagen.grasps.cvae_training import train_cvae
from hupbench.datagen.grasps.params import JOINTS, PARAM_DIM, ROT, TRANS
from hupbench.datagen.assets.hand import build_hand
from hupbench.core.rotations_torch import axis_angle_to_matrix, matrix_to_rot6d, rot6d_to_matrix

#: small enough to train in about a second, with the default latent size
TINY = CVAEConfig(n_bps=32, hidden=64, bps_embed=16, epochs=30, batch_size=32, lr=5e-3, keypoint_weight=0.0)


@pytest.fixture(scope="module", autouse=True)
def single_thread():
    # models this small gain nothing from intra-op threads, and on a shared
    # two-core machine contended thread pools slowed training 50-fold
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture(scope="module")
def hand():
    return build_hand()


def _condition(batch: int, n_bps: int, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    bps = 0.15 * torch.rand(batch, n_bps, generator=g)
    init_rot6d = matrix_to_rot6d(axis_angle_to_matrix(torch.randn(batch, 3, generator=g)))
    init_trans = 0.08 * torch.randn(batch, 3, generator=g)
    return bps, init_rot6d, init_trans


def _grasps(batch: int, seed: int = 1) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    R = axis_angle_to_matrix(torch.randn(batch, 3, generator=g))
    return torch.cat([matrix_to_rot6d(R), 0.08 * torch.randn(batch, 3, generator=g),
                      torch.rand(batch, 45, generator=g)], dim=-1)


def _synthetic_corpus(m: int, n_bps: int, seed: int = 0) -> dict[str, np.ndarray]:
    """Grasps that are a smooth function of a 3-vector hidden in the condition, plus noise."""
    rng = np.random.default_rng(seed)
    t = rng.normal(size=(m, 3))
    bps = 0.06 + 0.04 * np.sin(t @ rng.normal(size=(3, n_bps)))
    init_rot6d = matrix_to_rot6d(axis_angle_to_matrix(torch.as_tensor(0.5 * t))).numpy()
    init_trans = 0.05 * t
    R = axis_angle_to_matrix(torch.as_tensor(0.5 * t + 0.2 * np.tanh(t[:, ::-1])))
    x = np.concatenate([
        matrix_to_rot6d(R).numpy(),
        init_trans + 0.02 * np.tanh(t @ rng.normal(size=(3, 3))),
        1.0 / (1.0 + np.exp(-(t @ rng.normal(size=(3, 45))))),
    ], axis=1)
    x += 0.003 * rng.normal(size=x.shape)
    return {"x": x.astype(np.float32), "bps": bps.astype(np.float32),
            "init_rot6d": init_rot6d.astype(np.float32), "init_trans": init_trans.astype(np.float32)}


# ----------------------------------------------------------------------------- model


@pytest.mark.parametrize("batch", [1, 4])
def test_output_shapes(batch):
    config = CVAEConfig(n_bps=64, hidden=32, bps_embed=16)
    model = GraspCVAE(config)
    bps, init_rot6d, init_trans = _condition(batch, 64)
    out = model(_grasps(batch), bps, init_rot6d, init_trans)
    assert isinstance(out, CVAEOutput)
    assert out.x_hat.shape == (batch, PARAM_DIM)
    assert out.mu.shape == (batch, 16) and out.logvar.shape == (batch, 16)
    assert model.decode(torch.zeros(batch, 16), bps, init_rot6d, init_trans).shape == (batch, PARAM_DIM)
    sampled = model.sample(bps, init_rot6d, init_trans)
    assert sampled.shape == (batch, PARAM_DIM) and not sampled.requires_grad
    # the rotation part is always a proper rotation's 6D form
    R = rot6d_to_matrix(out.x_hat[:, ROT])
    torch.testing.assert_close(matrix_to_rot6d(R), out.x_hat[:, ROT], atol=1e-5, rtol=0)


def test_residual_round_trip_and_zero_residual_is_the_initial_pose():
    x = _grasps(8)
    _, init_rot6d, init_trans = _condition(8, 4)
    residual = grasp_to_residual(x, init_rot6d, init_trans)
    torch.testing.assert_close(residual_to_grasp(residual, init_rot6d, init_trans), x, atol=1e-5, rtol=0)
    start = residual_to_grasp(torch.zeros(8, PARAM_DIM), init_rot6d, init_trans)
    torch.testing.assert_close(start[:, ROT], init_rot6d, atol=1e-6, rtol=0)
    torch.testing.assert_close(start[:, TRANS], init_trans)
    torch.testing.assert_close(start[:, JOINTS], torch.full((8, 45), 0.5))
    # the translation offset is expressed in the initial hand frame, in units of 5 cm
    offset = torch.zeros(8, PARAM_DIM)
    offset[:, 6] = 1.0
    moved = residual_to_grasp(offset, init_rot6d, init_trans)
    torch.testing.assert_close(moved[:, TRANS] - init_trans, 0.05 * rot6d_to_matrix(init_rot6d)[:, :, 0])


def test_untrained_model_stays_near_the_initial_pose():
    torch.manual_seed(0)
    model = GraspCVAE().eval()
    bps, init_rot6d, init_trans = _condition(16, 1024)
    x_hat = model.sample(bps, init_rot6d, init_trans, torch.Generator().manual_seed(0))
    assert (x_hat[:, TRANS] - init_trans).norm(dim=-1).max() < 0.02
    assert (x_hat[:, JOINTS] - 0.5).abs().max() < 0.3


def test_gradients_reach_every_parameter(hand):
    torch.manual_seed(0)
    model = GraspCVAE(CVAEConfig(n_bps=64, hidden=32, bps_embed=16)).train()
    x = _grasps(6)
    out = model(x, *_condition(6, 64), generator=torch.Generator().manual_seed(0))
    cvae_loss(out, x, hand)["total"].backward()
    for name, param in model.named_parameters():
        assert param.grad is not None, name
        assert torch.isfinite(param.grad).all(), name
        assert param.grad.abs().max() > 0, name


# ----------------------------------------------------------------------------- loss


def test_loss_known_values(hand):
    x = _grasps(5)
    zeros = torch.zeros(5, 16)
    exact = cvae_loss(CVAEOutput(x.clone(), zeros, zeros), x, hand)
    for name, value in exact.items():
        assert abs(float(value)) < 1e-4, name
    # a 1 cm shift along x: mean |d trans| over three axes is 1/3 cm, every keypoint moves 10 mm
    shifted = x.clone()
    shifted[:, 6] += 0.01
    parts = cvae_loss(CVAEOutput(shifted, torch.ones(5, 16), zeros), x, hand, kl_weight=0.5, keypoint_weight=0.1)
    assert float(parts["trans_cm"]) == pytest.approx(1 / 3, rel=1e-4)
    assert float(parts["keypoint_mm"]) == pytest.approx(10.0, rel=1e-4)
    assert float(parts["rot"]) == pytest.approx(0.0, abs=1e-6)
    assert float(parts["kl"]) == pytest.approx(0.5 * 16)  # mu = 1, sigma = 1 in 16 dimensions
    assert float(parts["recon"]) == pytest.approx(1 / 3 * CVAEConfig.trans_weight + 0.1 * 10.0, rel=1e-4)
    assert float(parts["total"]) == pytest.approx(float(parts["recon"]) + 0.5 * 8.0, rel=1e-5)
    # without a hand model there is no keypoint term
    assert "keypoint_mm" not in cvae_loss(CVAEOutput(shifted, zeros, zeros), x)


# ----------------------------------------------------------------------------- sampling


def test_sampling_is_deterministic_with_a_seeded_generator():
    torch.manual_seed(0)
    model = GraspCVAE(CVAEConfig(n_bps=64, hidden=32, bps_embed=16)).eval()
    cond = _condition(4, 64)
    a = model.sample(*cond, generator=torch.Generator().manual_seed(11))
    b = model.sample(*cond, generator=torch.Generator().manual_seed(11))
    c = model.sample(*cond, generator=torch.Generator().manual_seed(12))
    torch.testing.assert_close(a, b, atol=0, rtol=0)
    assert (a - c).abs().max() > 1e-4


# ----------------------------------------------------------------------------- weights I/O


@pytest.fixture()
def saved(tmp_path):
    torch.manual_seed(0)
    config = CVAEConfig(n_bps=64, hidden=32, bps_embed=16, epochs=7)
    model = GraspCVAE(config).eval()
    path = save_cvae(model, config, tmp_path / "w" / "grasp_cvae.npz", {"corpus": "synthetic", "n": 3})
    return model, config, path


def test_save_load_round_trip(saved):
    model, config, path = saved
    assert [p.name for p in path.parent.iterdir()] == ["grasp_cvae.npz"]  # no temporary file left behind
    loaded, loaded_config, metadata = load_cvae(path)
    assert loaded_config == config and metadata == {"corpus": "synthetic", "n": 3}
    assert not loaded.training
    x, cond = _grasps(4), _condition(4, 64)
    torch.testing.assert_close(loaded(x, *cond).x_hat, model(x, *cond).x_hat, atol=0, rtol=0)
    gen_a, gen_b = torch.Generator().manual_seed(3), torch.Generator().manual_seed(3)
    torch.testing.assert_close(loaded.sample(*cond, generator=gen_a), model.sample(*cond, generator=gen_b),
                               atol=0, rtol=0)
    with np.load(path, allow_pickle=False) as npz:
        assert all(npz[name].dtype == np.float32 for name in npz.files if name != "__header__")


def _rewrite(path, edit) -> None:
    with np.load(path, allow_pickle=False) as npz:
        entries = {name: npz[name] for name in npz.files}
    edit(entries)
    with open(path, "wb") as handle:
        np.savez(handle, **entries)


def test_load_rejects_missing_extra_and_misshapen_weights(saved):
    _, _, path = saved
    _rewrite(path, lambda e: e.pop("decoder.out.weight"))
    with pytest.raises(ValueError, match=r"missing keys \['decoder.out.weight'\]"):
        load_cvae(path)
    _rewrite(path, lambda e: e.update({"decoder.out.weight": np.zeros((54, 32), np.float32),
                                       "decoder.extra.bias": np.zeros(3, np.float32)}))
    with pytest.raises(ValueError, match=r"unexpected keys \['decoder.extra.bias'\]"):
        load_cvae(path)
    _rewrite(path, lambda e: e.pop("decoder.extra.bias"))
    load_cvae(path)  # repaired
    _rewrite(path, lambda e: e.update({"bps_encoder.0.weight": np.zeros((16, 65), np.float32)}))
    with pytest.raises(ValueError, match=r"'bps_encoder.0.weight' has shape \(16, 65\), expected \(16, 64\)"):
        load_cvae(path)
    _rewrite(path, lambda e: e.pop("__header__"))
    with pytest.raises(ValueError, match="not a grasp CVAE weights file"):
        load_cvae(path)


def test_load_missing_file(tmp_path):
    with pytest.raises(FileNotFoundError, match="no grasp CVAE weights"):
        load_cvae(tmp_path / "absent.npz")


def test_shipped_weights(saved, tmp_path, monkeypatch):
    _, config, path = saved
    monkeypatch.setattr(cvae_module, "SHIPPED_WEIGHTS", tmp_path / "absent.npz")
    with pytest.raises(FileNotFoundError, match=cvae_module.RETRAIN_COMMAND):
        load_shipped_cvae()
    monkeypatch.setattr(cvae_module, "SHIPPED_WEIGHTS", path)
    assert load_shipped_cvae()[1] == config


# ----------------------------------------------------------------------------- training


def test_training_lowers_validation_reconstruction():
    corpus = _synthetic_corpus(256, TINY.n_bps)
    lines = []
    state = torch.random.get_rng_state()
    model, history = train_cvae(corpus, TINY, log=lines.append)
    torch.testing.assert_close(torch.random.get_rng_state(), state)  # the global RNG is left alone
    assert len(history) == TINY.epochs and len(lines) == TINY.epochs + 1
    first, last = history[0]["val_recon"], history[-1]["val_recon"]
    assert last < 0.5 * first, (first, last)
    assert history[-1]["train_total"] < 0.5 * history[0]["train_total"]
    # the restored model is the best-validation epoch, in eval mode
    assert not model.training
    data = {k: torch.from_numpy(v) for k, v in corpus.items()}
    with torch.no_grad():
        out = model(data["x"], data["bps"], data["init_rot6d"], data["init_trans"])
    assert math.isfinite(float(cvae_loss(out, data["x"], keypoint_weight=0.0)["total"]))


def test_training_is_deterministic_and_logs_keypoints():
    corpus = _synthetic_corpus(64, TINY.n_bps)
    config = dataclasses.replace(TINY, epochs=2, keypoint_weight=0.1)
    _, a = train_cvae(corpus, config, log=None)
    model_b, b = train_cvae(corpus, config, log=None)
    for ra, rb in zip(a, b):
        assert {k: v for k, v in ra.items() if k != "seconds"} == {k: v for k, v in rb.items() if k != "seconds"}
    assert "val_keypoint_mm" in a[-1] and a[-1]["val_keypoint_mm"] > 0
    _, c = train_cvae(corpus, dataclasses.replace(config, seed=1), log=None)
    assert c[-1]["val_total"] != a[-1]["val_total"]


@pytest.mark.parametrize(
    ("fields", "error", "match"),
    [
        ({"latent_dim": 0}, ValueError, "latent_dim must be a whole number >= 1"),
        ({"epochs": 1.5}, TypeError, "epochs must be a whole number"),
        ({"lr": 0.0}, ValueError, "lr must be a finite number > 0"),
        ({"kl_weight": float("nan")}, ValueError, "kl_weight"),
        ({"val_fraction": 0.7}, ValueError, "val_fraction"),
        ({"seed": -1}, ValueError, "seed"),
    ],
)
def test_config_validation(fields, error, match):
    with pytest.raises(error, match=match):
        CVAEConfig(**fields)
