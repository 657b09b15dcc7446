"""How wide predict's depth range must be: the median depth of every training and validation depth map of a
dataset, the factor by which the training frames' range must be widened to hold every validation frame, and
the largest factor under which the same validation maps read at ten times and a tenth of their scale (a map in
another unit) are all still refused. :data:`hupbench.inference.image_statistics.DEPTH_MARGIN` lies between the
two. The test split plays no part.

    python scripts/measure_depth_range.py DATASET
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from hupbench.core.contract import read_manifest
from hupbench.inference import image_statistics as stats
from hupbench.inference.images import read_depth_png

#: how far off a map in another unit is (millimetres read as 0.1 mm, or the other way round)
UNIT_SLIP = 10.0


def split_medians_m(dataset: Path, split: str, scale_m: float) -> np.ndarray:
    """(F,) the median valid depth, metres, of every depth map of a split (:func:`stats.depth_median_m`)."""
    return np.array([stats.depth_median_m(read_depth_png(path) * scale_m)
                     for path in sorted((dataset / split / "depth").glob("*.png"))])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("dataset", type=Path)
    args = parser.parse_args()
    scale_m = read_manifest(args.dataset)["depth_scale_m"]
    train, val = (split_medians_m(args.dataset, split, scale_m) for split in ("train", "val"))
    low, high = train.min(), train.max()
    needed = max(1.0, float(np.max(np.maximum(low / val, val / high))))
    # a slipped map is refused while UNIT_SLIP x median > high x factor and median / UNIT_SLIP < low / factor
    largest = float(np.min(np.minimum(UNIT_SLIP * val / high, UNIT_SLIP * low / val)))
    margin = stats.DEPTH_MARGIN
    print(f"train: {len(train)} frames, median depth {low:.3f}-{high:.3f} m")
    print(f"val: {len(val)} frames, median depth {val.min():.3f}-{val.max():.3f} m")
    print(f"factor that keeps every val frame: {needed:.3f}")
    print(f"largest factor that refuses every val frame read at {UNIT_SLIP:g} x or 1/{UNIT_SLIP:g} of its scale: "
          f"{largest:.3f}")
    print(f"DEPTH_MARGIN {margin:g}: keeps every val frame: {'yes' if needed <= margin else 'no'}; refuses the unit "
          f"slips: {'yes' if margin < largest else 'no'}")


if __name__ == "__main__":
    main()
