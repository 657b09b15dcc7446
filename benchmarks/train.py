"""Training throughput of the whole input pipeline: loader + augmentation + optimiser step, images/s.

Runs the training code's own pieces (``hupbench.data.setup_data``, ``build_run_model`` and ``train_step``)
on a real dataset for each source of frames side by side in one process: ``jpeg`` (JPEG decode and resize per
image in loader workers) and ``cache`` (frames decoded once into the memory-mapped frame cache); both
are augmented per batch on the training device. For each it prints the median step rate over the
timed steps, the end-to-end rate (all timed steps, data waits included) and the share of wall time the
device waited for data (time spent in the loader's ``next()``; on CUDA each step is synchronised so
that waits and compute are told apart).

Usage:
    python benchmarks/train.py DATASET [--model hopenet_r10_128 | --experiment NAME] [--device cpu|cuda]
        [--batch 32] [--steps 40] [--warmup 5] [--threads 2] [--compile]
        [--pipelines jpeg:1,cache:0,cache:0:cl,cache:0:cl:bf16] [--set KEY=VALUE ...] [--json FILE]
    Each pipeline item is PIPELINE:WORKERS[:cl][:bf16][:depth][:resident]: loader workers, channels_last, bf16
    autocast, the depth input beside the RGB (data.reader.input_modalities=rgb+depth), and ``resident``: the
    loader's first batch kept on the device and trained on at every step, no loader in the timed loop (the
    device's ceiling for the model: what a loader that never kept it waiting would reach; its augmentation and
    optimiser step still run). The first item is the reference the others are compared with. --experiment
    composes a file of conf/experiment/ (its model, input and loss) instead of --model; --set adds a train config
    override to every item (e.g. data.reader.depth_sensor=hololens2_ahat, the depth camera a clinic experiment
    reads); --json writes each item's figures to FILE.

The frame cache is built before timing (its one-off cost is printed separately). A train split smaller than
(warm-up + steps) x batch frames is cycled epoch after epoch, as training does. The first line names the CPU,
torch's CPU capability and whether bf16 is native there (elsewhere the bf16 items run emulated).
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path


def measure(dataset: str, pipeline: str, workers: int, precision: str, channels_last: bool, depth: bool,
            resident: bool, args) -> dict:
    import torch

    from hupbench.config import compose
    from hupbench.data import Placement, setup_data
    from hupbench.training.run_config import train_config
    from hupbench.training.loop import autocast_args, build_run_model, resolve_precision, train_step
    from hupbench.training.schedule import learning_rate

    chosen = [f"+experiment={args.experiment}"] if args.experiment else [f"model={args.model}"]
    cfg = compose("train", [*chosen, f"data.root={dataset}", f"data.pipeline={pipeline}",
                            f"data.num_workers={workers}", f"data.batch_size={args.batch}", f"device={args.device}",
                            f"precision={precision}", f"channels_last={str(channels_last).lower()}",
                            "data.val_frames=32", "train.bn_recompute_frames=0", "train.progress=true",
                            *(["data.reader.input_modalities=rgb+depth"] if depth else []), *args.set])
    run = train_config(cfg)
    device = torch.device(args.device)
    autocast = autocast_args(resolve_precision(run.precision, device), device)
    t0 = time.perf_counter()
    data = setup_data(run.data, run.seed, run.train.bn_recompute_frames, Placement(1, 0, device), run.train.progress,
                      with_seg=getattr(run.model, "segmentation", False))
    setup_s = time.perf_counter() - t0
    K = data.train_set.ann["K"][0]
    model = build_run_model(run, data, K).to(device)
    if channels_last:
        model = model.to(memory_format=torch.channels_last)
    train_model = torch.compile(model) if args.compile else model
    optimizer = run.optim.optimizer(model.parameters(), lr=learning_rate(run.optim, args.batch))
    scheduler = run.optim.scheduler(optimizer, total_steps=args.warmup + args.steps)
    sync = torch.cuda.synchronize if device.type == "cuda" else (lambda: None)
    epoch = 0
    data.sampler.set_position(epoch, 0)
    batches = iter(data.train_loader)
    waits, steps = [], []
    start = None
    for i in range(args.warmup + args.steps):
        if i == args.warmup:
            sync()
            start = time.perf_counter()
        t_wait = time.perf_counter()
        if not resident or i == 0:  # resident: the first batch, on the device from step 0 on
            batch = next(batches, None)
            if batch is None:  # a small train split: the next epoch, as training does (its start is timed too)
                epoch += 1
                data.sampler.set_position(epoch, 0)
                batches = iter(data.train_loader)
                batch = next(batches)
            if resident:
                batch = {name: value.to(device) for name, value in batch.items()}
        t_step = time.perf_counter()
        loss, _ = train_step(train_model, optimizer, batch, epoch, data, run, device, autocast)
        scheduler.step()
        float(loss)  # waits for the device
        t_end = time.perf_counter()
        if i >= args.warmup:
            waits.append(t_step - t_wait)
            steps.append(t_end - t_wait)
    total = time.perf_counter() - start
    return {"setup_s": setup_s, "median_img_s": args.batch / statistics.median(steps),
            "end_to_end_img_s": args.batch * args.steps / total, "wait_share": sum(waits) / total}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dataset", help="a dataset made by hupbench generate")
    chosen = parser.add_mutually_exclusive_group()
    chosen.add_argument("--model", default="hopenet_r10_128", help="a config of conf/model/")
    chosen.add_argument("--experiment", help="a file of conf/experiment/ (without .yaml), instead of --model")
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--batch", type=int, default=32)
    parser.add_argument("--steps", type=int, default=40, help="timed steps per pipeline (after the warm-up)")
    parser.add_argument("--warmup", type=int, default=5)
    parser.add_argument("--threads", type=int, default=2, help="torch intra-op threads of the training process")
    parser.add_argument("--compile", action="store_true", help="torch.compile the training model")
    parser.add_argument("--pipelines", default="jpeg:1,cache:0,cache:0:cl,cache:0:cl:bf16",
                        help="comma-separated PIPELINE:WORKERS[:cl][:bf16][:depth][:resident] (cl: channels_last; "
                             "bf16: autocast; depth: RGB and depth in; resident: one batch kept on the device, the "
                             "ceiling without a loader)")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="a train config override for every item (repeatable)")
    parser.add_argument("--json", help="write each item's figures to this file")
    args = parser.parse_args()

    import torch

    from hupbench.provenance import hardware_description
    from hupbench.training.loop import native_bf16

    torch.set_num_threads(args.threads)
    device = torch.device(args.device)
    print(f"{hardware_description(device)}; torch CPU capability {torch.backends.cpu.get_cpu_capability()}, "
          f"native bf16: {'yes' if native_bf16(device) else 'no (bf16 autocast is emulated)'}")
    print(f"{args.experiment or args.model}, batch {args.batch}, {args.steps} timed steps after {args.warmup}, "
          f"{args.device}{', compiled' if args.compile else ''}, torch threads {args.threads}")
    rows = []
    for item in args.pipelines.split(","):
        pipeline, workers, *flags = item.split(":")
        unknown = set(flags) - {"cl", "bf16", "depth", "resident"}
        if unknown:
            raise SystemExit(f"unknown flags {sorted(unknown)} in {item!r}; known: cl, bf16, depth, resident")
        result = measure(args.dataset, pipeline, int(workers), "bf16" if "bf16" in flags else "fp32",
                         "cl" in flags, "depth" in flags, "resident" in flags, args)
        rows.append((item, result))
        print(f"  {item:16s} setup {result['setup_s']:6.1f} s | median step {result['median_img_s']:7.1f} img/s | "
              f"end to end {result['end_to_end_img_s']:7.1f} img/s | waiting for data {100 * result['wait_share']:5.1f} %",
              flush=True)
    if len(rows) > 1:
        base = rows[0][1]["end_to_end_img_s"]
        for item, result in rows[1:]:
            print(f"  {item} / {rows[0][0]}: {result['end_to_end_img_s'] / base:.2f}x end to end")
    if args.json:
        Path(args.json).write_text(json.dumps({item: result for item, result in rows}, indent=1) + "\n")


if __name__ == "__main__":
    main()
