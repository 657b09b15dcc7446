"""docs/clinic_frames.png: clinic-track frames of the smallest and the largest hands of a clinic dataset, with the
abdomen under the probe and the room behind, each as RGB with its keypoints, depth and mask, beside frames of the
paper protocol (one hand, no patient, a flat backdrop with no depth). Depth maps share one colour range.

Usage: python scripts/clinic_picture.py [CLINIC_DATASET] [PAPER_DATASET] [--out docs/clinic_frames.png]
       (defaults: hupbench_out/dataset_clinic, hupbench_out/dataset)
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

#: pixels per tile side
TILE_PX = 200
#: the frames' depth is coloured on this range, metres: the hand at 0.35 m to the room's far wall
DEPTH_RANGE_M = (0.3, 3.0)
_KEYS = ("frame_id", "keypoints_2d", "visible", "grasp_id", "z_ego", "theta")
_CLINIC_KEYS = ("hand_length_mm", "hand_breadth_mm", "subject_sex", "roll_deg")


def _best_frame(ann: dict, rows: np.ndarray) -> int:
    """Of ``rows``, the frame with the most visible keypoints (the first of equals)."""
    return int(rows[np.argmax(ann["visible"][rows].sum(axis=1))])


def _row(root: Path, manifest: dict, split: str, ann: dict, row: int, title: str) -> np.ndarray:
    """RGB with keypoints, depth and mask of one frame, side by side under ``title``."""
    import cv2

    from hupbench.core.draw import beside, colorize_depth, colorize_labels, draw_keypoints, keypoint_radius_px, \
        resize_with_keypoints, titled
    from hupbench.datagen.dataset.sample_sheet import read_frame

    frame = read_frame(root, split, manifest, int(ann["frame_id"][row]))
    rgb, uv = resize_with_keypoints(frame["rgb"], ann["keypoints_2d"][row], TILE_PX)
    rgb = draw_keypoints(rgb, uv, ann["visible"][row], radius=keypoint_radius_px(TILE_PX), thickness=2)
    size = (TILE_PX, TILE_PX)
    depth = cv2.resize(colorize_depth(frame["depth_m"], *DEPTH_RANGE_M), size, interpolation=cv2.INTER_NEAREST)
    seg = cv2.resize(colorize_labels(frame["seg"]), size, interpolation=cv2.INTER_NEAREST)
    covered = 100.0 * (frame["depth_m"] > 0).mean()
    return titled(beside([rgb, depth, seg]), f"{title}\ndepth > 0 on {covered:.0f} % of the pixels")


def main() -> None:
    from hupbench.core.contract import read_annotations, read_manifest
    from hupbench.core.draw import stack, text_block, write_png
    from hupbench.datagen.dataset.sample_sheet import legends

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("clinic", nargs="?", default="hupbench_out/dataset_clinic", help="a finished clinic dataset")
    parser.add_argument("paper", nargs="?", default="hupbench_out/dataset", help="a finished paper-protocol dataset")
    parser.add_argument("--out", default="docs/clinic_frames.png")
    parser.add_argument("--split", default="train", help="the split the frames come from")
    args = parser.parse_args()
    clinic, paper = Path(args.clinic), Path(args.paper)
    clinic_manifest, paper_manifest = read_manifest(clinic, args.split), read_manifest(paper, args.split)
    ann = read_annotations(clinic, args.split, _KEYS + _CLINIC_KEYS, clinic_manifest)
    length = ann["hand_length_mm"]
    rows = []
    for name, grasp_rows in (("smallest hand", np.flatnonzero(length == length.min())),
                             ("largest hand", np.flatnonzero(length == length.max()))):
        row = _best_frame(ann, grasp_rows)
        sex = "woman" if ann["subject_sex"][row] == 0 else "man"
        rows.append(_row(clinic, clinic_manifest, args.split, ann, row,
                         f"clinic, {name}: {sex}, hand {length[row]:.0f} x {ann['hand_breadth_mm'][row]:.0f} mm "
                         f"(length x breadth); camera {ann['z_ego'][row]:.2f} m, "
                         f"{90 - np.degrees(ann['theta'][row]):.0f} deg above the bed, roll {ann['roll_deg'][row]:+.0f} deg"))
    paper_ann = read_annotations(paper, args.split, _KEYS, paper_manifest)
    for grasp in np.unique(paper_ann["grasp_id"])[:2]:
        row = _best_frame(paper_ann, np.flatnonzero(paper_ann["grasp_id"] == grasp))
        rows.append(_row(paper, paper_manifest, args.split, paper_ann, row,
                         f"paper protocol, grasp {int(grasp)}: the one hand, camera {paper_ann['z_ego'][row]:.1f} m "
                         "on the sphere tied to the wrist"))
    body = stack(rows)
    header = text_block(["Clinic track (top two rows) beside the paper protocol (bottom two): RGB with keypoints, "
                         f"depth ({DEPTH_RANGE_M[0]}-{DEPTH_RANGE_M[1]} m) and mask. On the clinic track the abdomen "
                         "lies under the probe and the room has depth, so depth > 0 is no foreground mask."],
                        body.shape[1])
    print(write_png(args.out, stack([header, body, legends(clinic_manifest, DEPTH_RANGE_M, body.shape[1])])))


if __name__ == "__main__":
    main()
