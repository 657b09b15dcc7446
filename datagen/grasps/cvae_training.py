"""Training the grasp CVAE of :mod:`datagen.grasps.cvae` on a corpus of refined grasps.

:func:`train_cvae` is what ``hupbench train-grasp-sampler`` runs (through
:mod:`datagen.grasps.cvae_sampling`, which makes the corpus); the loss is :func:`datagen.grasps.cvae.cvae_loss`.

Convention:
    Generator frame (probe at Theta_Vol, centred at its volume centroid),
    metres and radians; see :mod:`datagen.grasps.frames`.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping

import numpy as np
import torch

from datagen.grasps.cvae import CORPUS_KEYS, CVAEConfig, GraspCVAE, cvae_loss
from datagen.grasps.params import PARAM_DIM


def _float32_corpus(corpus: Mapping[str, np.ndarray], n_bps: int) -> dict[str, np.ndarray]:
    """The corpus's four arrays as C-contiguous float32; :func:`cvae_sampling.build_corpus` made them."""
    widths = {"x": PARAM_DIM, "bps": n_bps, "init_rot6d": 6, "init_trans": 3}
    arrays = {key: np.ascontiguousarray(corpus[key], dtype=np.float32) for key in CORPUS_KEYS}
    for key, arr in arrays.items():
        assert arr.ndim == 2 and arr.shape == (len(arrays["x"]), widths[key]), (key, arr.shape)
        assert np.isfinite(arr).all(), key
    assert len(arrays["x"]) >= 2, "build_corpus refuses fewer grasps"
    return arrays


def _loss_weights(config: CVAEConfig) -> dict[str, float]:
    return {name: getattr(config, name)
            for name in ("kl_weight", "keypoint_weight", "rot_weight", "trans_weight", "joint_weight")}


def _evaluate(model: GraspCVAE, data: dict[str, torch.Tensor], index: torch.Tensor, hand_model,
              config: CVAEConfig) -> dict[str, float]:
    """Loss parts on ``index`` with z = posterior mean, weighted by batch size."""
    model.eval()
    sums: dict[str, float] = {}
    with torch.no_grad():
        for start in range(0, len(index), config.batch_size):
            idx = index[start:start + config.batch_size]
            out = model(data["x"][idx], data["bps"][idx], data["init_rot6d"][idx], data["init_trans"][idx])
            for name, value in cvae_loss(out, data["x"][idx], hand_model, **_loss_weights(config)).items():
                sums[name] = sums.get(name, 0.0) + float(value) * len(idx)
    return {name: total / len(index) for name, total in sums.items()}


def train_cvae(corpus: Mapping[str, np.ndarray], config: CVAEConfig = CVAEConfig(),
               log: Callable[[str], None] | None = print,
               device: str | torch.device = "cpu") -> tuple[GraspCVAE, list[dict]]:
    """Train the grasp CVAE with Adam on a corpus of (condition, grasp) pairs.

    A seeded ``val_fraction`` of the rows is held out. Validation uses the
    posterior mean (eval mode). The weights of the epoch with the lowest
    validation total loss are restored at the end. Deterministic on CPU for
    a given ``config.seed`` and torch thread count (initial weights, split,
    shuffling and the reparameterisation noise are all seeded; the global
    torch RNG is left as it was; a different thread count changes float
    summation order in the last bits).

    Args:
        corpus: "x" (M, 54), "bps" (M, n_bps), "init_rot6d" (M, 6), "init_trans" (M, 3), float,
            generator frame (other keys are ignored), M >= 2.
        config: architecture and training hyperparameters.
        log: called with one line per epoch; None for silence.
        device: where to train, e.g. "cpu" or "cuda" (torch refuses a device that is not there).

    Returns:
        (model in eval mode on ``device``, history): one dict per epoch with
        "epoch", "lr", "seconds", and "train_<part>" / "val_<part>" for every
        part of :func:`cvae_loss`.
    """
    arrays = _float32_corpus(corpus, config.n_bps)
    dev = torch.device(device)
    n_rows = arrays["x"].shape[0]
    n_val = max(1, int(round(config.val_fraction * n_rows)))
    perm = np.random.default_rng(config.seed).permutation(n_rows)
    val_index = torch.as_tensor(perm[:n_val], device=dev)
    train_index = torch.as_tensor(perm[n_val:], device=dev)
    data = {key: torch.from_numpy(arr).to(dev) for key, arr in arrays.items()}

    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(config.seed)
        model = GraspCVAE(config).to(dev)
    hand_model = None
    if config.keypoint_weight > 0:
        from datagen.assets.hand import build_hand

        hand_model = build_hand()
    optimiser = torch.optim.Adam(model.parameters(), lr=config.lr)
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimiser, T_max=config.epochs, eta_min=0.1 * config.lr)
    shuffle_gen = torch.Generator().manual_seed(config.seed)
    noise_gen = torch.Generator(device=dev).manual_seed(config.seed + 1)

    history: list[dict] = []
    best_total, best_state = math.inf, None
    for epoch in range(1, config.epochs + 1):
        started = time.perf_counter()
        lr = optimiser.param_groups[0]["lr"]
        model.train()
        order = train_index[torch.randperm(len(train_index), generator=shuffle_gen).to(dev)]
        sums: dict[str, float] = {}
        for start in range(0, len(order), config.batch_size):
            idx = order[start:start + config.batch_size]
            out = model(data["x"][idx], data["bps"][idx], data["init_rot6d"][idx], data["init_trans"][idx],
                        generator=noise_gen)
            parts = cvae_loss(out, data["x"][idx], hand_model, **_loss_weights(config))
            optimiser.zero_grad(set_to_none=True)
            parts["total"].backward()
            optimiser.step()
            for name, value in parts.items():
                sums[name] = sums.get(name, 0.0) + float(value.detach()) * len(idx)
        schedule.step()
        val = _evaluate(model, data, val_index, hand_model, config)
        record = {"epoch": epoch, "lr": lr, **{f"train_{k}": v / len(order) for k, v in sums.items()},
                  **{f"val_{k}": v for k, v in val.items()}, "seconds": time.perf_counter() - started}
        history.append(record)
        if val["total"] < best_total:
            best_total = val["total"]
            best_state = {k: v.detach().clone() for k, v in model.state_dict().items()}
        if log is not None:
            keypoints = f" kp {val['keypoint_mm']:.2f} mm" if "keypoint_mm" in val else ""
            log(f"epoch {epoch:3d}/{config.epochs}: train {record['train_total']:.4f} | val {val['total']:.4f} "
                f"(rot {val['rot']:.4f} trans {val['trans_cm']:.3f} cm joint {val['joint']:.4f}{keypoints} "
                f"kl {val['kl']:.2f}) {record['seconds']:.1f} s")
    model.load_state_dict(best_state)
    model.eval()
    if log is not None:
        best = min(history, key=lambda r: r["val_total"])
        log(f"restored epoch {best['epoch']} (val total {best['val_total']:.4f})")
    return model, history


