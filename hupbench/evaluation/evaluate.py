"""``hupbench eval MODEL DATASET``: every benchmark metric of a checkpoint or an exported ONNX model.

The model runs over one split (:func:`hupbench.evaluation.prediction.predict_split`), the metrics of
:mod:`hupbench.evaluation.split_metrics` and :mod:`hupbench.evaluation.probe_pose` are computed on all frames, its
cost is measured (:mod:`hupbench.evaluation.latency`), and a results JSON (:mod:`hupbench.evaluation.results`) is
written; docs/metrics.md defines each number. A leaderboard row (``--out leaderboard/results/NAME.json``) is
written only from a source tree whose package code is committed, so that its ``git_commit`` reproduces it.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from hupbench import metrics
from hupbench.core.contract import is_sequence
from hupbench.core.errors import BadValueError, MissingFileError
from hupbench.core.input_checks import check_choice, check_int
from hupbench.core.processes import check_threads
from hupbench.evaluation.intervals import CONFIDENCE, RESAMPLES, SEED, interval_text
from hupbench.evaluation.latency import LATENCY_FRAMES, measured_latency, model_cost
from hupbench.evaluation.prediction import EvalModel, SplitPrediction, evenly_spaced, predict_split, split_reader
from hupbench.evaluation.probe_pose import dataset_probe, floor_probe_pose, logged_probe_pose, probe_pose_rows
from hupbench.evaluation.results import FLOOR_NAMES
from hupbench.evaluation.split_metrics import (
    grasp_theta_vol_deg,
    split_breakdowns,
    split_floor,
    split_intervals,
    split_metrics,
)
from hupbench.fits import check_fitted_probe, fits, model_fit_settings
from hupbench.input_geometry import INPUT_MODALITIES
from hupbench.provenance import check_run_name

__all__ = ["EvalOptions", "default_figures_dir", "default_results_path", "format_table", "is_leaderboard_row",
           "model_label", "run_eval"]

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
            measured row) and ``training.log``: the run's metrics.jsonl relative to the leaderboard folder of
            ``out`` (``leaderboard/`` for ``leaderboard/results/NAME.json``), where it must exist.
        label: the model's name in the results (default: the training config's ``label``, else model,
            backbone and input size).
        progress: progress bars (with ETA) over the model pass and the latency timings, on a terminal.
        figures: also draw prediction beside ground truth (sample and worst frames) and the PCK curve
            (:mod:`hupbench.evaluation.figures`) into ``figures_dir`` (default :func:`default_figures_dir`).
        interval_resamples, interval_seed: the bootstrap resamples (>= 1) and seed (>= 0) of the 95 % intervals
            over the test grasps (:mod:`hupbench.evaluation.intervals`).
        depth_sensor: the depth a depth-reading model gets (``data.reader.depth_sensor``): "dataset" (its
            sensor's, else its clean depth), "none", or a preset made from the clean depth with each frame's seeded
            noise (the same depth for every model); the results' ``dataset.depth_sensor`` records it.
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
    interval_resamples: int = RESAMPLES
    interval_seed: int = SEED
    depth_sensor: str = "dataset"

    def __post_init__(self) -> None:
        from hupbench.data.reader import DEPTH_SENSORS

        check_int(self.batch_size, "batch_size", low=1)
        check_choice(self.depth_sensor, "--depth-sensor", DEPTH_SENSORS)
        check_int(self.interval_resamples, "interval_resamples", low=1)
        check_int(self.interval_seed, "interval_seed", low=0)
        if self.threads is not None:
            check_threads(self.threads, "--threads")
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
        if out is not None or self.run_name is not None:
            check_run_name(out.stem if out is not None else self.run_name,
                           f"the results file stem of --out {out}" if out is not None else "--run-name")
        if self.training_log is not None:
            log = Path(self.training_log)
            where = None if out is None or log.is_absolute() or ".." in log.parts else out.parent.parent / log
            if where is None or not where.is_file():
                raise MissingFileError(f"--training-log {self.training_log!r} must name the run's metrics.jsonl "
                                       f"inside the leaderboard folder of --out, relative to it (logs/NAME.jsonl for "
                                       f"--out leaderboard/results/NAME.json): "
                                       + ("no --out" if out is None else f"{where or log} is not a file there"))
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


def is_leaderboard_row(out: Path) -> bool:
    """Whether a results path is a leaderboard row: ``.../leaderboard/results/NAME.json``, or a row of its depth sensor
    table, ``.../leaderboard/robustness/NAME.json``."""
    folder = out.resolve().parent
    return folder.name in ("results", "robustness") and folder.parent.name == "leaderboard"


def model_label(model_config: dict, input_size: int) -> str:
    """Human label naming the model, backbone, input size, a depth input and HUPNet's heads, e.g. "HOPE-Net
    (ResNet-18, 128 px)", "HUPNet (ResNet-18, 128 px, RGB-D, depth-anchored, rigid probe)", "HUPNet (ResNet-18,
    128 px, RGB-D, depth-anchored, stride-4 heatmaps, probe fitted to depth)", "HUPNet (ResNet-18, 128 px, RGB-D,
    depth-anchored, segmentation, probe fitted to depth, hand fitted to depth)"; a fit whose settings the model
    changes names them: "hand fitted to depth (iterations=16)"; a hand fit started from the model's training hands
    says how many: "hand fitted to depth (from 40 training hands, iterations=16)"."""
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
    if model_config.get("segmentation"):
        parts.append("segmentation")
    changed = model_config.get("fit_settings") or {}
    hands = model_config.get("hand_templates")
    for part in fits(model_config):
        notes = [f"{k}={v}" for k, v in changed.get(part, {}).items()]
        if part == "hand" and hands and model_fit_settings(model_config)[1].templates:
            notes.insert(0, f"from {len(hands)} training hands")
        parts.append(f"{part} fitted to depth" + (f" ({', '.join(notes)})" if notes else ""))
    return f"{name} ({', '.join(parts)})"


def _training_block(model_path: Path, payload: dict | None) -> dict:
    """The ``training`` block of a results file from a checkpoint's record (``payload``; None for an ONNX model:
    all None): wall time (s, validation included where recorded), samples seen, epochs, and the hardware line of
    the run's ``run.json`` beside its ``checkpoints/`` folder; ``command`` and ``log`` are the caller's."""
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
        ("dataset grasps sha256", results["dataset"].get("grasps_sha256") or "- (not recorded by its manifest)"),
        *_mpjpe_rows(results, f),
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
    floor_pose = m.get("split_floor_probe_pose")
    if floor_pose is not None:
        rows += probe_pose_rows("split floor probe", floor_pose, f)
    if results.get("sequence") is not None:
        rows += sequence_rows(results["sequence"])
    for axis, buckets in results["breakdowns"].items():
        for label, b in buckets.items():
            rows.append((f"  {axis}: {label}", (f"{f(b['mpjpe_mm']['all'])} mm all, {f(b['mpjpe_mm']['hand'])} hand, "
                                               f"{f(b['mpjpe_mm']['probe'])} probe ({b['frames']} frames)")))
    width = max(len(k) for k, _ in rows)
    return "\n".join(f"{k:<{width}}  {v}" for k, v in rows)


def _mpjpe_rows(results: dict, f) -> list[tuple[str, str]]:
    """Table rows of each MPJPE (all / hand / probe) with its interval over the test grasps and the split floor
    beside it, e.g. ("MPJPE probe", "18.62 mm [95 % CI 7.7-29.5], split floor 59.30 [53.0-65.6]"), and the
    intervals' provenance."""
    mpjpe, floor, intervals = results["metrics"]["mpjpe_mm"], results["split_floor"], results["intervals"]
    level = f"{100 * (CONFIDENCE if intervals is None else intervals['confidence']):g} % CI"
    rows = []
    for part in ("all", "hand", "probe"):
        text = f"{f(mpjpe[part])} mm"
        if intervals is not None:
            text += f" {interval_text(intervals['mpjpe_mm'][part], f'{level} ')}"
        if floor is not None:
            text += f", split floor {f(floor['floor_mm'][part])}"
            if intervals is not None:
                text += f" {interval_text((intervals['split_floor_mm'] or {}).get(part))}"
        rows.append((f"MPJPE {part}", text))
    if floor is not None:
        name = FLOOR_NAMES.get(floor["floor_kind"])
        rows.append(("split floor", floor["floor_kind"] + ("" if name is None else f": {name}")))
    if intervals is not None:
        grasps = intervals["grasps"]
        rows.append((level, f"{intervals['method']}; {grasps} test grasp{'' if grasps == 1 else 's'}, "
                            f"{intervals['resamples']:,} resamples, seed {intervals['seed']}"))
    return rows


def run_eval(options: EvalOptions, log: Callable[[str], None] = print) -> dict[str, Any]:
    """Evaluate a checkpoint or an exported ONNX model on one split and write the results JSON.

    ``--out`` (a leaderboard row: the package code committed), the dataset and the model file are checked
    before the model runs; the results file is then locked (a second eval writing it is refused) until it is
    written, and any failure writes none.

    Returns:
        {"results": the validated results dict, "out": str path, "table": str, "leaderboard_row": bool, and with
        ``figures`` "figures": {"samples", "worst", "pck"} str paths}
    """
    from hupbench.core.contract import read_manifest
    from hupbench.core.io import OutputLock, check_writable, clean_stale_tmp
    from hupbench.evaluation.results import write_results
    from hupbench.provenance import refuse_uncommitted_package

    previous_threads = torch.get_num_threads()
    if options.threads is not None:
        torch.set_num_threads(options.threads)
    try:
        row = options.out is not None and is_leaderboard_row(options.out)
        if options.out is not None:  # an unwritable --out is refused before minutes of work
            check_writable(options.out, "--out", file=True)
        if row:
            refuse_uncommitted_package(f"a leaderboard row ({options.out})")
        figures_dir = None
        if options.figures:
            figures_dir = check_writable(options.figures_dir or default_figures_dir(options.model, options.split),
                                         "--figures")
        manifest = read_manifest(options.dataset, options.split, needs="the benchmark needs")
        net = EvalModel(options.model)
        check_fitted_probe(net.model_config, manifest.get("probe"), str(options.dataset / "manifest.json"),
                           net.fit_probe)
        run_name = (options.out.stem if options.out is not None else
                    options.run_name if options.run_name is not None else net.run_name)
        out_path = options.out or check_writable(default_results_path(options.model, options.split), "--out",
                                                 file=True)
        with OutputLock.for_file(out_path, "eval"):
            clean_stale_tmp(out_path.parent, recursive=False)  # evaluations that were killed
            results, outputs = _results(options, net, manifest, run_name, out_path, log)
            write_results(out_path, results)
        answer = {"results": results, "out": str(out_path), "table": format_table(results), "leaderboard_row": row}
        if figures_dir is not None:
            answer["figures"] = {k: str(p) for k, p in _figures(figures_dir, results, outputs).items()}
        return answer
    finally:
        torch.set_num_threads(previous_threads)


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


def _sequence(options: EvalOptions, net: EvalModel, manifest: dict, predicted: SplitPrediction, fields: dict,
              log) -> dict:
    """The ``sequence`` block (:func:`hupbench.evaluation.sequence_metrics.sequence_block`) of a split of clips
    (``predicted`` the model over it, its fits also tracking each clip; ``fields`` its annotations, with
    :data:`~hupbench.evaluation.sequence_metrics.FIELDS`): the tracking filter chosen on the validation split (the
    model run over it too; on val itself when it is the split evaluated), then the split scored per frame and
    tracked (the tracked fits, then the filter)."""
    from hupbench.core.contract import SEQUENCE, read_annotations
    from hupbench.evaluation.sequence_metrics import FIELDS, choose_filter, sequence_block

    fps = float(manifest[SEQUENCE]["fps"])
    if options.split == "val":
        val, val_fields = predicted, fields
    else:
        if not manifest["counts"].get("val"):
            raise BadValueError(f"{options.dataset} has no val split: tracking's filter is chosen on it")
        reader = split_reader(options.dataset, "val", net, options.depth_sensor)
        val_fields = read_annotations(options.dataset, "val", FIELDS, manifest)
        val = predict_split(net, reader, options.batch_size, progress=options.progress, log=log,
                            clips=np.asarray(val_fields["clip_id"]))
    choice = choose_filter(val.points3d, val.labels3d, val_fields, fps, val.tracked3d)
    block = sequence_block(predicted.points3d, predicted.labels3d, fields, fps, choice, "val",
                           options.interval_resamples, options.interval_seed, predicted.tracked3d,
                           predicted.tracked_fits_ms, net.fit_settings)
    for name, text in sequence_rows(block):
        log(f"{options.split} {name}: {text}")
    return block


def sequence_rows(block: dict) -> list[tuple[str, str]]:
    """Table rows of a ``sequence`` block: the filter, then each metric untracked -> tracked with intervals and the
    paired interval of the difference."""
    settings = block["filter"]["settings"]
    rows = [("tracking", "none kept the MPJPE on " + block["filter"]["chosen_on"] if settings is None else
             f"1-euro, min cut-off {settings['min_cutoff_hz']:g} Hz, beta {settings['beta']:g}, chosen on "
             f"{block['filter']['chosen_on']}; {block['filter_ms_per_frame']:.3f} ms/frame; {block['clips']} clips "
             f"at {block['fps']:g} frames/s")]
    fitted = block.get("tracked_fits")
    if fitted is not None:
        rows.append(("tracked fits", f"from the frame before's probe pose, probe {fitted['probe_tracking_iterations']} "
                                     f"and hand {fitted['hand_tracking_iterations']} steps, "
                                     f"{fitted['ms_per_frame']:.2f} ms/frame (median, frame by frame)"))
    intervals = block["intervals"]
    for key, value in block["untracked"].items():
        rows.append((f"{key}, untracked -> tracked",
                     f"{value:.2f} {interval_text(intervals['untracked'][key])} -> {block['tracked'][key]:.2f} "
                     f"{interval_text(intervals['tracked'][key])}, difference "
                     f"{interval_text(intervals['tracked_minus_untracked'][key], '95 % CI ')}"))
    rows.append(("truth", ", ".join(f"{k} {v:.2f}" for k, v in block["truth"].items())))
    return rows


def _dataset_record(dataset: Path, manifest: dict, split: str, frames: int, theta_vol_by_grasp, log) -> dict:
    """The ``dataset`` block of a results file: the dataset by name and by the sha256 of its manifest and of its
    grasps file (the manifest's ``grasps_sha256``, None for a dataset made before it was recorded), never by a path
    of this machine; logged."""
    from hupbench.core.io import file_sha256

    total = sum(int(v) for v in manifest["counts"].values())
    record = {"name": f"hupbench {dataset.resolve().name} ({total:,} frames)",
              "manifest_sha256": file_sha256(dataset / "manifest.json"),
              "grasps_sha256": manifest.get("grasps_sha256"), "split": split, "frames": frames,
              "grasp_theta_vol_deg": theta_vol_by_grasp}
    log(f"dataset {record['name']}, split {split}: manifest sha256 {record['manifest_sha256']}, grasps sha256 "
        f"{record['grasps_sha256'] or 'not recorded (a dataset made before the manifest recorded it)'}")
    return record


def _results(options: EvalOptions, net: EvalModel, manifest: dict, run_name: str, out_path: Path,
             log) -> tuple[dict, dict]:
    """(the results dict of the model on the split: metrics, breakdowns, floors, latency and provenance; the
    outputs behind it: "pred2d", "gt2d" (N, 29, 2) normalised, "errors" (N, 29) mm, "reader", "image_size")."""
    from hupbench.core.contract import read_annotations
    from hupbench.evaluation.results import UTC_FORMAT, blank_results
    from hupbench.input_geometry import normalized_to_pixels
    from hupbench.provenance import git_commit, hardware_description

    dataset, split = options.dataset, options.split
    reader = split_reader(dataset, split, net, options.depth_sensor)
    keys = ("theta", "z_ego", "background_id", "T_cam_world", "grasp_id", "view_id")
    if is_sequence(manifest):
        from hupbench.evaluation.sequence_metrics import FIELDS

        keys = tuple(dict.fromkeys(keys + FIELDS))
    fields = {**reader.ann, **read_annotations(dataset, split, keys, reader.manifest)}
    grasp_ids = sorted({int(g) for g in fields["grasp_id"]})
    manifest_path = str(dataset / "manifest.json")
    theta_vol_by_grasp = grasp_theta_vol_deg(manifest, grasp_ids, manifest_path)
    track, floor = split_floor(manifest, split, grasp_ids, manifest_path)
    results = blank_results("measured", run_name)
    results["dataset"] = _dataset_record(dataset, manifest, split, len(reader), theta_vol_by_grasp, log)
    if reader.config.depth:
        results["dataset"]["depth_sensor"] = reader.sensor.name if reader.sensor is not None else "none"
        log(f"depth: {reader.depth_source}")
    K_eval = reader[0]["K"].double().numpy()
    if np.max(np.abs(K_eval - net.K_input)) > K_MISMATCH_REL * abs(net.K_input[0, 0]):
        log(f"warning: the dataset's input intrinsics {K_eval.round(3).tolist()} differ from the model's K_input "
            f"{net.K_input.round(3).tolist()}: its 3D output assumes the training camera")
    clips = np.asarray(fields["clip_id"]) if is_sequence(manifest) else None
    predicted = predict_split(net, reader, options.batch_size, progress=options.progress, log=log, clips=clips)
    pred2d, pred3d, gt2d, gt3d = predicted.points2d, predicted.points3d, predicted.labels2d, predicted.labels3d

    errors = metrics.keypoint_errors_mm(pred3d, gt3d)                                   # (N, 29) mm
    image_size = tuple(int(v) for v in manifest["image_size"])  # (W, H)
    parameters, flops = model_cost(net)
    # a run's config may name its variant (train.yaml ``label``); otherwise model, backbone and input size
    label = (options.label or ((net.payload or {}).get("config") or {}).get("label")
             or model_label(net.model_config, net.input_size))
    results["model"] = {"name": str(net.model_config.get("name")), "label": str(label),
                        "config": net.model_config, "parameters": parameters, "flops": flops,
                        "input_size": int(net.input_size), "format": net.format}
    results["metrics"] = split_metrics(normalized_to_pixels(pred2d, image_size), normalized_to_pixels(gt2d, image_size),
                                       pred3d, gt3d, fields, log)
    probe = dataset_probe(dataset, manifest)
    K_stored = np.asarray(fields["K"], np.float64)                                      # (N, 3, 3) stored images
    results["metrics"]["probe_pose"] = logged_probe_pose(pred3d, gt3d, K_stored, image_size[0], probe, "model", log)
    results["metrics"]["split_floor_probe_pose"] = floor_probe_pose(dataset, manifest, floor, fields, gt3d,
                                                                     image_size[0], probe, log)
    results["breakdowns"] = split_breakdowns(errors, fields, manifest, theta_vol_by_grasp)
    results["track"], results["split_floor"] = track, floor
    results["intervals"] = split_intervals(errors, fields["grasp_id"], floor, options.interval_resamples,
                                           options.interval_seed)
    for name, text in _mpjpe_rows(results, lambda v: f"{v:.2f}"):
        log(f"{split} {name}: {text}")
    if is_sequence(manifest):
        results["sequence"] = _sequence(options, net, manifest, predicted, fields, log)
    if options.latency:
        frames = np.stack([reader[int(i)]["image"].numpy() for i in evenly_spaced(len(reader), LATENCY_FRAMES)])
        results["latency_ms_per_image"] = measured_latency(net, out_path, run_name, log, options.progress, frames)
    results["device"] = hardware_description(torch.device("cpu"))
    results["training"] = _training_block(options.model, net.payload)
    results["training"]["command"] = options.training_command
    results["training"]["log"] = options.training_log
    results["git_commit"] = git_commit()
    results["created_utc"] = time.strftime(UTC_FORMAT, time.gmtime())
    return results, {"pred2d": pred2d, "gt2d": gt2d, "errors": errors, "reader": reader, "image_size": image_size}
