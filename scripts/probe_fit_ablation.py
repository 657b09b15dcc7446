"""What the probe's fit to the depth input (hupbench.fits.probe_fit) does to a checkpoint's probe, on a split:
the probe corner MPJPE (and under the half turn, eval's symmetric score) of the network alone and after the fit,
per grasp, how each frame's half turn was decided and the error of each kind, and the fit's time per frame.

The checkpoint must read depth (data.reader.input_modalities=rgb+depth); whether its config asks for the fit does
not matter here: both are measured. Quote it with the split's floor (printed from the manifest).
The fits here take every pixel near their object: a segmenting model's (model.segmentation) own masks are not
used (scripts/fit_speed.py runs its fits with them, without them and with the seg maps).

Usage: python scripts/probe_fit_ablation.py CHECKPOINT DATASET [--split test] [--frames 960] [--batch 32]
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import torch


def main() -> None:
    from diagnose_errors import batches, floor_line, split_labels, split_outputs
    from hupbench.core import keypoints as kp
    from hupbench.fits.probe_fit import DECISIONS, fit_probe

    args, model, reader, prediction = split_outputs(__doc__.splitlines()[0], batch=32, modalities="rgb+depth",
                                                    keep_images=True)
    n, rows, K = len(reader), prediction.rows, model.K_input
    net, fitted, decisions, fit_s = [], [], [], 0.0
    for images, points2d, points3d in batches(prediction):
        began = time.perf_counter()
        _, refined, report = fit_probe(points2d, points3d, images, K)
        fit_s += time.perf_counter() - began
        net.append(points3d[:, kp.CORNER_SLICE])
        fitted.append(refined[:, kp.CORNER_SLICE])
        decisions.append(report.decision)
    net, fitted, decisions = np.concatenate(net), np.concatenate(fitted), np.concatenate(decisions)
    labels, turned, grasp = split_labels(args, reader, rows)
    gt = labels[:, kp.CORNER_SLICE]

    def error(pred, truth):
        return np.linalg.norm(pred - truth, axis=-1).mean(axis=1) * 1000.0      # (F,) mm per frame

    rows_out = {}
    for name, pred in (("network", net), ("fit", fitted)):
        plain, half = error(pred, gt), np.minimum(error(pred, gt), error(pred, turned))
        rows_out[name] = (plain, half)
    print(f"{args.checkpoint} on {args.dataset} {args.split}: {len(rows)} of {n} frames; probe corner MPJPE, mm")
    floor = floor_line(reader, args.split, "probe")
    if floor:
        print(floor)
    grasps = sorted(np.unique(grasp).tolist())
    print(f"{'':10s}{'probe':>9s}{'median':>9s}{'half turn':>11s}" + "".join(f"{'grasp ' + str(g):>12s}" for g in grasps))
    for name, (plain, half) in rows_out.items():
        print(f"{name:10s}{plain.mean():9.2f}{np.median(plain):9.2f}{half.mean():11.2f}"
              + "".join(f"{plain[grasp == g].mean():12.2f}" for g in grasps))
    plain = rows_out["fit"][0]
    for index, name in enumerate(DECISIONS):
        chosen = decisions == index
        if chosen.any():
            print(f"  half turn by {name:9s}: {chosen.mean():6.1%} of frames, probe {plain[chosen].mean():6.2f} mm")
    print(f"the fit: {fit_s / len(rows) * 1000:.1f} ms per frame ({torch.get_num_threads()} threads)")
    print(json.dumps({"checkpoint": str(Path(args.checkpoint)), "frames": len(rows),
                      "probe_mm": {k: round(float(v[0].mean()), 2) for k, v in rows_out.items()},
                      "probe_half_turn_mm": {k: round(float(v[1].mean()), 2) for k, v in rows_out.items()}}))


if __name__ == "__main__":
    main()
