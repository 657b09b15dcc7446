"""End-to-end dataset generation speed: render + composite + encode + write, per worker count.

Renders the same small dataset (the first grasp of a grasps file, 2 distances,
``--backgrounds`` backgrounds, 2 gloves, 90 views) with 1 and 2 worker
processes into temporary folders and prints frames per second and the
projected wall time of the full default dataset (31,680 frames).

Usage: python benchmarks/generate.py GRASPS_NPZ [--backgrounds 4] [--workers 1 2]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

FULL_DATASET_FRAMES = 31680


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("grasps", help="a grasps.npz (from hupbench grasps)")
    parser.add_argument("--backgrounds", type=int, default=4)
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    args = parser.parse_args()

    from hupbench.datagen.dataset.spec import DatasetSpec
    from hupbench.datagen.dataset.writer import GenerateRun, generate
    from hupbench.core.io import save_npz

    with np.load(args.grasps) as data:
        one = {k: (data[k][:1] if data[k].ndim and len(data[k]) > 1 else data[k]) for k in data.files}
    spec = DatasetSpec(splits={"train": 1, "val": 0, "test": 0}, n_backgrounds=args.backgrounds)
    with tempfile.TemporaryDirectory() as tmp:
        grasps = save_npz(Path(tmp) / "one_grasp.npz", one)
        for workers in args.workers:
            out = Path(tmp) / f"w{workers}"
            start = time.perf_counter()
            result = generate(GenerateRun(spec, out, grasps, progress=False, workers=workers), {"benchmark": workers},
                              log=lambda *_: None)
            wall = time.perf_counter() - start
            rate = result["frames_rendered"] / wall
            print(f"workers {workers}: {result['frames_rendered']} frames in {wall:.1f} s = {rate:.1f} frames/s "
                  f"end to end (incl. worker start-up); full dataset {FULL_DATASET_FRAMES} frames: "
                  f"{FULL_DATASET_FRAMES / rate / 60:.1f} min", flush=True)


if __name__ == "__main__":
    main()
