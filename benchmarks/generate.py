"""End-to-end dataset generation speed: render + composite + encode + write, per worker count.

Renders the same small dataset (the first grasp of a grasps file, 2 distances,
``--backgrounds`` backgrounds, 2 gloves, 90 views of ``--size`` pixels) with 1 and 2 worker
processes into temporary folders and prints frames per second and the
projected wall time of the full default dataset (31,680 frames; meaningful at the default 256 px).

Usage: python benchmarks/generate.py GRASPS_NPZ [--backgrounds 4] [--workers 1 2] [--size 256] [--r-circ-m 0.15]
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
    parser.add_argument("--size", type=int, default=256, help="image side, pixels (intrinsics scale with it)")
    parser.add_argument("--r-circ-m", type=float, default=0.15, help="0.15: the default 90 views per sphere; 0.4: 10")
    args = parser.parse_args()

    from hupbench.datagen.dataset.spec import DatasetSpec
    from hupbench.datagen.dataset.sphere import SphereSpec
    from hupbench.datagen.dataset.writer import GenerateRun, generate
    from hupbench.core.io import save_npz

    with np.load(args.grasps) as data:
        one = {k: (data[k][:1] if data[k].ndim and len(data[k]) > 1 else data[k]) for k in data.files}
    scale = args.size / 256
    spec = DatasetSpec(splits={"train": 1, "val": 0, "test": 0}, n_backgrounds=args.backgrounds,
                       sphere=SphereSpec(r_circ_m=args.r_circ_m), width=args.size, height=args.size,
                       fx=480.0 * scale, fy=480.0 * scale, cx=128.0 * scale, cy=128.0 * scale)
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
