"""Training throughput: images per second for one optimiser step (forward, loss, backward, Adam).

Models: hopenet_r18 at 128 px, HOPE-Net (ResNet-10) and the ResNet-50 baseline at 224 px, in fp32
and with bf16 autocast (+ channels_last), on synthetic batches (speed does not depend on the
pixels). Prints the median over timed steps after warm-up and the bf16 / fp32 ratio.

Usage: python benchmarks/train.py [--batch 16] [--steps 6] [--threads 2]
"""

from __future__ import annotations

import argparse
import statistics
import time

import torch

CASES = (
    ("hopenet_r18", {"name": "hopenet", "backbone": "resnet18"}, 128),
    ("hopenet", {"name": "hopenet", "backbone": "resnet10"}, 224),
    ("resnet50", {"name": "resnet_regressor", "backbone": "resnet50"}, 224),
)


def step_time(model, images, bf16: bool) -> float:
    optimiser = torch.optim.Adam(model.parameters(), lr=1e-3)
    start = time.perf_counter()
    with torch.autocast("cpu", dtype=torch.bfloat16, enabled=bf16):
        out = model(images)
        loss = out.points3d.float().square().mean()
        if getattr(out, "points2d", None) is not None:
            loss = loss + out.points2d.float().square().mean()
    optimiser.zero_grad(set_to_none=True)
    loss.backward()
    optimiser.step()
    return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch", type=int, default=16)
    parser.add_argument("--steps", type=int, default=6, help="timed steps per case (after 2 warm-up steps)")
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)

    from models.build import build_model

    print(f"batch {args.batch}, {args.steps} timed steps, torch threads {args.threads}")
    for label, cfg, size in CASES:
        rates = {}
        for bf16 in (False, True):
            torch.manual_seed(0)
            model = build_model(cfg).train()
            images = torch.rand(args.batch, 3, size, size)
            if bf16:
                model = model.to(memory_format=torch.channels_last)
                images = images.contiguous(memory_format=torch.channels_last)
            for _ in range(2):
                step_time(model, images, bf16)
            times = [step_time(model, images, bf16) for _ in range(args.steps)]
            rates[bf16] = args.batch / statistics.median(times)
        print(f"  {label:12s} {size} px: fp32 {rates[False]:6.1f} img/s, bf16+channels_last {rates[True]:6.1f} img/s, "
              f"ratio {rates[True] / rates[False]:.2f}", flush=True)


if __name__ == "__main__":
    main()
