"""``hupbench eval MODEL DATASET``: every benchmark metric of a checkpoint or an exported ONNX model.

The model runs over one split (``hupbench.data.HUPDataset`` at its input size, batched), the metrics of
:mod:`hupbench.metrics` are computed on all frames, and a results JSON (:mod:`hupbench.evaluation.results`)
is written. A checkpoint runs through :class:`hupbench.inference.export.ContractModule`, the wrapper the
ONNX export uses, so both formats report the same quantities; docs/metrics.md defines each number.
"""

from __future__ import annotations

import copy
import errno
import json
import statistics
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from hupbench.core import keypoints as kp
from hupbench.core.contract import TRACKS
from hupbench.core.errors import BadValueError, MissingFileError, RunFailedError
from hupbench.core.input_checks import check_int
from hupbench.core.probe_symmetry import probe_symmetry_group
from hupbench import metrics
from hupbench.evaluation import breakdowns
from hupbench.evaluation.probe_pose import dataset_probe, floor_probe_pose, logged_probe_pose, probe_pose_rows
from hupbench.evaluation.results import FLOOR_NAMES, validate_grasp_theta_vol, validate_split_floor
from hupbench.inference.model_file import after_network, fits
from hupbench.inference.runtime import load_onnx_model, run_onnx, split_model_images
from hupbench.input_geometry import INPUT_MODALITIES

__all__ = ["LATENCY_RUNS", "EvalOptions", "count_flops", "default_figures_dir", "default_results_path",
           "format_table", "grasp_theta_vol_deg", "measure_latency_ms", "run_eval", "split_floor"]

#: (least warm-up runs, timed runs) per batch size for the latency medians
LATENCY_RUNS = {1: (3, 15), 32: (1, 5)}
#: warm-up also lasts at least this long (s): oneDNN and onnxruntime set up kernels lazily, and on
#: a busy machine the first calls can be many times slower than the steady state
WARMUP_MIN_S = 0.5
#: at most this many warm-up runs, however long they take
WARMUP_MAX_RUNS = 50
#: relative difference between the eval images' intrinsics and the model's K_input above which a warning is logged
K_MISMATCH_REL = 1e-3
MODEL_LABELS = {"hopenet": "HOPE-Net", "hupnet": "HUPNet", "resnet_regressor": "ResNet regressor"}
MODEL_SUFFIXES = (".pt", ".pth", ".onnx")


@dataclass(frozen=True)
class EvalOptions:
    """What ``hupbench eval`` is asked to do, checked once where it enters.

    Attributes:
        model: a hupbench checkpoint (``.pt``) or an ONNX file from ``hupbench export``.
        dataset: a finished dataset folder. split: "train", "val" or "test".
        out: results ``.json`` (default :func:`default_results_path`: beside the model, never on the
            leaderboard); when given, its stem is the run name.
        run_name: default: the checkpoint's training ``run_name`` (or file stem) or the ONNX metadata's.
        batch_size: frames per forward pass. latency: time PyTorch and onnxruntime (batch 1 and 32).
        threads: intra-op threads of PyTorch and onnxruntime during the run (default: torch's current setting).
        training_command, training_log: stored as ``training.command`` (the leaderboard requires one for a
            measured row) and ``training.log`` (metrics.jsonl relative to the leaderboard folder).
        label: the model's name in the results (default: the training config's ``label``, else model,
            backbone and input size).
        progress: progress bars (with ETA) over the model pass and the latency timings, on a terminal.
        figures: also draw prediction beside ground truth (sample and worst frames) and the PCK curve
            (:mod:`hupbench.evaluation.figures`) into ``figures_dir`` (default :func:`default_figures_dir`).
    """

    model: Path
    dataset: Path
    split: str = "test"
    out: Path | None = None
    run_name: str | None = None
    batch_size: int = 32
    latency: bool = True
    threads: int | None = None
    training_command: str | None = None
    training_log: str | None = None
    label: str | None = None
    progress: bool = True
    figures: bool = False
    figures_dir: Path | None = None

    def __post_init__(self) -> None:
        check_int(self.batch_size, "batch_size", low=1)
        check_int(self.threads, "threads", low=1, optional=True)
        model = Path(self.model)
        if model.suffix.lower() not in MODEL_SUFFIXES:
            raise BadValueError(f"unknown model file type {model.name!r}: expected a hupbench checkpoint (.pt) "
                                f"or an exported ONNX model (.onnx)")
        out = None if self.out is None else Path(self.out)
        if out is not None and out.suffix.lower() != ".json":
            raise BadValueError(f"--out must be a .json file, got {out.name!r}")
        if out is not None and self.run_name is not None and self.run_name != out.stem:
            raise BadValueError(f"the run name {self.run_name!r} must equal the results file stem {out.stem!r} "
                                f"(leave out --run-name or rename --out)")
        object.__setattr__(self, "model", model)
        object.__setattr__(self, "dataset", Path(self.dataset))
        object.__setattr__(self, "out", out)
        if self.figures_dir is not None:
            object.__setattr__(self, "figures", True)
            object.__setattr__(self, "figures_dir", Path(self.figures_dir))


def default_results_path(model: Path, split: str) -> Path:
    """Where eval writes without ``--out``: ``<model folder>/eval/<model file name>.<split>.json`` (e.g.
    ``checkpoints/eval/last.pt.test.json``), beside the model and never in the tracked
    ``leaderboard/results/``: a row joins the leaderboard only when ``--out`` names it there."""
    return model.parent / "eval" / f"{model.name}.{split}.json"


def default_figures_dir(model: Path, split: str) -> Path:
    """Where ``--figures`` draws without a folder: ``<model folder>/eval/<model file name>.<split>.figures/``."""
    return model.parent / "eval" / f"{model.name}.{split}.figures"


def model_label(model_config: dict, input_size: int) -> str:
    """Human label naming the model, backbone, input size, a depth input and HUPNet's heads, e.g. "HOPE-Net
    (ResNet-18, 128 px)", "HUPNet (ResNet-18, 128 px, RGB-D, depth-anchored, rigid probe)", "HUPNet (ResNet-18,
    128 px, RGB-D, depth-anchored, stride-4 heatmaps, probe fitted to depth)"."""
    name = MODEL_LABELS.get(model_config.get("name"), str(model_config.get("name")))
    backbone = model_config.get("backbone") or ""
    if backbone.startswith("resnet"):
        backbone = f"ResNet-{backbone[len('resnet'):]}"
    parts = ([backbone] if backbone else []) + [f"{input_size} px"]
    if model_config.get("name") == "resnet_regressor" and model_config.get("predict_2d"):
        parts.append("2D head")
    if model_config.get("backbone_size") and model_config["backbone_size"] != input_size:
        parts.append(f"backbone at {model_config['backbone_size']} px")
    if model_config.get("input_channels", 3) == INPUT_MODALITIES["rgb+depth"]:
        parts.append("RGB-D")
    if model_config.get("depth_anchor"):
        parts.append("depth-anchored")
    if model_config.get("heatmap_stride", 8) != 8:
        parts.append(f"stride-{model_config['heatmap_stride']} heatmaps")
    if model_config.get("probe_head") == "rigid":
        parts.append("rigid probe" + (f", {model_config['probe_crop_px']} px probe crop"
                                      if model_config.get("probe_crop_px") else ""))
    parts += [f"{part} fitted to depth" for part in fits(model_config)]
    return f"{name} ({', '.join(parts)})"


def count_flops(module: torch.nn.Module, input_size: int, channels: int = 3) -> int:
    """FLOPs of one forward pass on one (1, C, S, S) model image (2 x multiply-adds, as FlopCounterMode counts)."""
    from torch.utils.flop_counter import FlopCounterMode

    counter = FlopCounterMode(display=False)
    with torch.inference_mode(), counter:
        module(torch.zeros(1, channels, input_size, input_size))
    return int(counter.get_total_flops())


def measure_latency_ms(run: Callable[[np.ndarray], Any], input_size: int, batch: int,
                       warmup: int, repeats: int, channels: int = 3) -> float:
    """Median wall time per image of ``run`` on a (batch, C, S, S) float32 array of model images, milliseconds.

    Warm-up: at least ``warmup`` runs and ``WARMUP_MIN_S`` seconds (at most ``WARMUP_MAX_RUNS`` runs);
    then the median of ``repeats`` timed runs, divided by ``batch``.
    """
    images = np.random.default_rng(0).random((batch, channels, input_size, input_size), dtype=np.float32)
    start, runs = time.perf_counter(), 0
    while runs < warmup or (time.perf_counter() - start < WARMUP_MIN_S and runs < WARMUP_MAX_RUNS):
        run(images)
        runs += 1
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        run(images)
        times.append(time.perf_counter() - start)
    return statistics.median(times) * 1000.0 / batch


def _latencies(torch_module, onnx_path, input_size: int, channels: int, threads: int, log, progress: bool = True,
               export: Callable[[], object] | None = None,
               after: Callable[[np.ndarray, tuple], object] | None = None) -> dict[str, dict[str, float | None]]:
    """Latency medians of both runtimes; ``export()``, when given, first writes ``onnx_path`` (a stage of the
    progress bar: the exporter takes as long as the timings); ``after(images, outputs)``, when given, runs
    after the network inside the timing (the probe's fit)."""
    from tqdm import tqdm

    out = {"pytorch": {"batch1": None, "batch32": None}, "onnxruntime": {"batch1": None, "batch32": None}}
    runtimes = (["pytorch"] if torch_module is not None else []) + ["onnxruntime"]
    with tqdm(total=len(runtimes) * len(LATENCY_RUNS) + (export is not None), unit="step", desc="latency",
              dynamic_ncols=True, leave=False, disable=None if progress else True) as bar:
        if export is not None:
            bar.set_postfix_str("ONNX export for onnxruntime")
            export()
            bar.update(1)
        if torch_module is not None:
            def run_torch(images):
                with torch.inference_mode():
                    points2d, points3d = torch_module(torch.from_numpy(images))
                if after is not None:
                    after(images, (points2d.double().numpy(), points3d.double().numpy()))
            for batch, (warmup, repeats) in LATENCY_RUNS.items():
                bar.set_postfix_str(f"PyTorch batch {batch}")
                out["pytorch"][f"batch{batch}"] = measure_latency_ms(run_torch, input_size, batch, warmup, repeats,
                                                                     channels)
                bar.update(1)
        onnx_model = load_onnx_model(onnx_path, threads)

        def run_onnx_and_after(images):
            outputs = run_onnx(onnx_model, *split_model_images(images))
            if after is not None:
                after(images, outputs)
        for batch, (warmup, repeats) in LATENCY_RUNS.items():
            bar.set_postfix_str(f"onnxruntime batch {batch}")
            out["onnxruntime"][f"batch{batch}"] = measure_latency_ms(
                run_onnx_and_after, input_size, batch, warmup, repeats, channels)
            bar.update(1)
    log("latency (ms/image): " + ", ".join(f"{rt} b{b[5:]} {v:.2f}" for rt, d in out.items()
                                           for b, v in d.items() if v is not None))
    return out


def grasp_theta_vol_deg(manifest: dict, grasp_ids: list[int], where: str) -> dict[str, list[float] | None] | None:
    """{str(grasp id): [x, y, z] degrees or None} of the probe orientation Theta_Vol of exactly the evaluated
    ``grasp_ids``, from the manifest's ``grasp_theta_vol_deg`` (checked; ``where`` is the manifest's path),
    or None where the manifest records none."""
    recorded = manifest.get("grasp_theta_vol_deg")
    if recorded is None:
        return None
    validate_grasp_theta_vol(recorded, f"{where}: manifest['grasp_theta_vol_deg']")
    return {str(g): recorded.get(str(g)) for g in grasp_ids}


def split_floor(manifest: dict, split: str, grasp_ids: list[int], where: str) -> tuple[str | None, dict | None]:
    """(track or None, a checked copy of the split's floor or None) from the manifest's ``protocol.track``
    and ``split_floors["splits"][split]`` (absent in older datasets; the train split has none), whose
    ``per_grasp`` must hold exactly the evaluated ``grasp_ids``; ``where`` is the manifest's path."""
    track = (manifest.get("protocol") or {}).get("track")
    if track is not None and track not in TRACKS:
        raise BadValueError(f"{where}: manifest['protocol']['track'] must be one of {', '.join(TRACKS)}, got {track!r}")
    floors = manifest.get("split_floors")
    if floors is not None:
        if not isinstance(floors, dict) or not isinstance(floors.get("splits"), dict):
            raise BadValueError(f"{where}: manifest['split_floors'] must be a dict with 'definition' and "
                                f"'splits' (split -> floor), got {str(floors)[:80]}")
    entry = None if floors is None else floors["splits"].get(split)
    if entry is None:
        return track, None
    entry_where = f"{where}: manifest['split_floors']['splits'][{split!r}]"
    entry = copy.deepcopy(validate_split_floor(entry, entry_where))
    if set(entry["per_grasp"]) != {str(g) for g in grasp_ids}:
        raise BadValueError(f"{entry_where}['per_grasp'] must hold the split's grasps {sorted(grasp_ids)}, got "
                            f"{sorted(entry['per_grasp'], key=int)}")
    return track, entry


class EvalModel:
    """The model under evaluation, in either format: its name, sizes, a batch predictor, and what to time."""

    def __init__(self, path: Path) -> None:
        from hupbench.checkpoint import load_model
        from hupbench.inference.export import contract_model, default_run_name

        self.path = path
        if path.suffix.lower() == ".onnx":
            self.format, self.payload, self.module = "onnx", None, None
            self.onnx = load_onnx_model(path, torch.get_num_threads())
            if len(self.onnx.keypoint_names) != kp.NUM_KEYPOINTS:
                raise BadValueError(f"{path} predicts {len(self.onnx.keypoint_names)} keypoints; the benchmark has "
                                    f"{kp.NUM_KEYPOINTS}")
            if not self.onnx.model_config:  # eval rebuilds the architecture to count its parameters and FLOPs
                raise BadValueError(f"{path} lacks metadata hupbench.model_config, which eval needs for the model's "
                                    "cost")
            self.model_config, self.input_size = self.onnx.model_config, self.onnx.input_size
            self.input_modalities = self.onnx.input_modalities
            self.K_input, self.run_name = self.onnx.K_input, self.onnx.run_name or path.stem
            return
        model, payload = load_model(path)
        self.format, self.payload, self.onnx = "pytorch", payload, None
        self.module = contract_model(model, payload, str(path))
        self.model_config = dict(payload["model_config"])
        self.input_size = self.module.input_size
        self.input_modalities = self.module.input_modalities
        self.K_input = np.asarray(payload["K_input"], dtype=np.float64)
        self.run_name = default_run_name(path, payload)

    @property
    def fits(self) -> bool:
        """Whether the model's config asks for a fit after the network (:func:`hupbench.inference.model_file.fits`)."""
        return bool(fits(self.model_config))

    def after_network(self, images: np.ndarray, outputs: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        """What runs on the network's (points2d, points3d) float64 outputs for (B, C, S, S) model images: the fits
        to the depth input the model asks for, else nothing."""
        return after_network(self.model_config, *outputs, images, self.K_input)

    def predict(self, images: torch.Tensor) -> tuple[np.ndarray, np.ndarray]:
        """(B, C, S, S) model images -> points2d (B, 29, 2) normalised, points3d (B, 29, 3) metres, float64 numpy:
        the network's output, and the fits to the depth input after it where the model asks for them."""
        if self.module is not None:
            with torch.inference_mode():
                points2d, points3d = self.module(images)
            points2d, points3d = points2d.double().numpy(), points3d.double().numpy()
        else:
            points2d, points3d = run_onnx(self.onnx, *split_model_images(images.numpy()))
            points2d, points3d = points2d.astype(np.float64), points3d.astype(np.float64)
        return self.after_network(images.numpy(), (points2d, points3d))

    def cost(self) -> tuple[int, int]:
        """(parameters, FLOPs per image) of the architecture, rebuilt from its config when needed."""
        from hupbench.inference.export import ContractModule
        from hupbench.models.build import build_model

        module = self.module
        if module is None:
            module = ContractModule(build_model(self.model_config).eval(), self.K_input, self.input_size).eval()
        parameters = sum(p.numel() for p in module.model.parameters())
        return int(parameters), count_flops(module, self.input_size, self.channels)

    @property
    def channels(self) -> int:
        """C, channels of the model images (3 RGB, 4 with depth)."""
        return INPUT_MODALITIES[self.input_modalities]


def _training_block(model_path: Path, payload: dict | None) -> dict:
    block = {"wall_s": None, "hardware": None, "samples_seen": None, "epochs": None, "command": None, "log": None}
    if payload is None:
        return block
    # wall time of the whole run (validation included) where the checkpoint has it
    wall_field = "wall_seconds" if payload.get("wall_seconds") is not None else "train_seconds"
    for key, field, cast in (("wall_s", wall_field, float), ("samples_seen", "samples_seen", int),
                             ("epochs", "epoch", float)):
        if payload.get(field) is not None:
            block[key] = cast(payload[field])
    # the training loop writes run.json (with the hardware line) beside its checkpoints/ folder
    run_json = model_path.resolve().parent.parent / "run.json"
    if run_json.is_file():
        try:
            hardware = json.loads(run_json.read_text()).get("hardware")
        except json.JSONDecodeError:
            hardware = None
        if isinstance(hardware, str) and hardware.strip():
            block["hardware"] = hardware
    return block


def format_table(results: dict) -> str:
    """A short human-readable table of a results dict."""
    m, lat = results["metrics"], results["latency_ms_per_image"]

    def f(v, fmt="{:.2f}"):
        return "-" if v is None else fmt.format(v)

    rows = [
        ("model", f"{results['model']['label']} [{results['model']['format']}]"),
        ("dataset", (f"{results['dataset']['name']}, split {results['dataset']['split']}, "
                    f"{results['dataset']['frames']} frames")),
        ("MPJPE all / hand / probe", (f"{f(m['mpjpe_mm']['all'])} / {f(m['mpjpe_mm']['hand'])} / "
                                     f"{f(m['mpjpe_mm']['probe'])} mm")),
        ("root-relative hand MPJPE, wrist / middle MCP",
         f"{f(m['root_relative_hand_mpjpe_mm'])} / {f(m.get('middle_mcp_relative_hand_mpjpe_mm'))} mm"),
        ("probe MPJPE, half-turn symmetric", f"{f(m['probe_symmetric_mpjpe_mm'])} mm"),
        ("spread ratio x / y / z", " / ".join(f(m["spread_ratio"][a]) for a in metrics.SPREAD_AXES)),
        ("PA-MPJPE hand", f"{f(m['pa_mpjpe_hand_mm'])} mm"),
        ("3D PCK AUC 0-50 mm", f(m["pck_auc_0_50mm"], "{:.3f}")),
        ("2D error", f"{f(m['pixel_error_px'])} px"),
        ("parameters / GFLOPs", (f"{f(results['model']['parameters'], '{:,}')} / "
                                f"{f(None if results['model']['flops'] is None else results['model']['flops'] / 1e9, '{:.3f}')}")),
        ("latency PyTorch b1 / b32", f"{f(lat['pytorch']['batch1'])} / {f(lat['pytorch']['batch32'])} ms/image"),
        ("latency ORT b1 / b32", f"{f(lat['onnxruntime']['batch1'])} / {f(lat['onnxruntime']['batch32'])} ms/image"),
        ("track", results["track"] or "-"),
    ]
    pose = m.get("probe_pose")
    if pose is not None:
        rows += probe_pose_rows("probe", pose, f)
    floor = results["split_floor"]
    if floor is not None:
        mm = floor["floor_mm"]
        rows.append(("split floor hand / probe / all",
                     f"{f(mm['hand'])} / {f(mm['probe'])} / {f(mm['all'])} mm ({floor['floor_kind']})"))
    floor_pose = m.get("split_floor_probe_pose")
    if floor_pose is not None:
        rows += probe_pose_rows("split floor probe", floor_pose, f)
    for axis, buckets in results["breakdowns"].items():
        for label, b in buckets.items():
            rows.append((f"  {axis}: {label}", (f"{f(b['mpjpe_mm']['all'])} mm all, {f(b['mpjpe_mm']['hand'])} hand, "
                                               f"{f(b['mpjpe_mm']['probe'])} probe ({b['frames']} frames)")))
    width = max(len(k) for k, _ in rows)
    return "\n".join(f"{k:<{width}}  {v}" for k, v in rows)


def _symmetric_probe_error(pred3d: np.ndarray, gt3d: np.ndarray, fields: dict, log) -> float | None:
    """``metrics.probe_symmetric_mpjpe_mm`` with the group read from the annotations; None (logged) if undefined."""
    try:
        group = probe_symmetry_group(fields["keypoints_3d_cam"], fields["T_cam_world"])
    except BadValueError as exc:
        log(f"warning: no half-turn symmetric probe error: {exc}")
        return None
    errors, choice = metrics.probe_symmetric_errors_mm(pred3d, gt3d, group)
    plain = float(metrics.keypoint_errors_mm(pred3d, gt3d)[:, kp.CORNER_SLICE].mean())
    log(f"probe MPJPE {plain:.2f} mm; minimised over the half turn about the probe's long axis {errors.mean():.2f} mm "
        f"(the half-turned corner labels were closer on {100.0 * np.mean(choice != 0):.1f} % of frames)")
    return float(errors.mean())


def _spread_ratio(pred3d: np.ndarray, gt3d: np.ndarray, log) -> dict[str, float | None]:
    """``metrics.spread_ratios``, logged, with a warning naming every axis below ``SPREAD_RATIO_WARN``."""
    ratios = metrics.spread_ratios(pred3d, gt3d)
    shown = ", ".join(f"{a} {'-' if r is None else f'{r:.2f}'}" for a, r in ratios.items())
    log(f"spread ratio of predicted to true 3D keypoints across frames (1 = varies like the truth): {shown}")
    for axis in metrics.collapsed_axes(ratios):
        log(f"warning: predicted 3D keypoints barely vary along the camera {axis} axis across frames: spread ratio "
            f"{ratios[axis]:.2f} < {metrics.SPREAD_RATIO_WARN} of the truth's "
            f"(the model may give one {axis} for every image)")
    return ratios


def run_eval(options: EvalOptions, log: Callable[[str], None] = print) -> dict[str, Any]:
    """Evaluate a checkpoint or an exported ONNX model on one split and write the results JSON.

    The model file, ``--out`` and the dataset are checked before the model runs; the results file is then
    locked (a second eval writing it is refused) until it is written, and any failure writes none.

    Returns:
        {"results": the validated results dict, "out": str path, "table": str, and with ``figures``
        "figures": {"samples", "worst", "pck"} str paths}
    """
    from hupbench.core.contract import read_manifest
    from hupbench.core.io import OutputLock, check_writable, clean_stale_tmp
    from hupbench.evaluation.results import write_results

    previous_threads = torch.get_num_threads()
    if options.threads is not None:
        torch.set_num_threads(options.threads)
    try:
        if not options.model.is_file():
            raise MissingFileError(f"model file {options.model} does not exist")
        if options.out is not None:  # an unwritable --out is refused before minutes of work
            check_writable(options.out, "--out", file=True)
        figures_dir = None
        if options.figures:
            figures_dir = check_writable(options.figures_dir or default_figures_dir(options.model, options.split),
                                         "--figures")
        manifest = read_manifest(options.dataset, options.split, needs="the benchmark needs")
        net = EvalModel(options.model)
        run_name = options.out.stem if options.out is not None else options.run_name or net.run_name
        out_path = options.out or check_writable(default_results_path(options.model, options.split), "--out",
                                                 file=True)
        with OutputLock.for_file(out_path, "eval"):
            clean_stale_tmp(out_path.parent, recursive=False)  # evaluations that were killed
            results, outputs = _results(options, net, manifest, run_name, out_path, log)
            write_results(out_path, results)
        answer = {"results": results, "out": str(out_path), "table": format_table(results)}
        if figures_dir is not None:
            answer["figures"] = {k: str(p) for k, p in _figures(figures_dir, results, outputs).items()}
        return answer
    finally:
        torch.set_num_threads(previous_threads)


def _predict_split(net, reader, batch_size: int, split: str, progress: bool, log):
    """The model's (N, 29, 2) normalised and (N, 29, 3) metre predictions over a split, with the labels
    (float64), in frame order; a NaN or inf output is an error."""
    from tqdm import tqdm

    loader = torch.utils.data.DataLoader(reader, batch_size=batch_size, shuffle=False, num_workers=0)
    pred2d, pred3d, gt2d, gt3d = [], [], [], []
    start = time.perf_counter()
    for batch in tqdm(loader, unit="batch", desc=f"eval {split}", dynamic_ncols=True, leave=False,
                      disable=None if progress else True):  # None: only on a terminal
        p2, p3 = net.predict(batch["image"])
        pred2d.append(p2)
        pred3d.append(p3)
        gt2d.append(batch["keypoints_2d"].double().numpy())
        gt3d.append(batch["keypoints_3d"].double().numpy())
    pred2d, pred3d, gt2d, gt3d = (np.concatenate(a) for a in (pred2d, pred3d, gt2d, gt3d))
    log(f"ran {net.format} model on {len(reader)} {split} frames in {time.perf_counter() - start:.1f} s")
    bad = ~(np.isfinite(pred3d).all(axis=(1, 2)) & np.isfinite(pred2d).all(axis=(1, 2)))
    if bad.any():
        raise RunFailedError(f"the model's output is NaN or inf on {int(bad.sum())} of {len(bad)} frames")
    return pred2d, pred3d, gt2d, gt3d


def _measured_latency(net: EvalModel, out_path: Path, run_name: str, log, progress: bool) -> dict:
    """Latency per image of PyTorch and onnxruntime at batch 1 and 32 (an ONNX model: onnxruntime only)."""
    from hupbench.core.io import DiskFullError, tmp_path
    from hupbench.provenance import git_commit

    after = net.after_network if net.fits else None  # the fits are part of the model's run time
    if net.format == "onnx":
        return _latencies(None, net.path, net.input_size, net.channels, torch.get_num_threads(), log, progress,
                          after=after)
    from hupbench.inference.export import export_onnx, onnx_metadata

    # the timed ONNX file lives beside the results under a temporary name (``.NAME.tmpPID.onnx``), not in
    # a folder of the system's: a killed eval leaves it where the next one removes it
    onnx_path = tmp_path(out_path, ".onnx")
    out_path.parent.mkdir(parents=True, exist_ok=True)

    def export():
        try:
            export_onnx(net.module, onnx_path, onnx_metadata(net.payload, run_name, git_commit()))
        except OSError as exc:
            raise (DiskFullError(onnx_path) if exc.errno == errno.ENOSPC else exc) from exc

    try:
        return _latencies(net.module, onnx_path, net.input_size, net.channels, torch.get_num_threads(), log, progress,
                          export, after)
    finally:
        onnx_path.unlink(missing_ok=True)


def _figures(figures_dir: Path, results: dict, outputs: dict) -> dict[str, Path]:
    """:func:`hupbench.evaluation.figures.write_eval_figures` of the evaluated split, keypoints in the stored
    frames' pixels."""
    from hupbench.data.reader import read_rgb
    from hupbench.evaluation.figures import write_eval_figures
    from hupbench.input_geometry import normalized_to_pixels

    reader, image_size = outputs["reader"], outputs["image_size"]
    return write_eval_figures(
        figures_dir, results["model"]["label"], results["dataset"]["split"],
        lambda i: read_rgb(reader.path(i), image_size), reader.ann["frame_id"],
        normalized_to_pixels(outputs["gt2d"], image_size), normalized_to_pixels(outputs["pred2d"], image_size),
        outputs["errors"])


def _results(options: EvalOptions, net: EvalModel, manifest: dict, run_name: str, out_path: Path,
             log) -> tuple[dict, dict]:
    """(the results dict of the model on the split: metrics, breakdowns, floors, latency and provenance; the
    outputs behind it: "pred2d", "gt2d" (N, 29, 2) normalised, "errors" (N, 29) mm, "reader", "image_size")."""
    from hupbench.core.contract import read_annotations
    from hupbench.core.io import file_sha256
    from hupbench.data import HUPDataset, ReaderConfig
    from hupbench.evaluation.results import blank_results
    from hupbench.input_geometry import normalized_to_pixels
    from hupbench.provenance import git_commit, hardware_description

    dataset, split = options.dataset, options.split
    reader = HUPDataset(dataset, split, ReaderConfig(input_size=net.input_size, input_modalities=net.input_modalities))
    fields = {**reader.ann, **read_annotations(dataset, split, ("theta", "z_ego", "background_id", "T_cam_world",
                                                                "grasp_id", "view_id"), reader.manifest)}
    grasp_ids = sorted({int(g) for g in fields["grasp_id"]})
    manifest_path = str(dataset / "manifest.json")
    theta_vol_by_grasp = grasp_theta_vol_deg(manifest, grasp_ids, manifest_path)
    track, floor = split_floor(manifest, split, grasp_ids, manifest_path)
    K_eval = reader[0]["K"].double().numpy()
    if np.max(np.abs(K_eval - net.K_input)) > K_MISMATCH_REL * abs(net.K_input[0, 0]):
        log(f"warning: the dataset's input intrinsics {K_eval.round(3).tolist()} differ from the model's K_input "
            f"{net.K_input.round(3).tolist()}: its 3D output assumes the training camera")
    pred2d, pred3d, gt2d, gt3d = _predict_split(net, reader, options.batch_size, split, options.progress, log)

    errors = metrics.keypoint_errors_mm(pred3d, gt3d)                                   # (N, 29) mm
    image_size = tuple(int(v) for v in manifest["image_size"])  # (W, H)
    pixel_error = metrics.pixel_error_px(normalized_to_pixels(pred2d, image_size),
                                         normalized_to_pixels(gt2d, image_size))
    background_names = (manifest.get("backgrounds") or {}).get("names")
    results = blank_results("measured", run_name)
    parameters, flops = net.cost()
    # a run's config may name its variant (train.yaml ``label``); otherwise model, backbone and input size
    label = (options.label or ((net.payload or {}).get("config") or {}).get("label")
             or model_label(net.model_config, net.input_size))
    results["model"] = {"name": str(net.model_config.get("name")), "label": str(label),
                        "config": net.model_config, "parameters": parameters, "flops": flops,
                        "input_size": int(net.input_size), "format": net.format}
    total = sum(int(v) for v in manifest["counts"].values())
    results["dataset"] = {"path": str(dataset.resolve()), "manifest_sha256": file_sha256(dataset / "manifest.json"),
                          "split": split, "frames": len(reader), "name": f"hupbench {dataset.resolve().name} "
                                                                          f"({total:,} frames)",
                          "grasp_theta_vol_deg": theta_vol_by_grasp}
    results["metrics"] = {
        "mpjpe_mm": metrics.split_from_errors_mm(errors) | {"all_averaging": metrics.ALL_AVERAGING},
        "root_relative_hand_mpjpe_mm": metrics.root_relative_mpjpe_mm(pred3d, gt3d),
        "middle_mcp_relative_hand_mpjpe_mm": metrics.root_relative_mpjpe_mm(pred3d, gt3d, root=metrics.MIDDLE_MCP_INDEX),
        "pa_mpjpe_hand_mm": metrics.pa_mpjpe_mm(pred3d, gt3d),
        "pck_auc_0_50mm": metrics.pck_auc_from_errors(errors),
        "pixel_error_px": pixel_error,
        "probe_symmetric_mpjpe_mm": _symmetric_probe_error(pred3d, gt3d, fields, log),
        "spread_ratio": _spread_ratio(pred3d, gt3d, log),
    }
    probe = dataset_probe(dataset)
    K_stored = np.asarray(fields["K"], np.float64)                                      # (N, 3, 3) stored images
    results["metrics"]["probe_pose"] = logged_probe_pose(pred3d, gt3d, K_stored, image_size[0], probe, "model", log)
    results["metrics"]["split_floor_probe_pose"] = floor_probe_pose(dataset, manifest, floor, fields, gt3d,
                                                                     image_size[0], probe, log)
    results["breakdowns"] = {
        "latitude": metrics.breakdown_mpjpe_mm(errors, breakdowns.latitude_labels(fields["theta"])),
        "z_ego": metrics.breakdown_mpjpe_mm(errors, breakdowns.z_ego_labels(fields["z_ego"])),
        "background": metrics.breakdown_mpjpe_mm(errors, breakdowns.background_labels(fields["background_id"], background_names)),
        "grasp": metrics.breakdown_mpjpe_mm(errors, breakdowns.grasp_labels(fields["grasp_id"])),
    }
    if theta_vol_by_grasp is not None and any(v is not None for v in theta_vol_by_grasp.values()):
        by_grasp = {int(g): theta for g, theta in theta_vol_by_grasp.items()}
        results["breakdowns"]["theta_vol"] = metrics.breakdown_mpjpe_mm(
            errors, breakdowns.theta_vol_labels(fields["grasp_id"], by_grasp))
    results["track"], results["split_floor"] = track, floor
    if floor is not None:
        model_mm = results["metrics"]["mpjpe_mm"]
        log(f"{split} split floor: hand {floor['floor_mm']['hand']:.2f} / probe {floor['floor_mm']['probe']:.2f} / all "
            f"{floor['floor_mm']['all']:.2f} mm ({FLOOR_NAMES[floor['floor_kind']]}); this model: hand "
            f"{model_mm['hand']:.2f} / probe {model_mm['probe']:.2f} / all {model_mm['all']:.2f} mm")
    if options.latency:
        results["latency_ms_per_image"] = _measured_latency(net, out_path, run_name, log, options.progress)
    results["device"] = hardware_description(torch.device("cpu"))
    results["training"] = _training_block(options.model, net.payload)
    results["training"]["command"] = options.training_command
    results["training"]["log"] = options.training_log
    results["git_commit"] = git_commit()
    results["created_utc"] = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
    return results, {"pred2d": pred2d, "gt2d": gt2d, "errors": errors, "reader": reader, "image_size": image_size}
