"""A model's latency per stage at batch 1 and 32: the network (PyTorch, onnxruntime), the probe's fit and the hand's
fit after it, the whole of each runtime, and ``hupbench predict`` end to end, on real frames of a dataset; and, on
a dataset of clips, tracking them at batch 1: the fits started where they left the frame before
(:func:`hupbench.fits.track_fits`), onnxruntime with them and the 1-euro filter, and ``hupbench predict --track --fps``.

Each stage is timed on the same frames (the split's first ``--frames``, read at the model's input as eval reads
them), batch by batch over all of them, ``--repeats`` times after one warm-up round: the median time of a batch per
image (a fit's time depends on the frame: how many of its pixels it reads). A fit is timed on the output of the
stage before it. ``predict`` is timed over the frames' image and depth files, per image with the model file's load
and per image after it (less a run on one file: a stream's rate once loaded). eval's own latency runs the whole model on 32 frames spread over the split; this splits it by stage. The
tracked rows run the frames in order (the split's first frames: its first clips', in order), each started at the
frame before and afresh at each clip's first frame: the median frame. Prints the CPU with the figures.

Usage: python benchmarks/latency.py CHECKPOINT DATASET [--split val] [--frames 32] [--repeats 3] [--threads 2]
"""

from __future__ import annotations

import argparse
import platform
import statistics
import tempfile
import time
from collections.abc import Callable
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


def per_image_ms(run: Callable[[np.ndarray], object], frames: np.ndarray, batch: int, repeats: int) -> float | None:
    """The median over ``repeats`` rounds and the batches of ``frames`` (B, C, S, S) of ``run``'s time on a batch of
    ``batch`` frames, per image, ms; one untimed round first. None when there are fewer frames than ``batch``."""
    batches = [frames[i:i + batch] for i in range(0, len(frames) - batch + 1, batch)]
    if not batches:
        return None
    for images in batches:
        run(images)
    times = []
    for _ in range(repeats):
        for images in batches:
            start = time.perf_counter()
            run(images)
            times.append((time.perf_counter() - start) * 1000.0 / batch)
    return statistics.median(times)


def tracked_ms(run: Callable[[np.ndarray, object], object], frames: np.ndarray, firsts: np.ndarray,
               repeats: int) -> float:
    """The median time of ``run(frame (1, C, S, S), state) -> state`` over ``frames`` in order, the state carried from
    frame to frame and None at each clip's first frame (``firsts`` (F,) bool), over ``repeats`` rounds (one untimed
    round first), ms per frame."""
    times = []
    for round_ in range(repeats + 1):
        state = None
        for i in range(len(frames)):
            if firsts[i]:
                state = None
            start = time.perf_counter()
            state = run(frames[i:i + 1], state)
            if round_:
                times.append((time.perf_counter() - start) * 1000.0)
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoint", type=Path, help="a model that fits (e.g. the recommended one's last.pt)")
    parser.add_argument("dataset", type=Path, help="a finished dataset folder")
    parser.add_argument("--split", default="val", choices=("train", "val", "test"))
    parser.add_argument("--frames", type=int, default=32, help="frames timed (batch 32 needs at least 32)")
    parser.add_argument("--repeats", type=int, default=3, help="timed rounds over the frames")
    parser.add_argument("--threads", type=int, default=2, help="torch and onnxruntime threads")
    args = parser.parse_args()
    if min(args.frames, args.repeats, args.threads) < 1:
        parser.error("--frames, --repeats and --threads must be positive")

    import torch

    from hupbench.evaluation.latency import LATENCY_RUNS
    from hupbench.core.contract import SEGMENT_CLASSES, is_sequence, read_annotations
    from hupbench.evaluation.prediction import EvalModel, onnx_network_output, split_reader
    from hupbench.fits import fits
    from hupbench.fits.hand_fit import fit_hand
    from hupbench.fits.probe_fit import fit_probe
    from hupbench.inference.export import ExportOptions, run_export
    from hupbench.inference.tracking import OneEuroFilter
    from hupbench.inference.predict import PredictOptions, run_predict
    from hupbench.inference.runtime import load_onnx_model

    torch.set_num_threads(args.threads)
    net = EvalModel(args.checkpoint)
    asked = fits(net.model_config)
    reader = split_reader(args.dataset, args.split, net)
    count = min(args.frames, len(reader))
    frames = np.stack([reader[i]["image"].numpy() for i in range(count)])
    K, probe, (probe_settings, hand_settings) = net.K_input, net.fit_probe, net.fit_settings
    print(f"{args.checkpoint} on {count} {args.split} frames of {args.dataset}, input {net.input_size} px "
          f"{net.input_modalities}, fits: {', '.join(asked) or 'none'}; {args.threads} threads; {cpu_name()}")

    with tempfile.TemporaryDirectory() as folder:
        onnx_path = Path(folder) / "model.onnx"
        run_export(ExportOptions(args.checkpoint, onnx_path, dataset=args.dataset, parity_frames=2),
                   log=lambda *_: None)
        onnx = load_onnx_model(onnx_path, args.threads)
        stages = {
            "network, PyTorch": lambda x: net.network(torch.from_numpy(x)),
            "network, onnxruntime": lambda x: onnx_network_output(onnx, x),
        }
        # a fit's input, for a batch of frames (a view of them: its place and length), is the stage before it's
        # output, computed once, in the untimed round
        outputs = {}

        def once(kind: str, x: np.ndarray, compute: Callable[[], tuple]) -> tuple:
            key = (kind, x.__array_interface__["data"][0], len(x))
            if key not in outputs:
                outputs[key] = compute()
            return outputs[key]

        def network(x):
            return once("network", x, lambda: net.network(torch.from_numpy(x)))

        def after_probe(x):
            return once("probe", x, lambda: fit_probe(*network(x)[:2], x, K, probe_settings, probe, own(x, "probe"))[:2]
                        ) if "probe" in asked else network(x)[:2]

        def own(x, part: str):
            segmentation = network(x).segmentation
            return None if segmentation is None else segmentation == SEGMENT_CLASSES.index(part)

        if "probe" in asked:
            stages["probe fit"] = lambda x: fit_probe(*network(x)[:2], x, K, probe_settings, probe, own(x, "probe"))
        if "hand" in asked:
            stages["hand fit"] = lambda x: fit_hand(*after_probe(x), x, K, hand_settings, probe, own(x, "hand"),
                                                    net.model_config.get("hand_templates"))
        stages["PyTorch end to end (eval)"] = lambda x: net.predict(torch.from_numpy(x))
        stages["onnxruntime end to end"] = lambda x: net.after_network(x, onnx_network_output(onnx, x))
        width = max(map(len, stages)) + 2
        print(f"{'stage':{width}s}" + "".join(f"{f'batch {b}':>14s}" for b in LATENCY_RUNS) + "   (ms per image)")
        for name, run in stages.items():
            row = [per_image_ms(run, frames, b, args.repeats) for b in LATENCY_RUNS]
            print(f"{name:{width}s}" + "".join(f"{v:14.2f}" if v is not None else f"{'-':>14s}" for v in row),
                  flush=True)

        rgb = [reader.path(i, "rgb") for i in range(count)]
        # the depth files the model images read: a sensor's stored maps, else the clean ones
        kind = reader.depth_files[0] if len(reader.depth_files) == 1 else "depth"
        depth = reader.path(0, kind).parent if net.input_modalities == "rgb+depth" else None

        def predict_rows(name: str, **track) -> None:
            """``hupbench predict`` over the files at each batch size: per image with the model file's load, and
            per image after it (the run on all the files less a run on the first file alone, over the rest: the
            rate of a stream once the model is loaded)."""
            def seconds(files: list, b: int) -> float:
                start = time.perf_counter()
                run_predict(PredictOptions(onnx_path, tuple(files), Path(folder) / f"{name}{b}_{len(files)}",
                                           overlay=False, batch_size=b, depth_dir=depth, **track), log=lambda *_: None)
                return time.perf_counter() - start

            seconds(rgb[:1], 1)  # the process's first loads (imports, onnxruntime's start), untimed
            first = seconds(rgb[:1], 1)
            whole = [seconds(rgb, b) for b in LATENCY_RUNS]
            print(f"{'hupbench predict' + name + ', files':{width}s}" + "".join(f"{1e3 * t / count:14.2f}" for t in whole)
                  + f"   ({count} images; decoding and the model file's load ({1e3 * first:.0f} ms with one image) "
                  "included)")
            print(f"{'  the same, after the load':{width}s}"
                  + "".join(f"{1e3 * (t - first) / (count - 1):14.2f}" for t in whole), flush=True)

        predict_rows("")
        if not is_sequence(reader.manifest):
            return
        of_clip = np.asarray(read_annotations(args.dataset, args.split, ("clip_id",), reader.manifest)["clip_id"]
                             )[:count]
        firsts = np.r_[True, of_clip[1:] != of_clip[:-1]]
        clips = np.unique(of_clip)
        print(f"tracked, frame by frame in order ({count} frames of clip{'s' if len(clips) > 1 else ''} "
              f"{', '.join(str(int(c)) for c in clips)}, each started afresh; batch 1 only):")
        if asked:
            row = tracked_ms(lambda x, start: net.track_fits(x, network(x), start)[2], frames, firsts, args.repeats)
            print(f"{'tracked fits':{width}s}{row:14.2f}")
        smoother = OneEuroFilter(min_cutoff_hz=1.0, beta=3.0)

        def tracked(x, start):
            out = onnx_network_output(onnx, x)
            _, points3d, start = net.track_fits(x, out, start) if asked else (*out[:2], None)
            smoother(points3d[0], time.perf_counter())
            return start

        print(f"{'onnxruntime tracked end to end':{width}s}{tracked_ms(tracked, frames, firsts, args.repeats):14.2f}"
              "   (network, tracked fits, 1-euro filter)")
        predict_rows(" --track", track="1,3", fps=30.0)


if __name__ == "__main__":
    main()
