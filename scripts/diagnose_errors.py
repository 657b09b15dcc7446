"""Where a checkpoint's 3D error comes from, on a split: position against orientation, depth against the image
plane, hand against probe, beside the split's floor.

For the probe's 8 corners and the hand's 21 joints of each frame:
    centroid     error of the predicted centroid (where the set is): mm, and its z share (along the optical axis)
    about centroid   MPJPE after moving the prediction's centroid onto the truth's (how the set is turned or shaped)
    rigid        MPJPE after the best rotation and translation (no scale): what no rigid pose could fix (shape)
    z / xy       mean |error| along the optical axis and in the image plane, per keypoint, mm
and the same for the probe under its half turn (the closer labelling per frame, as eval's symmetric score);
the wrist's own error and the hand MPJPE relative to the wrist and to the middle MCP (keypoint 9), and the
split's nearest-training-grasp floor (hand, probe) from its manifest. It measures the network alone: the fits
after it (hupbench.fits) are measured by scripts/probe_fit_ablation.py and scripts/hand_fit_ablation.py.
Per test grasp, the probe's turn: the rotation between the box fitted to the predicted corners and the true
box (median angle, the share of frames turned 60-150 degrees, and how much of the turn is about the probe's
long axis: the mean |cosine| between the rotation's axis and it), beside the centroid's error.

Usage: python scripts/diagnose_errors.py CHECKPOINT DATASET [--split val] [--frames 960] [--batch 64]
       [--depth-sensor dataset]
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path

import numpy as np


def rigid_align(pred: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """(N, K, 3) predictions moved by the best rotation and translation onto gt (Kabsch, no scale)."""
    from hupbench.core.geometry import fit_rigid_pose

    T = fit_rigid_pose(pred, gt)                                                   # (N, 4, 4) pred -> gt
    return np.einsum("nij,nkj->nki", T[:, :3, :3], pred) + T[:, None, :3, 3]


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


def split_outputs(description: str, batch: int, modalities: str | None = None, keep_images: bool = False,
                  options: Callable[[argparse.ArgumentParser], None] | None = None):
    """The command line CHECKPOINT DATASET [--split val] [--frames] [--batch] [--depth-sensor] of these scripts,
    parsed, and the checkpoint's network (no fits) run on evenly spaced frames of the split by eval's
    :func:`hupbench.evaluation.prediction.predict_split`: (args, net, reader, prediction). ``modalities``: the input
    the script needs (an error naming it when the checkpoint reads another); None: what the checkpoint reads;
    ``keep_images``: keep the model images (and a segmenting model's segmentation, for fits run afterwards);
    ``options``: adds a script's own options to the parser. They diagnose on val unless told ``--split test``."""
    from hupbench.data.reader import DEPTH_SENSORS
    from hupbench.evaluation.prediction import EvalModel, evenly_spaced, predict_split, split_reader

    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("checkpoint")
    parser.add_argument("dataset")
    parser.add_argument("--split", default="val", choices=("train", "val", "test"))
    parser.add_argument("--frames", type=int, default=960, help="evenly spaced frames of the split (0: all)")
    parser.add_argument("--batch", type=int, default=batch)
    parser.add_argument("--depth-sensor", default="dataset", choices=DEPTH_SENSORS,
                        help="the depth a depth-reading model reads (data.reader.depth_sensor)")
    if options is not None:
        options(parser)
    args = parser.parse_args()
    net = EvalModel(Path(args.checkpoint))
    if modalities is not None and net.input_modalities != modalities:
        raise SystemExit(f"{args.checkpoint} reads {net.input_modalities}; this script needs {modalities}")
    reader = split_reader(Path(args.dataset), args.split, net, args.depth_sensor)
    rows = evenly_spaced(len(reader), args.frames)
    return args, net, reader, predict_split(net, reader, args.batch, rows, with_fits=False, keep_images=keep_images)


def batches(prediction) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """(images (B, C, S, S), points2d (B, 29, 2), points3d (B, 29, 3)) of each batch of a split's prediction."""
    starts = np.cumsum([0] + [len(images) for images in prediction.images])
    return [(images, prediction.points2d[a:b], prediction.points3d[a:b])
            for images, a, b in zip(prediction.images, starts[:-1], starts[1:])]


def floor_line(reader, split: str, part: str) -> str | None:
    """The split's nearest-training-grasp floor of ``part`` (hand, probe or all) from its manifest, overall and per
    grasp, as one line; None for a dataset without floors."""
    floors = reader.manifest.get("split_floors", {}).get("splits", {}).get(split)
    if not floors:
        return None
    per_grasp = ", ".join(f"{g} {v['floor_mm'][part]:.2f}" for g, v in sorted(floors["per_grasp"].items()))
    return f"floor (nearest training grasp): {part} {floors['floor_mm'][part]:.2f}; per grasp {per_grasp}"


def split_labels(args, reader, rows) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(keypoints (F, 29, 3) metres, the probe corners half-turned (F, 8, 3), grasp ids (F,)) of the frames."""
    from hupbench.core import keypoints as kp
    from hupbench.core.contract import read_annotations
    from hupbench.core.probe_symmetry import probe_symmetry_group

    ann = read_annotations(args.dataset, args.split, ("keypoints_3d_cam", "T_cam_world", "grasp_id"), reader.manifest)
    gt = ann["keypoints_3d_cam"][rows].astype(np.float64)
    turned = gt[:, kp.CORNER_SLICE][:, list(probe_symmetry_group(ann["keypoints_3d_cam"], ann["T_cam_world"])[1])]
    return gt, turned, ann["grasp_id"][rows]


def main() -> None:
    from hupbench import metrics
    from hupbench.core.geometry import fit_rigid_pose
    from hupbench.core import keypoints as kp

    args, net, reader, prediction = split_outputs(__doc__.splitlines()[0], batch=64)
    n, modalities, rows = len(reader), net.input_modalities, prediction.rows
    pred = prediction.points3d
    gt, turned, grasp = split_labels(args, reader, rows)
    hand, probe = slice(0, kp.NUM_HAND), slice(kp.NUM_HAND, kp.NUM_KEYPOINTS)
    closer = (np.linalg.norm(pred[:, probe] - turned, axis=-1).mean(1)
              < np.linalg.norm(pred[:, probe] - gt[:, probe], axis=-1).mean(1))
    gt_sym = np.where(closer[:, None, None], turned, gt[:, probe])
    print(f"{args.checkpoint} on {args.dataset} {args.split}: {len(rows)} of {n} frames, input {net.input_size} px "
          f"{modalities}; mm")
    print(f"{'':18s}" + "".join(f"{k:>15s}" for k in ("mpjpe", "centroid", "centroid_z", "about_centroid", "rigid",
                                                        "z", "xy")))
    for name, (p, g) in {"hand": (pred[:, hand], gt[:, hand]), "probe": (pred[:, probe], gt[:, probe]),
                         "probe, half turn": (pred[:, probe], gt_sym)}.items():
        print(f"{name:18s}" + "".join(f"{v:15.2f}" for v in decompose(p, g).values()))
    print(f"probe half-turned labels closer on {closer.mean():.0%} of frames")
    for part in ("hand", "probe"):
        floor = floor_line(reader, args.split, part)
        if floor:
            print(floor)
    wrist = float(metrics.keypoint_errors_mm(pred, gt)[:, metrics.ROOT_INDEX].mean())
    print(f"hand: wrist (keypoint 0) {wrist:.2f} mm absolute; hand MPJPE relative to the wrist "
          f"{metrics.root_relative_mpjpe_mm(pred, gt):.2f}, to the middle MCP (keypoint 9) "
          f"{metrics.root_relative_mpjpe_mm(pred, gt, root=metrics.MIDDLE_MCP_INDEX):.2f}")
    R = fit_rigid_pose(gt[:, probe], pred[:, probe])[:, :3, :3]
    angle = np.degrees(np.arccos(np.clip((np.trace(R, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)))
    axis = np.stack([R[:, 2, 1] - R[:, 1, 2], R[:, 0, 2] - R[:, 2, 0], R[:, 1, 0] - R[:, 0, 1]], axis=1)
    axis /= np.maximum(np.linalg.norm(axis, axis=1, keepdims=True), 1e-12)
    centred = gt[:, probe] - gt[:, probe].mean(1, keepdims=True)
    long_axis = np.linalg.svd(centred)[2][:, 0]                                   # (F, 3) the box's longest axis
    about_long = np.abs((axis * long_axis).sum(1))
    centroid = np.linalg.norm(pred[:, probe].mean(1) - gt[:, probe].mean(1), axis=-1) * 1000.0
    for g in sorted(np.unique(grasp).tolist()):
        s = grasp == g
        print(f"grasp {g}: probe turned {np.median(angle[s]):.0f} deg (median), 60-150 deg on "
              f"{((angle[s] >= 60) & (angle[s] <= 150)).mean():.0%} of frames, about the long axis "
              f"{about_long[s].mean():.2f} (mean |cos|); centroid {centroid[s].mean():.2f} mm")


if __name__ == "__main__":
    main()
