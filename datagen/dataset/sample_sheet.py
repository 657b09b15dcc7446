"""A picture of a dataset: one frame per (background, glove) with its depth, mask and keypoints, read
through the dataset contract (``hupbench verify --sample-sheet``)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from datagen.dataset.contract import frame_path, read_annotations, read_manifest
from datagen.dataset.verify_images import read_image
from datagen.errors import BadValueError


def sample_sheet(root, split: str = "train", view: int | None = None, tile_px: int = 128) -> np.ndarray:
    """One frame per (background, glove) of a dataset: RGB, depth, mask and keypoints side by side.

    Takes the split's first grasp at the first distance and the given view index (default: view
    40 of the paper protocol's sphere, where the grip and the probe's green orientation marker both
    show, or the middle view of a sphere with fewer views).

    Returns:
        (H, W, 3) uint8 RGB: one row per background, both gloves in a row.

    Raises:
        ValueError: the dataset lacks a modality, the split or a readable image (the message names it).
    """
    from datagen.render.draw import colorize_depth, colorize_labels, draw_keypoints, grid, titled

    root = Path(root)
    manifest = read_manifest(root, split=split)
    missing = {"rgb", "depth", "seg"} - set(manifest["modalities"])
    if missing:
        raise BadValueError(f"a sample sheet needs rgb, depth and seg; the dataset lacks {sorted(missing)}")
    ann = read_annotations(root, split, keys=("frame_id", "keypoints_2d", "visible", "background_id", "glove_id",
                                              "grasp_index", "z_ego"), manifest=manifest)
    n_view = manifest["layout"]["shape"][4]
    if view is None:
        view = 40 if n_view > 40 else n_view // 2
    assert 0 <= view < n_view, (view, n_view)
    first = (ann["grasp_index"] == ann["grasp_index"].min()) & (ann["z_ego"] == ann["z_ego"].min())
    names = (manifest.get("backgrounds") or {}).get("names") or []
    tiles = []
    scale = tile_px / manifest["image_size"][0]
    for b in sorted(set(ann["background_id"].tolist())):
        for glove in sorted(set(ann["glove_id"].tolist())):
            rows = np.flatnonzero(first & (ann["background_id"] == b) & (ann["glove_id"] == glove))
            if not len(rows):
                continue
            i = rows[min(view, len(rows) - 1)]
            fid = int(ann["frame_id"][i])
            images = {}
            for m in ("rgb", "depth", "seg"):
                path = frame_path(root, split, m, fid, manifest["rgb_format"])
                images[m], why = read_image(path, m)
                if images[m] is None:
                    raise BadValueError(f"{path}: {why}")
            rgb = images["rgb"][..., ::-1]
            size = (tile_px, tile_px)
            panels = [cv2.resize(np.ascontiguousarray(rgb), size, interpolation=cv2.INTER_AREA),
                      cv2.resize(colorize_depth(images["depth"] * manifest["depth_scale_m"]), size,
                                 interpolation=cv2.INTER_NEAREST),
                      cv2.resize(colorize_labels(images["seg"]), size, interpolation=cv2.INTER_NEAREST)]
            kps = draw_keypoints(panels[0], ann["keypoints_2d"][i] * scale + 0.5 * (scale - 1), ann["visible"][i],
                                 radius=1.5)
            label = f"{names[b] if b < len(names) else b} / glove {glove}"
            tiles += [titled(panels[0], label[:22]), titled(panels[1], "depth"), titled(panels[2], "mask"),
                      titled(kps, f"frame {fid}")]
    return grid(tiles, columns=8)
