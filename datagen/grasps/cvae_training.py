"""Training the grasp CVAE of :mod:`hupbench.datagen.grasps.cvae`: its corpus of refined grasps and the loop.

:func:`train_sampler` is what ``hupbench train-grasp-sampler`` runs: :func:`build_corpus` refines
randomised starts at random probe orientations and keeps the plausible grasps, :func:`train_cvae`
fits the CVAE to them (the loss is :func:`hupbench.datagen.grasps.cvae.cvae_loss`), and the weights are
saved with their provenance.

Convention:
    Generator frame (probe at Theta_Vol, centred at its volume centroid),
    metres and radians; see :mod:`hupbench.datagen.grasps.frames`.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass

import numpy as np
import torch

from hupbench.datagen.grasps import bps
from hupbench.datagen.grasps.approach import approach_azimuth, to_generator_frame
from hupbench.datagen.grasps.cvae import CORPUS_KEYS, CVAEConfig, GraspCVAE, cvae_loss, save_cvae
from hupbench.datagen.grasps.cvae_sampling import condition
from hupbench.datagen.grasps.frames import T_gen_probe
from hupbench.datagen.grasps.params import PARAM_DIM, pack
from hupbench.datagen.grasps.refine import GraspEnergy, RefineConfig, random_starts, refine
from hupbench.core.input_checks import check_int, check_number
from hupbench.core.errors import BadValueError, RunFailedError


def _float32_corpus(corpus: Mapping[str, np.ndarray], n_bps: int) -> dict[str, np.ndarray]:
    """The corpus's four arrays as C-contiguous float32; :func:`build_corpus` made them."""
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
        from hupbench.datagen.assets.hand import build_hand

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


@dataclass(frozen=True)
class CorpusConfig:
    """How the sampler's training corpus is made.

    Attributes:
        n_orientations: random probe orientations (uniform rotations).
        starts_per_orientation: randomised starts refined per orientation.
        iterations: refinement steps.
        seed: for the orientations and the starts.
        bps_n, bps_radius_m, bps_seed: the basis point set.
        bps_exact: exact mesh distances for the BPS features instead of the grid.
    """

    n_orientations: int = 64
    starts_per_orientation: int = 24
    iterations: int = 250
    seed: int = 1
    bps_n: int = bps.DEFAULT_N_BASIS
    bps_radius_m: float = bps.DEFAULT_RADIUS_M
    bps_seed: int = 0
    bps_exact: bool = False

    def __post_init__(self) -> None:
        for name in ("n_orientations", "starts_per_orientation", "bps_n"):
            check_int(getattr(self, name), name, low=1)
        check_int(self.bps_seed, "bps_seed", low=0)
        check_number(self.bps_radius_m, "bps_radius_m", 0.0, low_open=True)


def build_corpus(config: CorpusConfig, hand, probe, log=print) -> dict[str, np.ndarray]:
    """Refine randomised starts at random orientations; keep the plausible results.

    Returns:
        corpus dict: "x" (M, 54), "bps" (M, n), "init_rot6d" (M, 6), "init_trans" (M, 3),
        "theta" (M, 3) degrees, plus "n_refined" (scalar) for the record.
    """
    from scipy.spatial.transform import Rotation

    from hupbench.datagen.grasps.scores import score_grasps

    rng = np.random.default_rng(config.seed)
    energy = GraspEnergy(hand, probe, RefineConfig(iterations=config.iterations))
    basis = bps.basis_points(config.bps_n, config.bps_radius_m, config.bps_seed)
    thetas = Rotation.random(config.n_orientations, random_state=config.seed).as_euler("XYZ", degrees=True)
    parts = {k: [] for k in ("x", "bps", "init_rot6d", "init_trans", "theta")}
    limits = hand.buffers(torch.float64)["limits"]
    start_time = time.perf_counter()
    refined_total = 0
    for k, theta in enumerate(thetas):
        starts = random_starts(config.starts_per_orientation, rng, hand.limits_rad, approach_azimuth(theta, probe))
        refined = refine(energy, starts)
        refined_total += len(refined)
        keep = score_grasps(energy, refined)["plausible"]
        if keep.any():
            cond = condition(starts.take(keep), theta, probe, basis, config.bps_exact)
            gen = to_generator_frame(refined.take(keep), T_gen_probe(theta, probe))
            unit = ((torch.as_tensor(gen.angles) - limits[..., 0]) / (limits[..., 1] - limits[..., 0])).clamp(0, 1)
            x = pack(torch.as_tensor(gen.R_global), torch.as_tensor(gen.trans), unit).numpy().astype(np.float32)
            for key, value in (("x", x), *cond.items(), ("theta", np.repeat(theta[None], len(x), 0))):
                parts[key].append(value)
        kept = sum(len(v) for v in parts["x"])
        log(f"  orientation {k + 1}/{len(thetas)}: {int(keep.sum())}/{len(refined)} plausible, "
            f"{kept} kept, {time.perf_counter() - start_time:.0f} s")
    if not parts["x"]:
        raise RunFailedError("no plausible grasp in the whole corpus: check the refinement settings")
    if kept < 2:
        raise BadValueError(f"corpus needs at least 2 grasps (one to train on, one to validate), got {kept}")
    corpus = {k: np.concatenate(v) for k, v in parts.items()}
    corpus["n_refined"] = np.array(refined_total)
    return corpus


def train_sampler(corpus_config: CorpusConfig, cvae_config: CVAEConfig, out_path, hand, probe, log=print) -> dict:
    """Build the corpus, train the CVAE and save it with its provenance.

    Returns:
        dict with "path", "corpus_size", "n_refined", "history" and "seconds".
    """
    start = time.perf_counter()
    if cvae_config.n_bps != corpus_config.bps_n:
        raise BadValueError(f"cvae n_bps ({cvae_config.n_bps}) must equal corpus bps_n ({corpus_config.bps_n})")
    corpus = build_corpus(corpus_config, hand, probe, log=log)
    log(f"training the CVAE on {len(corpus['x'])} grasps")
    model, history = train_cvae({k: corpus[k] for k in ("x", "bps", "init_rot6d", "init_trans")}, cvae_config,
                                log=log)
    metadata = {"bps_n": corpus_config.bps_n, "bps_radius_m": corpus_config.bps_radius_m,
                "bps_seed": corpus_config.bps_seed, "bps_exact": corpus_config.bps_exact,
                "corpus": asdict(corpus_config), "corpus_size": int(len(corpus["x"])),
                "n_refined": int(corpus["n_refined"]), "final": history[-1] if history else {}}
    path = save_cvae(model, cvae_config, out_path, metadata)
    return {"path": str(path), "corpus_size": int(len(corpus["x"])), "n_refined": int(corpus["n_refined"]),
            "history": history, "seconds": time.perf_counter() - start}
