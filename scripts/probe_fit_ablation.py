"""What the probe's fit to the depth input (hupbench.inference.probe_fit) does to a checkpoint's probe, on a split:
the probe corner MPJPE (and under the half turn, eval's symmetric score) of the network alone and after the fit,
per grasp, how each frame's half turn was decided and the error of each kind, and the fit's time per frame.

The checkpoint must read depth (data.reader.input_modalities=rgb+depth); whether its config asks for the fit does
not matter here: both are measured. Quote it with the split's floor (printed from the manifest).

Usage: python scripts/probe_fit_ablation.py CHECKPOINT DATASET [--split test] [--frames 960] [--batch 32]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch


def main() -> None:
    from datagen import keypoints as kp
    from datagen.dataset.contract import read_annotations
    from hupbench.checkpoint import load_model
    from hupbench.data import HUPDataset, ReaderConfig
    from hupbench.evaluation.evaluate import probe_symmetry_group
    from hupbench.inference.export import contract_model
    from hupbench.inference.probe_fit import DECISIONS, fit_probe

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoint")
    parser.add_argument("dataset")
    parser.add_argument("--split", default="test")
    parser.add_argument("--frames", type=int, default=960, help="evenly spaced frames of the split (0: all)")
    parser.add_argument("--batch", type=int, default=32)
    args = parser.parse_args()

    model, payload = load_model(args.checkpoint)
    module = contract_model(model, payload, args.checkpoint)
    if not module.reads_depth:
        raise SystemExit(f"{args.checkpoint} reads no depth: the fit needs data.reader.input_modalities=rgb+depth")
    reader = HUPDataset(args.dataset, args.split, ReaderConfig(input_size=module.input_size,
                                                                input_modalities="rgb+depth"))
    n = len(reader)
    rows = np.arange(n) if not args.frames or args.frames >= n else np.linspace(0, n - 1, args.frames).round().astype(int)
    K = np.asarray(payload["K_input"], dtype=np.float64)
    net, fitted, decisions, fit_s = [], [], [], 0.0
    with torch.inference_mode():
        for start in range(0, len(rows), args.batch):
            images = torch.stack([reader[int(i)]["image"] for i in rows[start:start + args.batch]])
            points2d, points3d = module(images)
            points2d, points3d = points2d.double().numpy(), points3d.double().numpy()
            began = time.perf_counter()
            _, refined, report = fit_probe(points2d, points3d, images.numpy(), K)
            fit_s += time.perf_counter() - began
            net.append(points3d[:, kp.CORNER_SLICE])
            fitted.append(refined[:, kp.CORNER_SLICE])
            decisions.append(report.decision)
    net, fitted, decisions = np.concatenate(net), np.concatenate(fitted), np.concatenate(decisions)
    ann = read_annotations(args.dataset, args.split, ("keypoints_3d_cam", "T_cam_world", "grasp_id"), reader.manifest)
    gt = ann["keypoints_3d_cam"][rows][:, kp.CORNER_SLICE].astype(np.float64)
    turned = gt[:, list(probe_symmetry_group(ann["keypoints_3d_cam"], ann["T_cam_world"])[1])]
    grasp = ann["grasp_id"][rows]

    def error(pred, truth):
        return np.linalg.norm(pred - truth, axis=-1).mean(axis=1) * 1000.0      # (F,) mm per frame

    rows_out = {}
    for name, pred in (("network", net), ("fit", fitted)):
        plain, half = error(pred, gt), np.minimum(error(pred, gt), error(pred, turned))
        rows_out[name] = (plain, half)
    print(f"{args.checkpoint} on {args.dataset} {args.split}: {len(rows)} of {n} frames; probe corner MPJPE, mm")
    floors = reader.manifest.get("split_floors", {}).get("splits", {}).get(args.split)
    if floors:
        print("floor (nearest training grasp): probe {:.2f}; per grasp {}".format(
            floors["floor_mm"]["probe"],
            ", ".join(f"{g} {v['floor_mm']['probe']:.2f}" for g, v in sorted(floors["per_grasp"].items()))))
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
