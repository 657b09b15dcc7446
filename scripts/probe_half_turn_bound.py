"""What no model can beat on a split's probe without reading its orientation marker: the share of frames whose image
shows the marker, and the probe corner MPJPE that the half turn alone costs on the others.

The probe's shape is mirror-symmetric but for the marker (hupbench.fits.probe_fit): where the image does not show the
marker, nothing in it tells the probe from its half turn, and the training grasps hold the probe either way. With the
two turns equally likely there, any output of the corners, a rigid box or not, errs on average by at least half the
distance between the true corners and the half-turned ones (for each corner, the nearest a guess can come on average
to two equally likely places is half their distance). Averaged over all frames (0 where the marker shows), that is a
lower bound of the split's probe MPJPE for any model that has nothing but the marker to read the half turn from.

A frame shows the marker where at least --min-pixels pixels of its stored image are the probe's in the seg map and
have the marker's colour (its strongest channel ahead of the others by --chroma). As a check that those pixels are
the marker, the script prints how often their centre lies nearer the projection of the marker's site through the
true pose than through the half-turned one. Labels and stored images only: no model is run. Val by default.

Usage: python scripts/probe_half_turn_bound.py DATASET [--split val] [--frames 960] [--chroma 0.1] [--min-pixels 4]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def main() -> None:
    from hupbench.core import keypoints as kp
    from hupbench.core.camera import project_points
    from hupbench.core.contract import frame_path, read_annotations, read_manifest, seg_labels, track_of
    from hupbench.core.geometry import fit_rigid_pose
    from hupbench.data.reader import read_rgb, read_seg
    from hupbench.evaluation.prediction import evenly_spaced
    from hupbench.fits.known_probe import dataset_fit_probe

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dataset", type=Path)
    parser.add_argument("--split", default="val", choices=("train", "val", "test"))
    parser.add_argument("--frames", type=int, default=960, help="evenly spaced frames of the split (0: all)")
    parser.add_argument("--chroma", type=float, default=0.1, help="the marker colour's lead, RGB in [0, 1]")
    parser.add_argument("--min-pixels", type=int, default=4, help="marker-coloured probe pixels that show it")
    args = parser.parse_args()
    manifest = read_manifest(args.dataset, args.split)
    ann = read_annotations(args.dataset, args.split, ("keypoints_3d_cam", "K", "grasp_id"), manifest)
    rows = evenly_spaced(len(ann["frame_id"]), args.frames)
    probe = dataset_fit_probe(args.dataset)
    if not probe.has_marker:
        raise SystemExit(f"{args.dataset}: its probe carries no marker: nothing tells its half turn")
    probe_label = seg_labels(track_of(manifest))["probe"]
    corners = ann["keypoints_3d_cam"][rows][:, kp.CORNER_SLICE].astype(np.float64)       # (F, 8, 3)
    pose = fit_rigid_pose(probe.corners, corners)
    R, t = pose[:, :3, :3], pose[:, :3, 3]
    half = np.diag([-1.0, -1.0, 1.0])                                     # the half turn about the long axis (+z)
    flip_mm = np.linalg.norm(probe.corners @ (R @ half).transpose(0, 2, 1) + t[:, None] - corners, axis=-1).mean(1)
    flip_mm *= 1000.0                                                     # (F,) the half turn's own error
    sites = np.stack([R @ probe.marker + t, R @ half @ probe.marker + t], axis=1)    # (F, 2, 3) true, half-turned
    shown, nearer_true = np.zeros(len(rows), dtype=bool), np.zeros(len(rows), dtype=bool)
    for i, row in enumerate(rows):
        fid = int(ann["frame_id"][row])
        seg = read_seg(frame_path(args.dataset, args.split, "seg", fid))
        rgb = read_rgb(frame_path(args.dataset, args.split, "rgb", fid, manifest.get("rgb_format", "jpg"))) / 255.0
        v, u = np.nonzero((seg == probe_label) & (probe.marker_lead(rgb) > args.chroma))
        shown[i] = len(u) >= args.min_pixels
        if shown[i]:   # a site behind the camera projects to NaN: never the nearer
            far = np.linalg.norm(project_points(sites[i], ann["K"][row], behind="nan") - [u.mean(), v.mean()], axis=-1)
            nearer_true[i] = far[0] < far[1]
    bound = np.where(shown, 0.0, 0.5 * flip_mm)
    check = (f"their centre nearer the true site than the half-turned one's in {nearer_true[shown].mean():.1%}"
             if shown.any() else "no frame shows it")
    print(f"{args.dataset} {args.split}: {len(rows)} of {len(ann['frame_id'])} frames; the marker shown in "
          f"{shown.mean():.1%} of them (at least {args.min_pixels} probe pixels with its colour's lead > {args.chroma}); "
          f"{check}")
    print(f"the half turn's own corner error: {flip_mm.mean():.2f} mm")
    print(f"lower bound of the probe MPJPE without the marker: {bound.mean():.2f} mm")
    for g in sorted(np.unique(ann["grasp_id"][rows]).tolist()):
        at = ann["grasp_id"][rows] == g
        print(f"  grasp {g}: shown {shown[at].mean():6.1%}, bound {bound[at].mean():6.2f} mm")
    print(json.dumps({"frames": len(rows), "shown": round(float(shown.mean()), 4),
                      "nearer_true_site": round(float(nearer_true[shown].mean()), 4) if shown.any() else None,
                      "flip_mm": round(float(flip_mm.mean()), 2), "bound_mm": round(float(bound.mean()), 2)}))


if __name__ == "__main__":
    main()
