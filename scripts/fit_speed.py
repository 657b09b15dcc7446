"""What the fits' settings cost and give: a model's MPJPE (all, hand, probe) and each fit's time per frame at batch 1,
with the fits' default settings and with variants, on the same network output of evenly spaced frames of a split.
Tunes on val by default.

``--variant probe:NAME=VALUE[,...]`` or ``hand:NAME=VALUE[,...]`` (repeatable, both in one variant joined by ``;``)
changes fields of :class:`hupbench.fits.ProbeFitSettings` / :class:`hupbench.fits.HandFitSettings`, e.g.
``--variant "probe:hypotheses=12,coarse_points=128;hand:iterations=6"``.

A model with a segmentation head runs each setting with its own segmentation (as eval does) and without any; others
without. ``--true-masks`` also runs each setting with every fit reading only its own object's pixels of the
dataset's seg maps (the probe's, the hand's): what a perfect segmentation would give the fits, an upper bound for
diagnosis, never a model's number (a model reads no label).

The hand's fit starts from the model's training hands where its config has them (``hand:templates=false``: the
network's joints). ``--training-hands`` gives a checkpoint trained before they were recorded the hands its training
would have recorded: those of DATASET's train split (:func:`hupbench.fits.hand_fit.training_hands`; the model's own
training data, labels a model file may carry; a diagnosis of that checkpoint, not its row).

Usage: python scripts/fit_speed.py CHECKPOINT DATASET [--split val] [--frames 240] [--depth-sensor dataset]
       [--variant SPEC ...] [--true-masks] [--training-hands]
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

import numpy as np


def _variant(text: str) -> dict[str, dict]:
    """``"probe:hypotheses=12;hand:iterations=6"`` -> {"probe": {"hypotheses": 12}, "hand": {"iterations": 6}}, each
    value typed as its field's default (:func:`fit_divergence.settings_changes`)."""
    from fit_divergence import settings_changes

    from hupbench.fits import HandFitSettings, ProbeFitSettings

    kinds = {"probe": ProbeFitSettings, "hand": HandFitSettings}
    out: dict[str, dict] = {"probe": {}, "hand": {}}
    for part in text.split(";"):
        kind, _, items = part.partition(":")
        if kind not in kinds or not items:
            raise argparse.ArgumentTypeError(f"{part!r}: expected probe:NAME=VALUE[,...] or hand:NAME=VALUE[,...]")
        out[kind] |= settings_changes(items, kinds[kind])
    return out


def _shown(value) -> str:
    """A variant's value as its command line writes it (true / false, or a number)."""
    return str(value).lower() if isinstance(value, bool) else format(value, "g")


def main() -> None:
    from hupbench.core import keypoints as kp
    from hupbench.core.contract import SEGMENT_CLASSES, read_annotations
    from hupbench.data.reader import DEPTH_SENSORS
    from hupbench.evaluation.prediction import EvalModel, evenly_spaced, predict_split, split_reader
    from hupbench.fits import fits
    from hupbench.fits.hand_fit import fit_hand, training_hands
    from hupbench.fits.known_probe import default_fit_probe
    from hupbench.fits.probe_fit import fit_probe

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("model", help="a hupbench checkpoint (.pt) whose model runs fits after the network")
    parser.add_argument("dataset", help="a finished dataset folder")
    parser.add_argument("--split", default="val", choices=("train", "val", "test"))
    parser.add_argument("--frames", type=int, default=240, help="evenly spaced frames of the split (0: all)")
    parser.add_argument("--variant", type=_variant, action="append", default=[], metavar="SPEC",
                        help="also run the fits with these settings changed (repeatable)")
    parser.add_argument("--depth-sensor", default="dataset", choices=DEPTH_SENSORS,
                        help="the depth the model reads (hupbench eval's --depth-sensor)")
    parser.add_argument("--true-masks", action="store_true",
                        help="also run each setting on the dataset's seg maps (module docstring)")
    parser.add_argument("--training-hands", action="store_true",
                        help="a checkpoint without training hands: take them from DATASET's train split")
    args = parser.parse_args()
    net = EvalModel(Path(args.model))
    asked = fits(net.model_config)
    templates = net.model_config.get("hand_templates")   # the hand fit's starts, where the model has them
    if not asked:
        parser.error(f"{args.model} runs no fit after its network (model.probe_fit / model.hand_fit)")
    reader = split_reader(Path(args.dataset), args.split, net, args.depth_sensor)
    if args.training_hands:
        if templates is not None:
            parser.error(f"{args.model} has its own training hands: --training-hands is for a checkpoint without")
        train = read_annotations(Path(args.dataset), "train", ("keypoints_3d_cam", "grasp_id"), reader.manifest)
        templates = training_hands(train["keypoints_3d_cam"], train["grasp_id"])
    rows = evenly_spaced(len(reader), args.frames)
    p = predict_split(net, reader, 32, rows, with_fits=False, keep_images=True)
    images = np.concatenate(p.images)
    # the masks each run gives the fits: the model's own segmentation (what eval does) where it has a head, and then
    # none (its ablation); the dataset's seg maps with --true-masks
    masks = {} if p.segmentation is None else {"segmentation": p.segmentation}
    masks["no masks"] = None
    if args.true_masks:
        masks["true masks"] = np.stack([reader.seg_frame(int(r)) for r in rows])
    default_fit_probe()   # built once per process (seconds): not a fit's time

    def errors(points3d: np.ndarray) -> str:
        err = 1000.0 * np.linalg.norm(points3d - p.labels3d, axis=-1)
        return (f"all {err.mean():6.2f} hand {err[:, kp.HAND_SLICE].mean():6.2f} "
                f"probe {err[:, kp.CORNER_SLICE].mean():6.2f}")

    print(f"{args.model} on {len(rows)} {args.split} frames, depth {reader.depth_source}; mm, ms per frame at batch 1")
    print(f"{'network alone':48s} {errors(p.points3d)}")
    if "segmentation" in masks and "true masks" in masks:   # the head's agreement with the seg maps, per class
        got, true = masks["segmentation"], masks["true masks"]
        print("segmentation IoU " + ", ".join(
            f"{name} {np.sum((got == c) & (true == c)) / max(np.sum((got == c) | (true == c)), 1):.3f}"
            for c, name in enumerate(SEGMENT_CLASSES)))
    settings = [{"probe": {}, "hand": {}}] + args.variant
    for mask_name, (changes, mask) in ((m, (c, masks[m])) for m in masks for c in settings):
        probe = dataclasses.replace(net.fit_settings[0], **changes["probe"])
        hand = dataclasses.replace(net.fit_settings[1], **changes["hand"])
        out3d, spent = np.empty_like(p.points3d), {"probe": 0.0, "hand": 0.0}
        for i in range(len(rows)):
            points2d, points3d, frame = p.points2d[i:i + 1], p.points3d[i:i + 1], images[i:i + 1]
            own = {part: None if mask is None else mask[i:i + 1] == SEGMENT_CLASSES.index(part)
                   for part in ("probe", "hand")}
            if "probe" in asked:
                start = time.perf_counter()
                points2d, points3d, _ = fit_probe(points2d, points3d, frame, net.K_input, probe, net.fit_probe,
                                                  pixels=own["probe"])
                spent["probe"] += time.perf_counter() - start
            if "hand" in asked:
                start = time.perf_counter()
                points2d, points3d, _ = fit_hand(points2d, points3d, frame, net.K_input, hand, net.fit_probe,
                                                 pixels=own["hand"], templates=templates)
                spent["hand"] += time.perf_counter() - start
            out3d[i] = points3d[0]
        name = "; ".join(f"{kind} {', '.join(f'{k}={_shown(v)}' for k, v in c.items())}" for kind, c in changes.items()
                         if c) or "the model's settings"
        name += f" ({mask_name})"
        times = ", ".join(f"{kind} fit {1000.0 * spent[kind] / len(rows):5.1f}" for kind in asked)
        print(f"{name:48s} {errors(out3d)}; {times}", flush=True)

if __name__ == "__main__":
    main()
