"""A model's latency per stage at batch 1 and 32: the network (PyTorch, onnxruntime), the probe's fit and the hand's
fit after it, the whole of each runtime, and ``hupbench predict`` end to end, on real frames of a dataset.

Each stage is timed on the same frames (the split's first ``--frames``, read at the model's input as eval reads
them) with eval's warm-up and medians (:func:`hupbench.evaluation.latency.measure_latency_ms`); a fit is timed on the
output of the stage before it. ``predict`` is timed over the frames' image and depth files, the model file's load
included, per image. eval's own latency runs on random images, where a fit finds no hand; these are the figures of
frames it does find. Prints the CPU with the figures.

Usage: python benchmarks/latency.py CHECKPOINT DATASET [--split val] [--frames 32] [--threads 2]
"""

from __future__ import annotations

import argparse
import platform
import tempfile
import time
from pathlib import Path

import numpy as np


def cpu_name() -> str:
    """The CPU's model name (``/proc/cpuinfo``) and torch's CPU capability."""
    import torch

    name = platform.processor() or "unknown CPU"
    try:
        name = next(line.split(":", 1)[1].strip() for line in Path("/proc/cpuinfo").read_text().splitlines()
                    if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    return f"{name}, torch CPU capability {torch.backends.cpu.get_cpu_capability()}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoint", type=Path, help="a model that fits (e.g. the recommended one's last.pt)")
    parser.add_argument("dataset", type=Path, help="a finished dataset folder")
    parser.add_argument("--split", default="val", choices=("train", "val", "test"))
    parser.add_argument("--frames", type=int, default=32, help="frames timed (batch 32 needs at least 32)")
    parser.add_argument("--threads", type=int, default=2, help="torch and onnxruntime threads")
    args = parser.parse_args()
    if args.frames < 1 or args.threads < 1:
        parser.error("--frames and --threads must be positive")

    import torch

    from hupbench.evaluation.latency import LATENCY_RUNS, measure_latency_ms
    from hupbench.evaluation.prediction import EvalModel, split_reader
    from hupbench.fits import fits
    from hupbench.fits.hand_fit import fit_hand
    from hupbench.fits.probe_fit import fit_probe
    from hupbench.inference.export import ExportOptions, run_export
    from hupbench.inference.predict import PredictOptions, run_predict
    from hupbench.inference.runtime import load_onnx_model, run_onnx, split_model_images

    torch.set_num_threads(args.threads)
    net = EvalModel(args.checkpoint)
    asked = fits(net.model_config)
    reader = split_reader(args.dataset, args.split, net)
    count = min(args.frames, len(reader))
    frames = np.stack([reader[i]["image"].numpy() for i in range(count)])
    K = net.K_input
    print(f"{args.checkpoint} on {count} {args.split} frames of {args.dataset}, input {net.input_size} px "
          f"{net.input_modalities}, fits: {', '.join(asked) or 'none'}; {args.threads} threads; {cpu_name()}")

    with tempfile.TemporaryDirectory() as folder:
        onnx_path = Path(folder) / "model.onnx"
        run_export(ExportOptions(args.checkpoint, onnx_path, dataset=args.dataset, parity_frames=2),
                   log=lambda *_: None)
        onnx = load_onnx_model(onnx_path, args.threads)
        stages = {
            "network, PyTorch": lambda x: net.network(torch.from_numpy(x)),
            "network, onnxruntime": lambda x: run_onnx(onnx, *split_model_images(x)),
        }
        outputs = {b: net.network(torch.from_numpy(frames[:b])) for b in LATENCY_RUNS}
        if "probe" in asked:
            stages["probe fit"] = lambda x: fit_probe(*outputs[len(x)], x, K)
            outputs = {b: fit_probe(*o, frames[:b], K)[:2] for b, o in outputs.items()}
        if "hand" in asked:
            stages["hand fit"] = lambda x: fit_hand(*outputs[len(x)], x, K)
        stages["PyTorch end to end (eval)"] = lambda x: net.predict(torch.from_numpy(x))
        stages["onnxruntime end to end"] = lambda x: net.after_network(x, run_onnx(onnx, *split_model_images(x)))
        width = max(map(len, stages)) + 2
        print(f"{'stage':{width}s}" + "".join(f"{f'batch {b}':>14s}" for b in LATENCY_RUNS) + "   (ms per image)")
        for name, run in stages.items():
            row = [measure_latency_ms(run, net.input_size, b, *LATENCY_RUNS[b], net.channels, frames[:b])
                   if b <= count else None for b in LATENCY_RUNS]
            print(f"{name:{width}s}" + "".join(f"{v:14.2f}" if v is not None else f"{'-':>14s}" for v in row),
                  flush=True)

        rgb = [reader.path(i, "rgb") for i in range(count)]
        depth = reader.path(0, "depth").parent if net.input_modalities == "rgb+depth" else None
        row = []
        for b in LATENCY_RUNS:
            start = time.perf_counter()
            run_predict(PredictOptions(onnx_path, tuple(rgb), Path(folder) / f"predict{b}", overlay=False,
                                       batch_size=b, depth_dir=depth), log=lambda *_: None)
            row.append((time.perf_counter() - start) * 1000.0 / count)
        print(f"{'hupbench predict, files':{width}s}" + "".join(f"{v:14.2f}" for v in row)
              + f"   ({count} images, decoding and the model file's load included)")


if __name__ == "__main__":
    main()
