"""Where the fits after the network help or hurt: per-frame hand and probe MPJPE of a model on evenly spaced frames of
a split, the network alone against the network with its fits (the model's own, e.g. the probe and the hand fitted to
the depth), and how many frames each leaves beyond a bound. Diagnoses on val by default.

``--hand-variant NAME=VALUE[,NAME=VALUE]`` (repeatable) also runs the fits with those fields of
:class:`hupbench.fits.HandFitSettings` changed, on the same network output, e.g. ``--hand-variant free_weight=0``
(the fit without its free-space term): which term of the fit makes it diverge.

Usage: python scripts/fit_divergence.py CHECKPOINT DATASET [--split val] [--frames 240] [--bound-mm 100]
                                        [--hand-variant free_weight=0 ...]
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import numpy as np


def settings_changes(text: str, settings_type) -> dict:
    """``"free_weight=0,iterations=5,templates=false"`` -> {"free_weight": 0.0, "iterations": 5, "templates": False}:
    numeric and true / false fields of the frozen settings dataclass ``settings_type``, each typed as its default
    (argparse's error otherwise)."""
    fields = {f.name: type(getattr(settings_type(), f.name)) for f in dataclasses.fields(settings_type)}
    changes = {}
    for item in text.split(","):
        name, _, value = item.partition("=")
        if name not in fields or fields[name] not in (int, float, bool) or not value:
            known = ", ".join(n for n, t in fields.items() if t in (int, float, bool))
            raise argparse.ArgumentTypeError(f"{item!r}: expected NAME=NUMBER (or true / false), NAME one of "
                                             f"{settings_type.__name__}' {known}")
        if fields[name] is bool:
            if value not in ("true", "false"):
                raise argparse.ArgumentTypeError(f"{item!r}: {value!r} is not true or false")
            changes[name] = value == "true"
            continue
        try:
            changes[name] = fields[name](value)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{item!r}: {value!r} is not a {fields[name].__name__}") from None
    return changes


def _variant(text: str) -> dict:
    """A ``--hand-variant``: :func:`settings_changes` of :class:`hupbench.fits.HandFitSettings`."""
    from hupbench.fits import HandFitSettings

    return settings_changes(text, HandFitSettings)


def main() -> None:
    from hupbench.core import keypoints as kp
    from hupbench.evaluation.prediction import EvalModel, evenly_spaced, predict_split, split_reader
    from hupbench.fits import after_network

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("model", help="a hupbench checkpoint (.pt) whose model runs fits after the network")
    parser.add_argument("dataset", help="a finished dataset folder")
    parser.add_argument("--split", default="val", choices=("train", "val", "test"))
    parser.add_argument("--frames", type=int, default=240, help="evenly spaced frames of the split (0: all)")
    parser.add_argument("--bound-mm", type=float, default=100.0, help="a frame's hand MPJPE beyond this counts as lost")
    parser.add_argument("--hand-variant", type=_variant, action="append", default=[], metavar="NAME=VALUE[,...]",
                        help="also run the fits with these HandFitSettings fields changed (repeatable)")
    args = parser.parse_args()
    net = EvalModel(Path(args.model))
    reader = split_reader(Path(args.dataset), args.split, net)
    rows = evenly_spaced(len(reader), args.frames)
    p = predict_split(net, reader, 32, rows, with_fits=False, keep_images=True)
    images = np.concatenate(p.images)
    outputs = {"network alone ": p.points3d}
    for changes in [{}] + args.hand_variant:
        name = "network + fits" + "".join(f", hand fit {k}={v:g}" for k, v in changes.items())
        settings = dataclasses.replace(net.fit_settings[1], **changes)
        outputs[name] = after_network(net.model_config, p.points2d, p.points3d, images, net.K_input, hand=settings,
                                      fitted=net.fit_probe, segmentation=p.segmentation)[1]
    hand = {}
    for name, points3d in outputs.items():
        err_mm = 1000.0 * np.linalg.norm(points3d - p.labels3d, axis=-1)
        hand[name], probe = err_mm[:, kp.HAND_SLICE].mean(axis=1), err_mm[:, kp.CORNER_SLICE].mean(axis=1)
        depth_mm = 1000.0 * (points3d[:, kp.HAND_SLICE, 2] - p.labels3d[:, kp.HAND_SLICE, 2]).mean(axis=1)
        lost = hand[name] > args.bound_mm
        print(f"{name}: hand MPJPE mean {hand[name].mean():.1f} mm, median {np.median(hand[name]):.1f}, 90th "
              f"percentile {np.percentile(hand[name], 90):.1f}, max {hand[name].max():.1f}; probe mean "
              f"{probe.mean():.1f}, median {np.median(probe):.1f}; hand beyond {args.bound_mm:g} mm on {int(lost.sum())} of {len(rows)} "
              f"{args.split} frames" + (f", there {depth_mm[lost].mean():+.0f} mm deeper than the truth on average"
                                        if lost.any() else ""), flush=True)
    change = hand["network + fits"] - hand["network alone "]
    print(f"the fits make the hand worse on {int((change > 0).sum())} of {len(rows)} frames, better on "
          f"{int((change < 0).sum())}; median change {np.median(change):+.1f} mm")


if __name__ == "__main__":
    main()
