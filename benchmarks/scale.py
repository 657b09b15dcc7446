"""Scaling on one machine: dataset generation on 1 and 2 Ray workers; training with 1 and 2 processes.

generation: renders the same small dataset (one grasp, 1 glove, ``--backgrounds`` chunks of one
view sphere each) with ``hupbench generate``'s launchers: Ray with 1 and 2 actors on one private
Ray runtime, and the local launcher for reference. Prints, per run, frames/s end to end (including
actor start-up) and after start-up (from the moment every worker has finished its first chunk to
the last chunk, read from the written files' times), the 2-worker / 1-worker ratios, and whether
the runs wrote byte-identical annotations.

training: trains the same model with the same global batch on 1 process (all threads) and on 2
torchrun processes (DDP over gloo, the threads shared out), and prints training images/s from each
run's metrics.jsonl after the warm-up steps, and the 2-process / 1-process ratio.

Usage:
    python benchmarks/scale.py generation [--backgrounds 4] [--size 256] [--r-circ-m 0.15]
                                          [--ray-workers 1 2] [--local-workers 2] [--grasps GRASPS_NPZ]
    python benchmarks/scale.py training [--dataset hupbench_out/dataset] [--model hopenet_r10_128]
                                        [--batch 32] [--steps 40] [--threads 2] [--processes 1 2]
"""

from __future__ import annotations

import argparse
import logging
import tempfile
import time
from pathlib import Path

import numpy as np

# ----------------------------------------------------------------------------- generation


def _one_grasp(path: Path, grasps: str | None) -> Path:
    """The first grasp of a grasps file, or the hand-set preview grasp, as a one-grasp grasps.npz."""
    from hupbench.core.io import save_npz
    from hupbench.datagen.render.preview import handset_grasp

    if grasps is None:
        g = handset_grasp()
        arrays = {"hand_pose": g.hand_pose[None], "hand_trans": g.hand_trans[None],
                  "grasp_id": np.zeros(1, dtype=np.int64)}
    else:
        with np.load(grasps) as data:
            arrays = {k: data[k][:1] for k in ("hand_pose", "hand_trans", "grasp_id")}
    return save_npz(path, arrays)


def _rate_after_start_up(out: Path, chunk_size: int, workers: int) -> float | None:
    """Frames/s from the time every worker had finished one chunk to the last chunk.

    A chunk is finished when the last of its files is written (file modification times), so
    the rate leaves out process start-up, renderer set-up and the first mesh build of every
    worker. None when there are fewer than two rounds of chunks.
    """
    done: dict[int, int] = {}
    for path in out.glob("*/*/*.*"):
        chunk = int(path.stem) // chunk_size
        done[chunk] = max(done.get(chunk, 0), path.stat().st_mtime_ns)
    times = sorted(done.values())
    if len(times) < 2 * workers:
        return None
    return (len(times) - workers) * chunk_size / ((times[-1] - times[workers - 1]) * 1e-9)


def generation(args: argparse.Namespace) -> None:
    import ray

    from hupbench.datagen.dataset.spec import DatasetSpec
    from hupbench.datagen.dataset.writer import GenerateRun, generate
    from hupbench.datagen.dataset.ray_launcher import RayOptions
    from hupbench.datagen.dataset.sphere import SphereSpec

    scale = args.size / 256
    spec = DatasetSpec(splits={"train": 1, "val": 0, "test": 0}, z_ego_m=(0.5,), n_backgrounds=args.backgrounds,
                       n_gloves=1, sphere=SphereSpec(r_circ_m=args.r_circ_m), width=args.size, height=args.size,
                       fx=480.0 * scale, fy=480.0 * scale, cx=128.0 * scale, cy=128.0 * scale)
    runs = [("ray", n) for n in args.ray_workers] + [("local", n) for n in args.local_workers]
    with tempfile.TemporaryDirectory() as tmp:
        grasps = _one_grasp(Path(tmp) / "one_grasp.npz", args.grasps)
        start = time.perf_counter()
        ray.init(address="local", num_cpus=max(args.ray_workers), include_dashboard=False,
                 logging_level=logging.ERROR, log_to_driver=False)
        print(f"ray start-up: {time.perf_counter() - start:.1f} s (private runtime, {max(args.ray_workers)} CPUs; "
              "not counted below)", flush=True)
        rows, annotations = [], {}
        try:
            for launcher, workers in runs:
                out = Path(tmp) / f"{launcher}{workers}"
                start = time.perf_counter()
                run = GenerateRun(spec, out, grasps, progress=False, workers=workers, launcher=launcher,
                                  ray=RayOptions(num_workers=workers))
                result = generate(run, {"benchmark": "scale"}, log=lambda *_: None)
                wall = time.perf_counter() - start
                chunk_size = result["frames_total"] // args.backgrounds
                steady = _rate_after_start_up(out, chunk_size, workers)
                rows.append((launcher, workers, result["frames_rendered"], wall, result["frames_rendered"] / wall,
                             steady))
                annotations[(launcher, workers)] = (out / "train" / "annotations.npz").read_bytes()
                if (launcher, workers) == runs[0]:
                    print(f"dataset: 1 grasp x {args.backgrounds} backgrounds x 1 glove x {chunk_size} views = "
                          f"{result['frames_total']} frames at {args.size} px, {args.backgrounds} chunks of "
                          f"{chunk_size}", flush=True)
                print(f"{launcher:6s} {workers} worker(s): {result['frames_rendered']} frames in {wall:6.1f} s = "
                      f"{rows[-1][4]:6.2f} frames/s end to end, "
                      + (f"{steady:6.2f} frames/s after start-up" if steady else "after start-up: too few chunks"),
                      flush=True)
        finally:
            ray.shutdown()
    by = {(r[0], r[1]): r for r in rows}
    if ("ray", 1) in by and ("ray", 2) in by:
        one, two = by[("ray", 1)], by[("ray", 2)]
        steady = f"{two[5] / one[5]:.2f}" if one[5] and two[5] else "n/a"
        print(f"ratio ray 2 workers / 1 worker: {two[4] / one[4]:.2f} end to end, {steady} after start-up")
    same = len(set(annotations.values())) == 1
    print(f"annotations byte-identical across all {len(annotations)} runs: {'yes' if same else 'NO'}")


def add_generation_args(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--backgrounds", type=int, default=4, help="chunks (one view sphere each)")
    parser.add_argument("--size", type=int, default=256, help="image side, pixels (intrinsics scale with it)")
    parser.add_argument("--r-circ-m", type=float, default=0.15, help="0.15: 90 views per chunk; 0.4: 10")
    parser.add_argument("--ray-workers", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--local-workers", type=int, nargs="*", default=[2])
    parser.add_argument("--grasps", default=None, help="grasps.npz (its first grasp); default: the hand-set grasp")
    parser.set_defaults(run=generation)


# ----------------------------------------------------------------------------- training


def _training_rate(run_dir: Path, warmup_steps: int) -> float:
    """Images/s between the first logged step after warm-up and the last one (training time only)."""
    import json

    lines = [json.loads(line) for line in (run_dir / "metrics.jsonl").read_text().splitlines()]
    steps = [r for r in lines if r["event"] == "train" and r["step"] >= warmup_steps]
    first, last = steps[0], steps[-1]
    return (last["samples_seen"] - first["samples_seen"]) / (last["train_wall_s"] - first["train_wall_s"])


def training(args: argparse.Namespace) -> None:
    import subprocess
    import sys

    repo = Path(__file__).resolve().parents[1]
    rates = {}
    print(f"training {args.model} on {args.dataset}: global batch {args.batch}, {args.steps} steps, "
          f"{args.threads} threads in all")
    for n in args.processes:
        if args.batch % n or args.threads % n:
            raise SystemExit(f"--batch {args.batch} and --threads {args.threads} must divide by {n} processes")
        with tempfile.TemporaryDirectory() as tmp:
            run_dir = Path(tmp) / "run"
            overrides = [f"model={args.model}", f"data.root={Path(args.dataset).resolve()}", f"run_dir={run_dir}",
                         f"data.batch_size={args.batch // n}", f"threads={args.threads // n}",
                         f"train.max_steps={args.steps}", "train.log_every=5", f"train.val_every={10 * args.steps}",
                         f"train.ckpt_every={10 * args.steps}", "train.bn_recompute_frames=0", "data.val_frames=8",
                         "train.progress=false", "train.tensorboard=false"]
            launcher = [sys.executable] if n == 1 else [sys.executable, "-m", "torch.distributed.run", "--standalone",
                                                        "--nproc-per-node", str(n)]
            start = time.perf_counter()
            done = subprocess.run([*launcher, str(repo / "train.py"), *overrides], capture_output=True, text=True,
                                  cwd=tmp, env={**__import__("os").environ, "OMP_NUM_THREADS": str(args.threads // n)})
            if done.returncode != 0:
                raise SystemExit(f"{n}-process run failed:\n{done.stderr[-3000:]}")
            rates[n] = _training_rate(run_dir, warmup_steps=min(10, args.steps // 2))
            print(f"  {n} process(es) x {args.threads // n} thread(s), batch {args.batch // n} each: "
                  f"{rates[n]:6.1f} img/s ({time.perf_counter() - start:.0f} s wall incl. start-up)", flush=True)
    if 1 in rates:
        for n, rate in rates.items():
            if n != 1:
                print(f"  ratio {n} processes / 1 process: {rate / rates[1]:.2f}")


def add_training_args(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--dataset", default="hupbench_out/dataset", help="a finished dataset (train and val splits)")
    parser.add_argument("--model", default="hopenet_r10_128", help="a conf/model/ name")
    parser.add_argument("--batch", type=int, default=32, help="global batch, split over the processes")
    parser.add_argument("--steps", type=int, default=40)
    parser.add_argument("--threads", type=int, default=2, help="torch threads in all, split over the processes")
    parser.add_argument("--processes", type=int, nargs="+", default=[1, 2])
    parser.set_defaults(run=training)


# ----------------------------------------------------------------------------- entry point


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sections = parser.add_subparsers(dest="section", required=True)
    add_generation_args(sections.add_parser("generation", help="frames/s with 1 and 2 Ray workers"))
    add_training_args(sections.add_parser("training", help="training images/s with 1 and 2 torchrun processes"))
    args = parser.parse_args()
    args.run(args)


if __name__ == "__main__":
    main()
