"""Where a checkpoint's 3D error comes from, on a split: position against orientation, depth against the image
plane, hand against probe. The figures issue 23's models are judged by, beside the split's floor.

For the probe's 8 corners and the hand's 21 joints of each frame:
    centroid     error of the predicted centroid (where the set is): mm, and its z share (along the optical axis)
    about centroid   MPJPE after moving the prediction's centroid onto the truth's (how the set is turned or shaped)
    rigid        MPJPE after the best rotation and translation (no scale): what no rigid pose could fix (shape)
    z / xy       mean |error| along the optical axis and in the image plane, per keypoint, mm
and the same for the probe under its half turn (the closer labelling per frame, as eval's symmetric score).

Usage: python scripts/diagnose_errors.py CHECKPOINT DATASET [--split test] [--frames 960] [--batch 64]
"""

from __future__ import annotations

import argparse

import numpy as np
import torch


def rigid_align(pred: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """(N, K, 3) predictions moved by the best rotation and translation onto gt (Kabsch, no scale)."""
    mu_p, mu_g = pred.mean(axis=1, keepdims=True), gt.mean(axis=1, keepdims=True)
    x, y = pred - mu_p, gt - mu_g
    u, _, vt = np.linalg.svd(np.einsum("nki,nkj->nij", y, x))
    d = np.where(np.linalg.det(u) * np.linalg.det(vt) < 0.0, -1.0, 1.0)
    u[:, :, 2] *= d[:, None]
    return np.einsum("nij,nkj->nki", u @ vt, x) + mu_g


def decompose(pred: np.ndarray, gt: np.ndarray) -> dict[str, float]:
    """The figures of the module docstring for (N, K, 3) metres, in mm."""
    err = lambda a, b: float(np.linalg.norm(a - b, axis=-1).mean() * 1000.0)  # noqa: E731
    centroid = np.linalg.norm(pred.mean(1) - gt.mean(1), axis=-1) * 1000.0
    centred = pred - pred.mean(1, keepdims=True) + gt.mean(1, keepdims=True)
    return {"mpjpe": err(pred, gt), "centroid": float(centroid.mean()),
            "centroid_z": float(np.abs(pred.mean(1)[:, 2] - gt.mean(1)[:, 2]).mean() * 1000.0),
            "about_centroid": err(centred, gt), "rigid": err(rigid_align(pred, gt), gt),
            "z": float(np.abs(pred[..., 2] - gt[..., 2]).mean() * 1000.0),
            "xy": float(np.linalg.norm(pred[..., :2] - gt[..., :2], axis=-1).mean() * 1000.0)}


def main() -> None:
    from datagen import keypoints as kp
    from hupbench.checkpoint import load_model
    from hupbench.data import HUPDataset, ReaderConfig
    from hupbench.evaluation.evaluate import probe_symmetry_group
    from hupbench.inference.export import contract_model
    from datagen.dataset.contract import read_annotations

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoint")
    parser.add_argument("dataset")
    parser.add_argument("--split", default="test")
    parser.add_argument("--frames", type=int, default=960, help="evenly spaced frames of the split (0: all)")
    parser.add_argument("--batch", type=int, default=64)
    args = parser.parse_args()

    model, payload = load_model(args.checkpoint)
    module = contract_model(model, payload, args.checkpoint)
    modalities = "rgb+depth" if module.reads_depth else "rgb"
    reader = HUPDataset(args.dataset, args.split, ReaderConfig(input_size=module.input_size,
                                                                input_modalities=modalities))
    n = len(reader)
    rows = np.arange(n) if not args.frames or args.frames >= n else np.linspace(0, n - 1, args.frames).round().astype(int)
    preds = []
    with torch.inference_mode():
        for start in range(0, len(rows), args.batch):
            images = torch.stack([reader[int(i)]["image"] for i in rows[start:start + args.batch]])
            preds.append(module(images)[1].double().numpy())
    pred = np.concatenate(preds)
    gt = reader.labels["keypoints_3d"][rows].double().numpy()
    ann = read_annotations(args.dataset, args.split, ("keypoints_3d_cam", "T_cam_world"), reader.manifest)
    group = probe_symmetry_group(ann["keypoints_3d_cam"], ann["T_cam_world"])
    hand, probe = slice(0, kp.NUM_HAND), slice(kp.NUM_HAND, kp.NUM_KEYPOINTS)
    turned = gt[:, probe][:, list(group[1])]
    closer = (np.linalg.norm(pred[:, probe] - turned, axis=-1).mean(1)
              < np.linalg.norm(pred[:, probe] - gt[:, probe], axis=-1).mean(1))
    gt_sym = np.where(closer[:, None, None], turned, gt[:, probe])
    print(f"{args.checkpoint} on {args.dataset} {args.split}: {len(rows)} of {n} frames, input {module.input_size} px "
          f"{modalities}; mm")
    print(f"{'':18s}" + "".join(f"{k:>15s}" for k in ("mpjpe", "centroid", "centroid_z", "about_centroid", "rigid",
                                                        "z", "xy")))
    for name, (p, g) in {"hand": (pred[:, hand], gt[:, hand]), "probe": (pred[:, probe], gt[:, probe]),
                         "probe, half turn": (pred[:, probe], gt_sym)}.items():
        print(f"{name:18s}" + "".join(f"{v:15.2f}" for v in decompose(p, g).values()))
    print(f"probe half-turned labels closer on {closer.mean():.0%} of frames")


if __name__ == "__main__":
    main()
