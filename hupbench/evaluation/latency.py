"""What a model costs: parameters, FLOPs per image, and the latency per image of PyTorch and onnxruntime.

Latency is the median wall time per image over timed runs at batch 1 and 32 (:data:`LATENCY_RUNS`) after a warm-up,
on frames of the evaluated split (:data:`LATENCY_FRAMES` spread over it, taken in turn), the fits after the network
included where the model asks for them (they are part of its run time, and on real frames they find what they fit:
on random images a fit finds too few points and skips its work); docs/metrics.md defines the figures.
"""

from __future__ import annotations

import errno
import itertools
import statistics
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch

from hupbench.evaluation.prediction import EvalModel, onnx_network_output
from hupbench.inference.runtime import load_onnx_model

__all__ = ["LATENCY_FRAMES", "LATENCY_RUNS", "count_flops", "measure_latency_ms", "measured_latency", "model_cost"]

#: (least warm-up runs, timed runs) per batch size for the latency medians
LATENCY_RUNS = {1: (3, 15), 32: (1, 5)}
#: frames of the evaluated split the latency runs on
LATENCY_FRAMES = 32
#: warm-up also lasts at least this long (s): oneDNN and onnxruntime set up kernels lazily, and on
#: a busy machine the first calls can be many times slower than the steady state
WARMUP_MIN_S = 0.5
#: at most this many warm-up runs, however long they take
WARMUP_MAX_RUNS = 50


def count_flops(module: torch.nn.Module, input_size: int, channels: int = 3) -> int:
    """FLOPs of one forward pass on one (1, C, S, S) model image (2 x multiply-adds, as FlopCounterMode counts)."""
    from torch.utils.flop_counter import FlopCounterMode

    counter = FlopCounterMode(display=False)
    with torch.inference_mode(), counter:
        module(torch.zeros(1, channels, input_size, input_size))
    return int(counter.get_total_flops())


def model_cost(net: EvalModel) -> tuple[int, int]:
    """(parameters, FLOPs per image) of a model's architecture, rebuilt from its config for an ONNX model."""
    from hupbench.inference.export import ContractModule
    from hupbench.models.build import build_model

    module = net.module
    if module is None:
        module = ContractModule(build_model(net.model_config).eval(), net.K_input, net.input_size).eval()
    parameters = sum(p.numel() for p in module.model.parameters())
    return int(parameters), count_flops(module, net.input_size, net.channels)


def measure_latency_ms(run: Callable[[np.ndarray], Any], input_size: int, batch: int,
                       warmup: int, repeats: int, channels: int = 3, frames: np.ndarray | None = None) -> float:
    """Median wall time per image of ``run`` on (batch, C, S, S) float32 arrays of model images, milliseconds.

    The images: ``frames`` (F, C, S, S), each run the next ``batch`` of them in turn (wrapping around); None: random
    ones. Warm-up: at least ``warmup`` runs and ``WARMUP_MIN_S`` seconds (at most ``WARMUP_MAX_RUNS`` runs);
    then the median of ``repeats`` timed runs, divided by ``batch``.
    """
    if frames is None:
        frames = np.random.default_rng(0).random((batch, channels, input_size, input_size), dtype=np.float32)
    frames = np.ascontiguousarray(frames, dtype=np.float32)
    turns = itertools.count()

    def images() -> np.ndarray:
        first = next(turns) * batch
        return np.take(frames, np.arange(first, first + batch), axis=0, mode="wrap")

    start, runs = time.perf_counter(), 0
    while runs < warmup or (time.perf_counter() - start < WARMUP_MIN_S and runs < WARMUP_MAX_RUNS):
        run(images())
        runs += 1
    times = []
    for _ in range(repeats):
        batch_images = images()
        start = time.perf_counter()
        run(batch_images)
        times.append(time.perf_counter() - start)
    return statistics.median(times) * 1000.0 / batch


def _latencies(net: EvalModel, onnx_path: Path, log, progress: bool, export: Callable[[], object] | None = None,
               frames: np.ndarray | None = None) -> dict[str, dict[str, float | None]]:
    """Latency medians of both runtimes (PyTorch only for a checkpoint, at torch's thread count); ``export()``, when
    given, first writes ``onnx_path`` (a stage of the progress bar: the exporter takes as long as the timings). The
    fits the model asks for run after the network inside the timing."""
    from tqdm import tqdm

    after = net.after_network if net.fits else None
    size, channels = net.input_size, net.channels
    out = {"pytorch": {"batch1": None, "batch32": None}, "onnxruntime": {"batch1": None, "batch32": None}}
    runtimes = (["pytorch"] if net.module is not None else []) + ["onnxruntime"]
    with tqdm(total=len(runtimes) * len(LATENCY_RUNS) + (export is not None), unit="step", desc="latency",
              dynamic_ncols=True, leave=False, disable=None if progress else True) as bar:
        if export is not None:
            bar.set_postfix_str("ONNX export for onnxruntime")
            export()
            bar.update(1)
        if net.module is not None:
            def run_torch(images):
                outputs = net.network(torch.from_numpy(images))
                if after is not None:
                    after(images, outputs)
            for batch, (warmup, repeats) in LATENCY_RUNS.items():
                bar.set_postfix_str(f"PyTorch batch {batch}")
                out["pytorch"][f"batch{batch}"] = measure_latency_ms(run_torch, size, batch, warmup, repeats, channels,
                                                                     frames)
                bar.update(1)
        onnx_model = load_onnx_model(onnx_path, torch.get_num_threads())

        def run_onnx_and_after(images):
            outputs = onnx_network_output(onnx_model, images)
            if after is not None:
                after(images, outputs)
        for batch, (warmup, repeats) in LATENCY_RUNS.items():
            bar.set_postfix_str(f"onnxruntime batch {batch}")
            out["onnxruntime"][f"batch{batch}"] = measure_latency_ms(run_onnx_and_after, size, batch, warmup, repeats,
                                                                     channels, frames)
            bar.update(1)
    log("latency (ms/image): " + ", ".join(f"{rt} b{b[5:]} {v:.2f}" for rt, d in out.items()
                                           for b, v in d.items() if v is not None))
    return out


def measured_latency(net: EvalModel, out_path: Path, run_name: str, log, progress: bool,
                     frames: np.ndarray | None = None) -> dict:
    """Latency per image, ms, of PyTorch and onnxruntime at batch 1 and 32 (an ONNX model: onnxruntime only) on
    ``frames`` (F, C, S, S) model images of the evaluated split (None: random images): ``{runtime: {"batch1",
    "batch32"}}``. A checkpoint is exported for onnxruntime beside ``out_path`` under a temporary name, removed
    afterwards; ``run_name`` goes into its metadata."""
    from hupbench.core.io import DiskFullError, tmp_path
    from hupbench.provenance import git_commit

    if net.format == "onnx":
        return _latencies(net, net.path, log, progress, frames=frames)
    from hupbench.inference.export import export_onnx, onnx_metadata

    # the timed ONNX file lives beside the results under a temporary name (``.NAME.tmpPID.onnx``), not in
    # a folder of the system's: a killed eval leaves it where the next one removes it
    onnx_path = tmp_path(out_path, ".onnx")
    out_path.parent.mkdir(parents=True, exist_ok=True)

    def export():
        try:
            export_onnx(net.module, onnx_path, onnx_metadata(net.payload, run_name, git_commit(), net.module.outputs))
        except OSError as exc:
            raise (DiskFullError(onnx_path) if exc.errno == errno.ENOSPC else exc) from exc

    try:
        return _latencies(net, onnx_path, log, progress, export, frames)
    finally:
        onnx_path.unlink(missing_ok=True)
