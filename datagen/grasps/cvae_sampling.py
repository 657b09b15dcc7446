"""The sampling stage: CVAE proposals conditioned on the probe's BPS and the initial wrist.

Convention:
    The CVAE works in the generator frame of each Theta_Vol; everything it
    returns here is converted back to the probe frame. Metres and radians.
"""

from __future__ import annotations

import numpy as np
import torch

from hupbench.datagen.grasps import bps
from hupbench.datagen.grasps.cvae import CVAEConfig, GraspCVAE, load_shipped_cvae
from hupbench.datagen.grasps.approach import approach_azimuth, to_generator_frame
from hupbench.datagen.grasps.frames import T_gen_probe
from hupbench.datagen.grasps.params import unit_to_angles, unpack
from hupbench.datagen.grasps.refine import GraspBatch, random_starts
from hupbench.core.rotations_torch import matrix_to_rot6d


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
