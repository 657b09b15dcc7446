"""A heatmap model's per-keypoint confidence (:func:`hupbench.models.heatmap.heatmap_confidence`) on test frames and on
images of uniform noise: how much it says.

    python scripts/measure_keypoint_confidence.py CHECKPOINT DATASET [--frames 256]

Prints the median and 10th percentile over frames and keypoints, hand joints and probe corners apart.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

from hupbench.core import keypoints as kp
from hupbench.checkpoint import load_model
from hupbench.data import HUPDataset, ReaderConfig


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoint", type=Path)
    parser.add_argument("dataset", type=Path)
    parser.add_argument("--frames", type=int, default=256)
    args = parser.parse_args()
    model, payload = load_model(args.checkpoint)
    model.eval()
    channels = payload["model_config"].get("input_channels", 3)
    reader = HUPDataset(args.dataset, "test", ReaderConfig(input_size=int(payload["input_size"]),
                                                           input_modalities="rgb+depth" if channels == 4 else "rgb"))
    idx = np.linspace(0, len(reader) - 1, min(args.frames, len(reader))).round().astype(int)

    def confidence(images: torch.Tensor) -> np.ndarray:
        with torch.inference_mode():
            return model(images).confidence.numpy()  # (B, N)

    frames = np.concatenate([confidence(torch.stack([reader[int(i)]["image"] for i in idx[s:s + 32]]))
                             for s in range(0, len(idx), 32)])
    size = int(payload["input_size"])
    noise = confidence(torch.rand(32, channels, size, size, generator=torch.Generator().manual_seed(0)))
    for name, values in ((f"{len(frames)} test frames", frames), ("32 noise images", noise)):
        hand, corners = values[:, :kp.NUM_HAND], values[:, kp.NUM_HAND:]
        print(f"{name:16s} hand median {np.median(hand):.3f} (p10 {np.percentile(hand, 10):.3f}), "
              f"corners median {np.median(corners):.3f} (p10 {np.percentile(corners, 10):.3f})")


if __name__ == "__main__":
    main()
