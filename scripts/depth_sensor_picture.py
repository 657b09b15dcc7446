"""docs/depth_sensor.png: the same frames' clean depth (the renderer's z-buffer) and what each depth camera of
hupbench.core.depth_sensor makes of it (the noise each frame's own, as the reader and the generator draw it), and a
side view of the points around the probe: clean beside each sensor's.

Usage: python scripts/depth_sensor_picture.py [DATASET] [--split train] [--frames 2] [--out docs/depth_sensor.png]
       (default DATASET: hupbench_out/dataset_clinic; any dataset with depth and seg maps)
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

#: depth colour range, metres: the hand at 0.35 m to a metre past the AHAT camera's wrap
DEPTH_RANGE_M = (0.3, 2.0)
#: the probe region: probe pixels and this many pixels around them
PROBE_MARGIN_PX = 12
#: the side view's colour per sensor
COLOURS = {"none": "0.2", "azure_kinect_nfov": "tab:blue", "hololens2_ahat": "tab:red",
           "hololens2_longthrow": "tab:green"}


def _frames(ann: dict, seg_of, count: int) -> list[int]:
    """Rows of ``count`` frames of different grasps, each its grasp's frame with the most probe pixels."""
    chosen = []
    for grasp in np.unique(ann["grasp_id"])[:count]:
        rows = np.flatnonzero(ann["grasp_id"] == grasp)[:12]
        chosen.append(int(max(rows, key=lambda r: int((seg_of(r) == 3).sum()))))
    return chosen


def _points(depth_m: np.ndarray, K: np.ndarray, region: np.ndarray) -> np.ndarray:
    """(P, 3) camera-frame points of the pixels of ``region`` that have depth."""
    v, u = np.nonzero(region & (depth_m > 0))
    z = depth_m[v, u]
    return np.stack([(u - K[0, 2]) / K[0, 0] * z, (v - K[1, 2]) / K[1, 1] * z, z], -1)


def main() -> None:
    import cv2
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from hupbench.core.contract import frame_path, read_annotations, read_manifest
    from hupbench.core.depth_sensor import NONE, PRESETS, stored_sensor_depth
    from hupbench.data.reader import read_depth, read_rgb, read_seg

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dataset", nargs="?", default="hupbench_out/dataset_clinic")
    parser.add_argument("--split", default="train")
    parser.add_argument("--frames", type=int, default=2)
    parser.add_argument("--out", default="docs/depth_sensor.png")
    args = parser.parse_args()
    root = Path(args.dataset)
    manifest = read_manifest(root, args.split)
    ann = read_annotations(root, args.split, ("frame_id", "grasp_id"), manifest)
    K, scale, labels = np.asarray(manifest["K"]), manifest["depth_scale_m"], manifest["seg_labels"]
    seed = (manifest.get("depth_sensor") or {}).get("seed", 0)

    def path(row: int, modality: str) -> Path:
        return frame_path(root, args.split, modality, int(ann["frame_id"][row]), manifest["rgb_format"])

    rows = _frames(ann, lambda r: read_seg(path(r, "seg")), args.frames)
    sensors = [NONE, *PRESETS]
    fig, axes = plt.subplots(len(rows), len(sensors) + 2, figsize=(3.0 * (len(sensors) + 2), 3.2 * len(rows)),
                             squeeze=False)
    for i, row in enumerate(rows):
        clean, seg = read_depth(path(row, "depth")), read_seg(path(row, "seg"))
        region = cv2.dilate((seg == labels["probe"]).astype(np.uint8),
                            np.ones((2 * PROBE_MARGIN_PX + 1,) * 2, np.uint8)).astype(bool)
        axes[i, 0].imshow(read_rgb(path(row, "rgb")))
        axes[i, 0].set_title(f"frame {int(ann['frame_id'][row])}, grasp {int(ann['grasp_id'][row])}", fontsize=9)
        side = axes[i, -1]
        for j, name in enumerate(sensors, start=1):
            depth = clean if name == NONE else stored_sensor_depth(clean, seg, K, PRESETS[name], labels, scale, seed,
                                                                  int(ann["frame_id"][row]))
            metres = depth * scale
            shown = np.ma.masked_where(metres == 0, metres)
            axes[i, j].imshow(shown, cmap="viridis", vmin=DEPTH_RANGE_M[0], vmax=DEPTH_RANGE_M[1],
                              interpolation="nearest")
            axes[i, j].set_facecolor("black")
            axes[i, j].set_title(f"{name}: {100 * (metres == 0).mean():.0f} % no depth", fontsize=9)
            points = _points(metres, K, region)
            side.scatter(points[:, 0] * 1000, points[:, 2] * 1000, s=1, c=COLOURS[name], label=name, alpha=0.6)
        side.set_xlabel("x (mm)")
        side.set_ylabel("depth (mm)")
        side.invert_yaxis()
        side.set_title("the probe region, side view", fontsize=9)
        side.legend(fontsize=7, markerscale=6, loc="best")
        for ax in axes[i, :-1]:
            ax.set_xticks([])
            ax.set_yticks([])
    fig.suptitle(f"Clean depth and each depth camera's (hupbench/core/depth_sensor.py); depth "
                 f"{DEPTH_RANGE_M[0]}-{DEPTH_RANGE_M[1]} m, black: no depth", fontsize=11)
    fig.tight_layout()
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=90, metadata={"Software": None})
    plt.close(fig)
    print(out)


if __name__ == "__main__":
    main()
