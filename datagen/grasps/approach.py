"""Where the operator's hand comes from, and grasps moved between the probe and generator frames.

For each probe orientation Theta_Vol the hand approaches from the same side of the generator
frame (the operator's side, -y), so the orientation decides which face of the handle it meets.
Both the generator (:mod:`hupbench.datagen.grasps.synthesis`) and the CVAE sampler
(:mod:`hupbench.datagen.grasps.cvae_sampling`) follow this rule.

Convention:
    Probe frame (lens apex at the origin) and the generator frame of a Theta_Vol
    (:mod:`hupbench.datagen.grasps.frames`); metres and radians.
"""

from __future__ import annotations

import numpy as np

from hupbench.datagen.grasps import frames
from hupbench.datagen.grasps.refine import GraspBatch

#: the operator stands on the generator frame's -y side
APPROACH_GEN = np.array([0.0, -1.0, 0.0])


def approach_azimuth(theta_vol_deg, probe) -> float:
    """Azimuth (radians, about the probe's +z) of the operator's side in the probe frame."""
    T = frames.T_gen_probe(theta_vol_deg, probe)
    a = T[:3, :3].T @ APPROACH_GEN  # the operator's side, in the probe frame
    if np.hypot(a[0], a[1]) < 1e-6:
        return 0.0  # looking straight along the handle: any side; keep the canonical one
    # turn the canonical grip (hand on the probe's -y side) to the operator's side
    return float(np.arctan2(a[1], a[0]) - np.arctan2(-1.0, 0.0))


def to_generator_frame(grasps: GraspBatch, T_gen_probe: np.ndarray) -> GraspBatch:
    """Express probe-frame grasps in a generator frame (rotation about the wrist + move).

    Args:
        grasps: hand poses in the probe frame.
        T_gen_probe: (4, 4) float64, maps probe-frame points into the generator frame.
    """
    R = T_gen_probe[:3, :3]
    return GraspBatch(R @ grasps.R_global, grasps.trans @ R.T + T_gen_probe[:3, 3], grasps.angles, grasps.energy)

