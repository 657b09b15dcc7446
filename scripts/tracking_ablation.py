"""How the fits track a clip: per-frame fits against fits started where they left the frame before
(:func:`hupbench.fits.track_fits`), over whole clips of a split, for a few step counts; the error (all / hand /
probe), the acceleration error and the fits' time per frame at batch 1, then each fit's own time and the probe fit's
decisions. The tracking settings of :class:`hupbench.fits.settings.ProbeFitSettings` and ``HandFitSettings`` were
chosen with it on val (docs/sequences.md); it defaults to val.

Usage: python scripts/tracking_ablation.py MODEL DATASET [--split val] [--clips 8]

MODEL is a checkpoint of a model with both fits (``probe_fit: depth``, ``hand_fit: depth``); DATASET a dataset of
clips (``hupbench generate +track=clinic_sequences``). ``--clips`` clips evenly spread over the split run whole.
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections import Counter
from pathlib import Path

import numpy as np


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("model", type=Path, help="a checkpoint of a model with both fits")
    parser.add_argument("dataset", type=Path, help="a dataset of clips")
    parser.add_argument("--split", default="val", choices=("train", "val", "test"))
    parser.add_argument("--clips", type=int, default=8, help="clips run, evenly spread over the split")
    args = parser.parse_args()
    if args.clips < 1:
        parser.error("--clips must be positive")

    import torch

    from hupbench.core import keypoints as kp
    from hupbench.core.contract import SEGMENT_CLASSES, is_sequence, read_annotations, read_manifest
    from hupbench.core.errors import BadValueError
    from hupbench.evaluation.prediction import EvalModel, predict_split, split_reader
    from hupbench.fits import after_network, fits, track_fits
    from hupbench.fits.hand_fit import fit_hand
    from hupbench.fits.probe_fit import DECISIONS, fit_probe
    from hupbench.fits.settings import HandFitSettings, ProbeFitSettings

    manifest = read_manifest(args.dataset)
    if not is_sequence(manifest):
        raise BadValueError(f"{args.dataset} is not a dataset of clips (hupbench generate +track=clinic_sequences)")
    net = EvalModel(args.model)
    if fits(net.model_config) != ("probe", "hand"):
        raise BadValueError(f"{args.model} does not fit both the probe and the hand (probe_fit, hand_fit: depth)")
    torch.set_num_threads(2)
    clip = np.asarray(read_annotations(args.dataset, args.split, ("clip_id",), manifest)["clip_id"])
    names = np.unique(clip)
    chosen = names[np.linspace(0, len(names) - 1, min(args.clips, len(names))).round().astype(int)]
    rows = np.flatnonzero(np.isin(clip, chosen))
    out = predict_split(net, split_reader(args.dataset, args.split, net), 32, rows, with_fits=False,
                        keep_images=True)
    images, segmentation, truth, of_clip, K = np.concatenate(out.images), out.segmentation, out.labels3d, clip[rows], \
        net.K_input
    firsts = np.r_[True, of_clip[1:] != of_clip[:-1]]
    print(f"{args.model} on {len(chosen)} {args.split} clips ({len(rows)} frames) of {args.dataset}, batch 1")

    def scores(points: np.ndarray) -> str:
        error = np.linalg.norm(points - truth, axis=-1) * 1000
        accel = np.mean([np.linalg.norm(np.diff(points[of_clip == c], 2, 0) - np.diff(truth[of_clip == c], 2, 0),
                                        axis=-1).mean() * 1000 for c in chosen])
        return (f"{error.mean():6.2f} / {error[:, kp.HAND_SLICE].mean():6.2f} / {error[:, kp.CORNER_SLICE].mean():6.2f}"
                f"   accel {accel:6.2f}")

    def run(probe: ProbeFitSettings, hand: HandFitSettings, tracked: bool) -> tuple[np.ndarray, float]:
        points, seconds, start = np.empty_like(truth), [], None
        for i in range(len(rows)):
            begun = time.perf_counter()
            frame = (net.model_config, out.points2d[i:i + 1], out.points3d[i:i + 1], images[i:i + 1], K)
            if tracked:
                _, p3, start = track_fits(*frame, None if firsts[i] else start, probe, hand, net.fit_probe,
                                          None if segmentation is None else segmentation[i:i + 1])
            else:
                _, p3 = after_network(*frame, probe, hand, net.fit_probe, None if segmentation is None else segmentation[i:i + 1])
            seconds.append(time.perf_counter() - begun)
            points[i] = p3[0]
        return points, 1e3 * statistics.median(seconds)

    P, H = ProbeFitSettings, HandFitSettings
    print(f"{'fits':48s}{'all / hand / probe (mm)':>26s}{'':14s}{'fits ms/frame':>14s}")
    print(f"{'none (the network)':48s}{scores(out.points3d)}")
    for name, probe, hand, tracked in (
            ("per frame (defaults)", P(), H(), False),
            ("per frame, hand 2 steps", P(), H(iterations=2), False),
            ("from the frame before: probe 2, hand 2 steps", P(tracking_iterations=2), H(tracking_iterations=2), True),
            ("from the frame before: probe 4, hand 2 steps", P(tracking_iterations=4), H(tracking_iterations=2), True),
            ("from the frame before: probe 6, hand 2 steps", P(tracking_iterations=6), H(tracking_iterations=2), True),
            ("from the frame before: probe 4, hand 1 step", P(tracking_iterations=4), H(tracking_iterations=1), True)):
        points, ms = run(probe, hand, tracked)
        print(f"{name:48s}{scores(points)}{ms:14.2f}", flush=True)

    own = {part: np.ones(images[:, 0].shape, bool) if segmentation is None else
           segmentation == SEGMENT_CLASSES.index(part) for part in ("probe", "hand")}
    times: dict[str, list[float]] = {"probe, per frame": [], "probe, from the frame before": [],
                                     "hand, 8 steps": [], "hand, 2 steps": []}
    decisions: dict[str, Counter] = {"per frame": Counter(), "from the frame before": Counter()}
    start = None
    for i in range(len(rows)):
        frame = (out.points2d[i:i + 1], out.points3d[i:i + 1], images[i:i + 1], K)
        for name, begin in (("per frame", None), ("from the frame before", None if firsts[i] else start)):
            begun = time.perf_counter()
            p2, p3, report = fit_probe(*frame, probe=net.fit_probe, pixels=own["probe"][i:i + 1], start=begin)
            times[f"probe, {name}"].append(time.perf_counter() - begun)
            decisions[name][DECISIONS[report.decision[0]]] += 1
        start = report.pose
        for name, steps in (("hand, 8 steps", 8), ("hand, 2 steps", 2)):
            begun = time.perf_counter()
            fit_hand(p2, p3, images[i:i + 1], K, H(iterations=steps), net.fit_probe, own["hand"][i:i + 1],
                     net.model_config.get("hand_templates"))
            times[name].append(time.perf_counter() - begun)
    for name, seconds in times.items():
        print(f"{name:32s} median {1e3 * statistics.median(seconds):6.2f} ms, mean {1e3 * np.mean(seconds):6.2f} ms")
    for name, counts in decisions.items():
        print(f"probe fit's decisions, {name}: " + ", ".join(f"{k} {v}" for k, v in counts.most_common()))


if __name__ == "__main__":
    main()
