"""The sampling stage: CVAE proposals conditioned on the probe's BPS and the initial wrist.

Also builds the training corpus (refinement from randomised starts at random
probe orientations) and trains the sampler that ships with the package.

Convention:
    The CVAE works in the generator frame of each Theta_Vol; everything it
    returns here is converted back to the probe frame. Metres and radians.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass

import numpy as np
import torch

from datagen.grasps import bps
from datagen.grasps.cvae import CVAEConfig, GraspCVAE, load_shipped_cvae, save_cvae
from datagen.grasps.cvae_training import train_cvae
from datagen.grasps.approach import approach_azimuth, to_generator_frame
from datagen.grasps.frames import T_gen_probe
from datagen.grasps.params import pack, unit_to_angles, unpack
from datagen.grasps.refine import GraspBatch, GraspEnergy, RefineConfig, random_starts, refine
from datagen.input_checks import check_int, check_number
from datagen.rotations_torch import matrix_to_rot6d
from datagen.errors import BadValueError, RunFailedError


def condition(starts: GraspBatch, theta, probe, basis: np.ndarray, bps_exact: bool) -> dict[str, np.ndarray]:
    """The CVAE condition of probe-frame starts: BPS of the rotated probe and the initial wrist.

    Returns:
        dict with "bps" (B, n) float32 metres, "init_rot6d" (B, 6), "init_trans" (B, 3) metres,
        both in the generator frame.
    """
    gen = to_generator_frame(starts, T_gen_probe(theta, probe))
    features = bps.encode_probe(probe, theta, basis, exact=bps_exact)
    R = torch.as_tensor(gen.R_global)
    return {
        "bps": np.broadcast_to(features, (len(starts), len(features))).astype(np.float32),
        "init_rot6d": matrix_to_rot6d(R).numpy().astype(np.float32),
        "init_trans": gen.trans.astype(np.float32),
    }


def sample_grasps(n: int, theta, probe, hand, rng: np.random.Generator,
                  model: tuple[GraspCVAE, CVAEConfig, dict] | None = None) -> GraspBatch:
    """Propose n grasps for one probe orientation with the CVAE.

    Args:
        n: number of proposals.
        theta: (3,) Theta_Vol, degrees.
        probe, hand: the models.
        rng: numpy generator; draws the initial wrists and seeds the latent samples.
        model: (model, config, metadata) as from :func:`load_shipped_cvae`; default the shipped one.

    Returns:
        :class:`GraspBatch` in the probe frame (to be refined briefly).
    """
    net, _, meta = model or load_shipped_cvae()
    basis = bps.basis_points(meta["bps_n"], meta["bps_radius_m"], meta["bps_seed"])
    starts = random_starts(n, rng, hand.limits_rad, approach_azimuth(theta, probe))
    cond = condition(starts, theta, probe, basis, meta["bps_exact"])
    generator = torch.Generator().manual_seed(int(rng.integers(2**62)))
    net.eval()
    with torch.no_grad():
        x = net.sample(*(torch.as_tensor(cond[k]) for k in ("bps", "init_rot6d", "init_trans")),
                       generator=generator).double()
    R, trans, unit = unpack(x)
    angles = unit_to_angles(unit, hand.buffers(torch.float64)["limits"])
    gen = GraspBatch(R.numpy(), trans.numpy(), angles.numpy())
    T = T_gen_probe(theta, probe)
    return to_generator_frame(gen, np.linalg.inv(T))


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

    from datagen.grasps.scores import score_grasps

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
    corpus = {k: np.concatenate(v) for k, v in parts.items()}
    if len(corpus["x"]) < 2:
        raise BadValueError(f"corpus needs at least 2 grasps (one to train on, one to validate), got {len(corpus['x'])}")
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
