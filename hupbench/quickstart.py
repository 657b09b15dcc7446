"""``hupbench quickstart``: the main job on the embedded default.

For now it renders the preview sheet of a hand-set grasp (RGB, depth,
labels, projected keypoints); later stages (dataset, training, evaluation,
ONNX export, prediction) join as they land.
"""

from __future__ import annotations

import time
from pathlib import Path

from omegaconf import DictConfig

from datagen.io import write_json
from hupbench.config import build
from hupbench.provenance import run_info


def run_quickstart(cfg: DictConfig) -> dict:
    """Run the quickstart pipeline.

    Args:
        cfg: the composed ``quickstart`` config.

    Returns:
        dict with "out_dir", "preview" (path), "run_info" (path), "render_platform",
        "seconds" and the number of keypoints in view.
    """
    from datagen import gl
    from datagen.preview import handset_grasp, preview

    start = time.perf_counter()
    out_dir = Path(cfg.out_dir)
    intrinsics = build(cfg.camera)
    view = build(cfg.view)
    result = preview(out_dir / "preview.png", handset_grasp(), intrinsics, view,
                     modalities=list(cfg.render.modalities), platform=cfg.render.platform)
    preview_path = result["path"]
    uv = result["keypoints_2d"]
    in_view = int(((uv[:, 0] >= -0.5) & (uv[:, 0] < intrinsics.width - 0.5)
                   & (uv[:, 1] >= -0.5) & (uv[:, 1] < intrinsics.height - 0.5)).sum())
    seconds = time.perf_counter() - start
    info_path = write_json(out_dir / "run.json", run_info(cfg, verb="quickstart", seconds=seconds,
                                                          render_platform=gl.configure()))
    return {"out_dir": str(out_dir), "preview": str(preview_path), "run_info": str(info_path),
            "render_platform": gl.configure(), "keypoints_in_view": in_view, "seconds": seconds}
