"""Regenerate the README's dataset pictures from a finished dataset: docs/grasps_contact_sheet.png (its grasps,
three views each, with their scores and splits) and docs/dataset_samples.png (its overview: views from across the
camera sphere with a map of all view positions, every camera distance, every grasp, with legends); also
docs/preview.png, the quickstart's first picture (the hand-set grasp, which needs no dataset).

Usage: python scripts/docs_pictures.py [DATASET] [--out docs]   (DATASET: default hupbench_out/dataset)
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np


def main() -> None:
    from hupbench.core.contract import read_manifest
    from hupbench.datagen.dataset.sample_sheet import overview
    from hupbench.datagen.grasps.sheet import contact_sheet
    from hupbench.core.draw import write_png
    from hupbench.datagen.render.preview import preview

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dataset", nargs="?", default="hupbench_out/dataset", help="a finished dataset folder")
    parser.add_argument("--out", default="docs", help="folder the PNGs are written to")
    args = parser.parse_args()
    root, out = Path(args.dataset), Path(args.out)
    manifest = read_manifest(root)
    split_of = {int(g): split for split, ids in manifest["grasp_ids"].items() for g in ids}
    with np.load(root / "grasps.npz") as data:
        grasps = {k: data[k] for k in data.files}
    print(write_png(out / "grasps_contact_sheet.png", contact_sheet(grasps, 200, split_of=split_of)))
    print(write_png(out / "dataset_samples.png", overview(root)))
    print(preview(out / "preview.png")["path"])


if __name__ == "__main__":
    main()
