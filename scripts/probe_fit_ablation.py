"""What the probe's fit to the depth input (hupbench.fits.probe_fit) does to a checkpoint's probe, on a split:
the probe corner MPJPE (and under the half turn, eval's symmetric score) of the network alone and after the fit,
per grasp, how each frame's half turn was decided and the error of each kind (beside the network's own on those
frames), the fitted box's rotation from the true box (median, and the share of frames turned more than 150 degrees:
the half turn lost), its centre's distance and its long axis's angle from the true box's (what is left when the
turn about that axis is set aside), per decision the centre's offset along the camera ray (the depth's share) and
the error left with the true centre (the rotation's), and the fit's time per frame.

A segmenting model's fit takes only its own segmentation's probe pixels, as eval runs it (``--no-masks``: every
pixel near the probe). ``--from-truth`` also starts the fit from the true corners: what the depth can hold, apart
from where the fit starts (a diagnosis: a model never has the truth).

The checkpoint must read depth (data.reader.input_modalities=rgb+depth); whether its config asks for the fit does
not matter here: both are measured, with the probe fit's settings its config gives (as eval runs it). Quote it with
the split's floor (printed from the manifest).

Usage: python scripts/probe_fit_ablation.py CHECKPOINT DATASET [--split val] [--frames 960] [--batch 32]
       [--depth-sensor dataset] [--no-masks] [--from-truth]
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import torch


def rotation_deg(pred: np.ndarray, truth: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """(F,) degrees between the probe boxes (``corners``, probe frame) fitted to the predicted and the true corners
    (F, 8, 3)."""
    from hupbench.core.geometry import fit_rigid_pose, matrix_to_axis_angle

    relative = fit_rigid_pose(corners, pred)[:, :3, :3].transpose(0, 2, 1) @ fit_rigid_pose(corners, truth)[:, :3, :3]
    return np.degrees(np.linalg.norm(matrix_to_axis_angle(relative), axis=-1))   # stable near the half turn


def centre_and_axis(pred: np.ndarray, truth: np.ndarray, corners: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(F,) mm between the boxes' centres (the corners' means) and (F,) degrees between their long axes (the probe
    frame's +z, either way: the half turn keeps it) of predicted and true corners (F, 8, 3): what is left when the
    turn about the long axis is set aside."""
    from hupbench.core.geometry import fit_rigid_pose

    centre = np.linalg.norm(pred.mean(1) - truth.mean(1), axis=-1) * 1000.0
    cosine = np.abs((fit_rigid_pose(corners, pred)[:, :3, 2] * fit_rigid_pose(corners, truth)[:, :3, 2]).sum(-1))
    return centre, np.degrees(np.arccos(np.clip(cosine, 0.0, 1.0)))


def centre_along_ray(pred: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """(F,) mm of the centres' offset along the camera's ray to the true centre (the depth's share; the rest of
    :func:`centre_and_axis`'s distance lies across the ray, where the image shows it)."""
    ray = truth.mean(1) / np.linalg.norm(truth.mean(1), axis=-1, keepdims=True)
    return np.abs(((pred.mean(1) - truth.mean(1)) * ray).sum(-1)) * 1000.0


def main() -> None:
    from diagnose_errors import batches, floor_line, split_labels, split_outputs
    from hupbench.core import keypoints as kp
    from hupbench.core.contract import SEGMENT_CLASSES
    from hupbench.fits.known_probe import default_fit_probe
    from hupbench.fits.probe_fit import DECISIONS, fit_probe

    def options(parser):
        parser.add_argument("--no-masks", action="store_true", help="a segmenting model's fit on every pixel")
        parser.add_argument("--from-truth", action="store_true", help="also the fit started from the true corners")

    args, model, reader, prediction = split_outputs(__doc__.splitlines()[0], batch=32, modalities="rgb+depth",
                                                    keep_images=True, options=options)
    n, rows, K, probe = len(reader), prediction.rows, model.K_input, model.fit_probe or default_fit_probe()
    labels, turned, grasp = split_labels(args, reader, rows)
    masks = None if args.no_masks or prediction.segmentation is None else (
        prediction.segmentation == SEGMENT_CLASSES.index("probe"))
    starts = {"fit": None, "fit from the truth": labels} if args.from_truth else {"fit": None}
    net, fitted, decisions, fit_s, start = [], {name: [] for name in starts}, {name: [] for name in starts}, 0.0, 0
    for images, points2d, points3d in batches(prediction):
        stop = start + len(images)
        pixels = None if masks is None else masks[start:stop]
        net.append(points3d[:, kp.CORNER_SLICE])
        for name, truth in starts.items():
            begun = np.array(points3d)
            if truth is not None:
                begun[:, kp.CORNER_SLICE] = truth[start:stop, kp.CORNER_SLICE]
            began = time.perf_counter()
            _, refined, report = fit_probe(points2d, begun, images, K, model.fit_settings[0], probe, pixels)
            if truth is None:
                fit_s += time.perf_counter() - began
            fitted[name].append(refined[:, kp.CORNER_SLICE])
            decisions[name].append(report.decision)
        start = stop
    gt = labels[:, kp.CORNER_SLICE]

    def error(pred, truth):
        return np.linalg.norm(pred - truth, axis=-1).mean(axis=1) * 1000.0      # (F,) mm per frame

    predictions = {"network": np.concatenate(net), **{name: np.concatenate(v) for name, v in fitted.items()}}
    print(f"{args.checkpoint} on {args.dataset} {args.split}: {len(rows)} of {n} frames, depth "
          f"{args.depth_sensor}, the fit on {'no mask' if masks is None else 'the model segmentation'}'s pixels; "
          f"probe corner MPJPE, mm")
    floor = floor_line(reader, args.split, "probe")
    if floor:
        print(floor)
    grasps = sorted(np.unique(grasp).tolist())
    print(f"{'':20s}{'probe':>9s}{'median':>9s}{'half turn':>11s}{'rot. deg':>10s}{'>150 deg':>10s}{'centre':>8s}"
          f"{'axis deg':>10s}"
          + "".join(f"{'grasp ' + str(g):>12s}" for g in grasps))
    out = {}
    for name, pred in predictions.items():
        plain, half = error(pred, gt), np.minimum(error(pred, gt), error(pred, turned))
        angle = rotation_deg(pred, gt, probe.corners)
        centre, axis = centre_and_axis(pred, gt, probe.corners)
        out[name] = (plain, half)
        print(f"{name:20s}{plain.mean():9.2f}{np.median(plain):9.2f}{half.mean():11.2f}{np.median(angle):10.1f}"
              f"{(angle > 150).mean():10.1%}{centre.mean():8.1f}{axis.mean():10.1f}"
              + "".join(f"{plain[grasp == g].mean():12.2f}" for g in grasps))
        if name == "network":
            continue
        chosen_by = np.concatenate(decisions[name])
        along = centre_along_ray(pred, gt)
        # the same corners moved to the true centre: what the rotation alone leaves
        centred = error(pred - pred.mean(1, keepdims=True) + gt.mean(1, keepdims=True), gt)
        for index, kind in enumerate(DECISIONS):
            chosen = chosen_by == index
            if chosen.any():
                print(f"  half turn by {kind:9s}: {chosen.mean():6.1%} of frames, probe {plain[chosen].mean():6.2f} mm "
                      f"(the network's there {out['network'][0][chosen].mean():6.2f}), turned > 150 deg "
                      f"{(angle[chosen] > 150).mean():6.1%}, centre {centre[chosen].mean():5.1f} mm, long axis "
                      f"{axis[chosen].mean():5.1f} deg; centre along the ray {along[chosen].mean():5.1f} mm, at the "
                      f"true centre {centred[chosen].mean():6.2f} mm, half-turn symmetric "
                      f"{half[chosen].mean():6.2f} mm")
    print(f"the fit: {fit_s / len(rows) * 1000:.1f} ms per frame ({torch.get_num_threads()} threads)")
    print(json.dumps({"checkpoint": str(Path(args.checkpoint)), "frames": len(rows),
                      "probe_mm": {k: round(float(v[0].mean()), 2) for k, v in out.items()},
                      "probe_half_turn_mm": {k: round(float(v[1].mean()), 2) for k, v in out.items()}}))


if __name__ == "__main__":
    main()
