"""Can HOPE-Net's Graph U-Net lift 2D keypoints to absolute camera-frame 3D? Measured from true 2D.

The official HOPE-Net code trains its Graph U-Net alone from ground-truth 2D (``Graph.py``); this
does the same on a hupbench dataset, for each lifting variant of ``hupbench.models.hopenet.HOPENet``:

    constant     the training split's mean layout for every frame (the floor any model must beat)
    direct       the faithful U-Net: 2D points in, camera-frame 3D out (an offset from the mean layout)
    camera       the U-Net predicts each keypoint's depth and a 2D correction; x and y follow from the
                 2D point, its depth and the input camera's intrinsics (lift="camera")

Inputs are the true 2D keypoints in normalised coordinates of the model input (no image), targets
the true 3D keypoints; trained on the training split, scored on the validation split: MPJPE (all /
hand / probe, mm) and the per-axis spread ratios of hupbench eval.

Usage: python scripts/diagnose_lifting.py DATASET [--steps 3000] [--batch 256] [--input-size 128]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch


def load(root, split: str, size: int) -> tuple[torch.Tensor, torch.Tensor, np.ndarray]:
    """(N, 29, 2) normalised true 2D, (N, 29, 3) metres true 3D, and the input K."""
    from hupbench.data import input_labels, read_manifest

    manifest = read_manifest(root, split)
    with np.load(f"{root}/{split}/annotations.npz") as data:
        ann = {k: data[k] for k in ("keypoints_3d_cam", "keypoints_2d", "K", "visible")}
    labels = input_labels(ann, size / int(manifest["image_size"][0]), size)
    return torch.from_numpy(labels["keypoints_2d"]), torch.from_numpy(labels["keypoints_3d"]), labels["K"][0]


def lifter(variant: str, mean: np.ndarray, K: np.ndarray, size: int) -> torch.nn.Module:
    from hupbench.models.hopenet import GraphLifter

    return GraphLifter(lift=variant, points3d_mean=mean.tolist(), points3d_scale=0.01,
                       K_input=K.tolist(), input_size=size)


def main() -> None:
    from hupbench.metrics import mpjpe_split_mm, spread_ratios

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dataset")
    parser.add_argument("--steps", type=int, default=3000)
    parser.add_argument("--batch", type=int, default=256)
    parser.add_argument("--input-size", type=int, default=128)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    x_train, y_train, K = load(args.dataset, "train", args.input_size)
    x_val, y_val, _ = load(args.dataset, "val", args.input_size)
    mean = y_train.double().mean(dim=0).numpy()
    print(f"{len(x_train)} training and {len(x_val)} validation frames; true 2D -> 3D, {args.steps} steps of "
          f"{args.batch}, Adam 1e-3 with cosine decay")

    def report(name: str, pred: torch.Tensor, seconds: float) -> None:
        split = mpjpe_split_mm(pred.double(), y_val.double())
        ratios = spread_ratios(pred, y_val)
        print(f"  {name:9s} val MPJPE all {split['all']:6.1f} | hand {split['hand']:6.1f} | probe {split['probe']:6.1f} mm"
              f" | spread ratio x {ratios['x']:.2f} y {ratios['y']:.2f} z {ratios['z']:.2f} | {seconds:5.0f} s",
              flush=True)

    report("constant", torch.from_numpy(mean).float().expand_as(y_val), 0.0)
    for variant in ("direct", "camera"):
        torch.manual_seed(args.seed)
        model = lifter(variant, mean, K, args.input_size)
        optimizer = torch.optim.Adam(model.parameters(), lr=1e-3)
        schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, args.steps)
        generator = torch.Generator().manual_seed(args.seed)
        start = time.perf_counter()
        for _ in range(args.steps):
            idx = torch.randint(len(x_train), (args.batch,), generator=generator)
            loss = torch.nn.functional.mse_loss(model(x_train[idx]) / 0.01, y_train[idx] / 0.01)  # cm^2
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
            schedule.step()
        with torch.no_grad():
            pred = torch.cat([model(chunk) for chunk in x_val.split(1024)])
        report(variant, pred, time.perf_counter() - start)


if __name__ == "__main__":
    main()
