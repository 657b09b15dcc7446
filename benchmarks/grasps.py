"""Grasp generation, error against run time.

For the refinement alone (randomised starts) and for the sampler + refinement
(CVAE proposals), refine the same number of candidates with growing
iteration budgets and print, per budget: wall time, plausible fraction,
plausible grasps per minute, and the distribution of penetration and pads in
contact, and the spread of the plausible grasps (mean pairwise joint distance
within an orientation). "heuristic" is the baseline of one hand-made start per
orientation. Each budget is a fresh run (Adam restarts), measured in one process.

Usage: python benchmarks/grasps.py [--orientations 4] [--starts 16] [--budgets 0 25 50 100 200 300]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch


def diversity_mm(hand, grasps, plausible: np.ndarray, orientation: np.ndarray) -> float:
    """Mean pairwise distance (mm, averaged over the 21 joints) between plausible grasps of the
    same orientation, averaged over orientations; 0 where fewer than two are plausible."""
    with torch.no_grad():
        keypoints, _ = hand.forward_torch(torch.as_tensor(grasps.R_global), torch.as_tensor(grasps.trans),
                                          torch.as_tensor(grasps.angles), vertex_index=torch.arange(1))
    keypoints = keypoints.numpy()
    spreads = []
    for k in np.unique(orientation):
        kp_ok = keypoints[(orientation == k) & plausible]
        if len(kp_ok) < 2:
            spreads.append(0.0)
            continue
        d = np.linalg.norm(kp_ok[:, None] - kp_ok[None], axis=-1).mean(axis=-1)  # (n, n) mean over joints
        spreads.append(1000.0 * d[np.triu_indices(len(kp_ok), 1)].mean())
    return float(np.mean(spreads))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--orientations", type=int, default=4, help="probe orientations (about the handle axis)")
    parser.add_argument("--starts", type=int, default=16, help="candidates per orientation")
    parser.add_argument("--budgets", type=int, nargs="+", default=[0, 25, 50, 100, 200, 300])
    parser.add_argument("--samplers", nargs="+", default=["heuristic", "random", "cvae"],
                        choices=["heuristic", "random", "cvae"])
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    if args.orientations < 1 or args.starts < 1 or min(args.budgets) < 0:
        parser.error("--orientations and --starts must be positive, --budgets >= 0")
    torch.set_num_threads(args.threads)

    from hupbench.datagen.grasps.cvae_sampling import sample_grasps
    from hupbench.datagen.grasps.approach import approach_azimuth
    from hupbench.datagen.grasps.refine import GraspBatch, GraspEnergy, RefineConfig, heuristic_starts, random_starts, refine
    from hupbench.datagen.grasps.scores import score_grasps
    from hupbench.datagen.assets.hand import build_hand
    from hupbench.datagen.assets.probe import build_probe
    from hupbench.datagen.grasps.cvae import load_shipped_cvae

    hand, probe = build_hand(), build_probe()
    thetas = [(0.0, 0.0, 360.0 * k / args.orientations) for k in range(args.orientations)]
    model = load_shipped_cvae() if "cvae" in args.samplers else None
    print(f"{len(thetas)} orientations x {args.starts} candidates, torch threads {args.threads}")
    print(f"{'sampler':8s} {'iters':>5s} {'seconds':>8s} {'plausible':>9s} {'per min':>8s} "
          f"{'pen p50/p90 mm':>15s} {'pads p50':>8s} {'thumb':>6s} {'spread mm':>10s}")
    for sampler in args.samplers:
        for budget in args.budgets:
            rng = np.random.default_rng(args.seed)
            energy = GraspEnergy(hand, probe, RefineConfig(iterations=budget))
            start = time.perf_counter()
            batches = []
            for theta in thetas:
                if sampler == "cvae":
                    starts = sample_grasps(args.starts, theta, probe, hand, rng, model)
                elif sampler == "heuristic":
                    starts = heuristic_starts(args.starts, hand.limits_rad, approach_azimuth(theta, probe))
                else:
                    starts = random_starts(args.starts, rng, hand.limits_rad, approach_azimuth(theta, probe))
                batches.append(refine(energy, starts) if budget else starts)
            seconds = time.perf_counter() - start
            grasps = GraspBatch.concat(batches)
            scores = score_grasps(energy, grasps)
            ok = scores["plausible"]
            spread = diversity_mm(hand, grasps, ok, np.repeat(np.arange(len(thetas)), args.starts))
            pen = scores["max_penetration_mm"]
            print(f"{sampler:8s} {budget:5d} {seconds:8.1f} {ok.mean():9.2f} {60.0 * ok.sum() / seconds:8.1f} "
                  f"{np.median(pen):7.1f}/{np.percentile(pen, 90):<7.1f} {np.median(scores['pads_in_contact']):8.0f} "
                  f"{scores['thumb_contact'].mean():6.2f} {spread:10.1f}", flush=True)


if __name__ == "__main__":
    main()
