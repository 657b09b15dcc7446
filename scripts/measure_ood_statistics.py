"""Which statistic tells rendered frames from real photographs: predict's image statistics, or the backbone's
pooled feature? Prints, for both, the share of flagged test frames (as rendered, and cropped to 4:3 so that
predict pads them) and of flagged real photographs, at the 99th percentile of validation frames.

    python scripts/measure_ood_statistics.py CHECKPOINT DATASET [--photos DIR ...]

Both are Mahalanobis distances to the training frames' mean and shrunk covariance
(:func:`hupbench.inference.image_statistics.calibrate`); the feature is the mean over space of the backbone's
last stage (``model.backbone.layer4``) on the padded model input. Real photographs: opencv-doc's hand photos
and sample images (Debian's opencv-doc package).
"""

from __future__ import annotations

import argparse
import glob
from pathlib import Path

import numpy as np
import torch

from hupbench.checkpoint import load_model
from hupbench.inference import image_statistics as stats
from hupbench.inference.images import read_image
from hupbench.inference.predict import preprocess

PHOTOS = ["/usr/share/doc/opencv-doc/opencv4/html/hand*.jpg", "/usr/share/doc/opencv-doc/examples/data/*.jpg"]


def crop_4_3(image: np.ndarray) -> np.ndarray:
    height, width = image.shape[:2]
    keep = int(width * 3 / 4)
    return image[(height - keep) // 2:(height - keep) // 2 + keep]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoint", type=Path)
    parser.add_argument("dataset", type=Path)
    parser.add_argument("--photos", nargs="*", default=PHOTOS, help="glob patterns of photographs")
    parser.add_argument("--frames", type=int, nargs=3, default=(2000, 500, 500), metavar=("TRAIN", "VAL", "TEST"))
    args = parser.parse_args()
    torch.set_num_threads(1)
    model, payload = load_model(args.checkpoint)
    model.eval()
    size = int(payload["input_size"])
    c5: list[torch.Tensor] = []
    model.backbone.layer4.register_forward_hook(lambda _m, _i, out: c5.append(out))

    def measure(images: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        """(B, F) pooled features and (B, 10) image statistics."""
        features = []
        for start in range(0, len(images), 32):
            batch = np.stack([preprocess(image, size)[0] for image in images[start:start + 32]])
            c5.clear()
            with torch.inference_mode():
                model(torch.from_numpy(batch))
            features.append(c5[-1].float().mean(dim=(2, 3)).numpy())
        return np.concatenate(features), np.stack([stats.image_statistics(image, size) for image in images])

    def frames(split: str, n: int) -> list[np.ndarray]:
        files = sorted((args.dataset / split / "rgb").iterdir())
        idx = np.unique(np.linspace(0, len(files) - 1, min(n, len(files))).round().astype(int))
        return [read_image(files[i]) for i in idx]

    photos = [read_image(p) for pattern in args.photos for p in sorted(glob.glob(pattern))]
    train, val, test = (frames(split, n) for split, n in zip(("train", "val", "test"), args.frames))
    sets = {"val": measure(val), "test": measure(test), "test 4:3": measure([crop_4_3(i) for i in test]),
            "photos": measure(photos)}
    train_measures = measure(train)
    print(f"{args.checkpoint} ({size} px), {len(train)} train / {len(val)} val / {len(test)} test frames, "
          f"{len(photos)} photographs")
    for k, name in enumerate(("backbone feature", "image statistics")):
        check = stats.calibrate(train_measures[k], sets["val"][k], "val")
        flagged = {key: check.distance(value[k]) > check.threshold for key, value in sets.items() if key != "val"}
        print(f"{name:17s} threshold {check.threshold:7.2f}: flagged test {flagged['test'].mean():6.1%}, "
              f"test 4:3 {flagged['test 4:3'].mean():6.1%}, photographs {flagged['photos'].mean():6.1%} "
              f"({flagged['photos'].sum()}/{len(photos)})")


if __name__ == "__main__":
    main()
