"""Where the fits after the network help or hurt: per-frame hand and probe MPJPE of a model on evenly spaced frames of
a split, the network alone against the network with its fits (the model's own, e.g. the probe and the hand fitted to
the depth), and how many frames each leaves beyond a bound. Diagnoses on val by default.

Usage: python scripts/fit_divergence.py CHECKPOINT DATASET [--split val] [--frames 240] [--bound-mm 100]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np


def main() -> None:
    from hupbench.core import keypoints as kp
    from hupbench.evaluation.prediction import EvalModel, evenly_spaced, predict_split, split_reader

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("model", help="a hupbench checkpoint (.pt) whose model runs fits after the network")
    parser.add_argument("dataset", help="a finished dataset folder")
    parser.add_argument("--split", default="val", choices=("train", "val", "test"))
    parser.add_argument("--frames", type=int, default=240, help="evenly spaced frames of the split (0: all)")
    parser.add_argument("--bound-mm", type=float, default=100.0, help="a frame's hand MPJPE beyond this counts as lost")
    args = parser.parse_args()
    net = EvalModel(Path(args.model))
    reader = split_reader(Path(args.dataset), args.split, net)
    rows = evenly_spaced(len(reader), args.frames)
    hand = {}
    for fits in (False, True):
        p = predict_split(net, reader, 32, rows, with_fits=fits)
        err_mm = 1000.0 * np.linalg.norm(p.points3d - p.labels3d, axis=-1)
        hand[fits], probe = err_mm[:, kp.HAND_SLICE].mean(axis=1), err_mm[:, kp.CORNER_SLICE].mean(axis=1)
        print(f"{'network + fits' if fits else 'network alone '}: hand MPJPE mean {hand[fits].mean():.1f} mm, median "
              f"{np.median(hand[fits]):.1f}, 90th percentile {np.percentile(hand[fits], 90):.1f}, max {hand[fits].max():.1f}; "
              f"probe mean {probe.mean():.1f}, median {np.median(probe):.1f}; hand beyond {args.bound_mm:g} mm on "
              f"{int((hand[fits] > args.bound_mm).sum())} of {len(rows)} {args.split} frames", flush=True)
    change = hand[True] - hand[False]
    print(f"the fits make the hand worse on {int((change > 0).sum())} of {len(rows)} frames, better on "
          f"{int((change < 0).sum())}; median change {np.median(change):+.1f} mm")


if __name__ == "__main__":
    main()
