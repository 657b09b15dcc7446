"""What the hand's fit to the depth input (hupbench.fits.hand_fit) does to a checkpoint's hand, on a split: the
hand MPJPE of the network alone and after the fit, after the fit without each of its parts (the bones' turns, i.e.
a rigid hand; the free-space term), and after the fit started from the true joints (what its capsule hand gets
wrong), per grasp, with where the error is (scripts/diagnose_errors.py's centroid / about centroid / rigid), and
the fit's time per frame. The probe's fit runs first, as in eval.

The checkpoint must read depth (data.reader.input_modalities=rgb+depth); whether its config asks for the fits does
not matter here: both are measured. The fit's weights were chosen with ``--split val``; quote the test split once,
with its floor (printed from the manifest).
The fits here take every pixel near their object: a segmenting model's (model.segmentation) own masks are not
used (scripts/fit_speed.py runs its fits with them, without them and with the seg maps).

Usage: python scripts/hand_fit_ablation.py CHECKPOINT DATASET [--split val] [--frames 960] [--batch 32]
       [--depth-sensor dataset]
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import torch

#: the fit's parts taken out, each as the settings it runs with instead (hupbench.fits.HandFitSettings); and the fit
#: started from the true joints instead of the network's (what its capsule hand gets wrong: 0 for a perfect hand)
VARIANTS = {"fit": {}, "fit, rigid hand": {"bone_prior_m": 1e3}, "fit, no free space": {"free_weight": 0.0},
            "fit from the truth": {}}


def main() -> None:
    from dataclasses import replace

    from diagnose_errors import batches, decompose, floor_line, split_labels, split_outputs
    from hupbench.core import keypoints as kp
    from hupbench.fits.hand_fit import fit_hand
    from hupbench.fits.probe_fit import fit_probe

    args, net, reader, prediction = split_outputs(__doc__.splitlines()[0], batch=32, modalities="rgb+depth",
                                                  keep_images=True)
    rows, K = prediction.rows, net.K_input
    outputs = batches(prediction)
    own_probe, own_hand = net.fit_settings
    # the probe's fit as eval runs it: the model's settings and its own probe (the one its hand fit leaves out)
    probe_fitted = [fit_probe(points2d, points3d, images, K, own_probe, net.fit_probe)[:2]
                    for images, points2d, points3d in outputs]
    hands = {"network": np.concatenate([points3d[:, kp.HAND_SLICE] for _, points3d in probe_fitted])}
    labels, _, grasp = split_labels(args, reader, rows)
    starts = np.cumsum([0] + [len(images) for images, _, _ in outputs])
    seconds = {}
    for name, changes in VARIANTS.items():
        settings = replace(own_hand, **changes)
        began, out = time.perf_counter(), []
        for start, (images, _, _), (points2d, points3d) in zip(starts, outputs, probe_fitted):
            if name == "fit from the truth":
                points3d = points3d.copy()
                points3d[:, kp.HAND_SLICE] = labels[start:start + len(images), kp.HAND_SLICE]
            out.append(fit_hand(points2d, points3d, images, K, settings, net.fit_probe,
                                templates=net.model_config.get("hand_templates"))[1][:, kp.HAND_SLICE])
        seconds[name] = time.perf_counter() - began
        hands[name] = np.concatenate(out)
    gt = labels[:, kp.HAND_SLICE]
    print(f"{args.checkpoint} on {args.dataset} {args.split}: {len(rows)} of {len(reader)} frames; hand, mm")
    floor = floor_line(reader, args.split, "hand")
    if floor:
        print(floor)
    grasps = sorted(np.unique(grasp).tolist())
    print(f"{'':20s}{'hand':>8s}{'median':>8s}{'centroid':>10s}{'about c.':>10s}{'rigid':>8s}"
          + "".join(f"{'grasp ' + str(g):>10s}" for g in grasps))
    summary = {}
    for name, pred in hands.items():
        per_frame = np.linalg.norm(pred - gt, axis=-1).mean(axis=1) * 1000.0
        parts = decompose(pred, gt)
        summary[name] = round(float(per_frame.mean()), 2)
        print(f"{name:20s}{per_frame.mean():8.2f}{np.median(per_frame):8.2f}{parts['centroid']:10.2f}"
              f"{parts['about_centroid']:10.2f}{parts['rigid']:8.2f}"
              + "".join(f"{per_frame[grasp == g].mean():10.2f}" for g in grasps))
    print(f"the fit: {seconds['fit'] / len(rows) * 1000:.1f} ms per frame ({torch.get_num_threads()} threads)")
    print(json.dumps({"checkpoint": str(Path(args.checkpoint)), "split": args.split, "frames": len(rows),
                      "hand_mm": summary}))


if __name__ == "__main__":
    main()
