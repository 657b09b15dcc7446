"""``hupbench export CKPT``: ONNX export with a parity check of onnxruntime against PyTorch.

The file follows the model-file contract of :mod:`hupbench.inference.model_file` (input ``image``, outputs
``points2d`` and ``points3d``, and ``confidence`` for a model with a per-keypoint confidence, the
``hupbench.*`` metadata) at the fixed opset ``OPSET``, exported with the dynamo exporter.
:class:`ContractModule` wraps any model of :mod:`models` into that interface, and ``hupbench eval`` runs the
same wrapper, so the PyTorch and ONNX numbers mean the same thing. The export also calibrates predict's
out-of-distribution check on the dataset's frames (:mod:`hupbench.inference.image_statistics`).

The file is written under a temporary name while the output is locked, onnxruntime runs it on real dataset
images beside PyTorch, and it is renamed to its final name only when the 3D outputs agree within
``PARITY_MAX_3D_MM``.
"""

from __future__ import annotations

import logging
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from hupbench.core import keypoints as kp
from hupbench.core.errors import BadValueError, MissingFileError, RunFailedError
from hupbench.core.input_checks import check_int
from hupbench.fits import fits
from hupbench.fits.known_probe import FitProbe, dataset_fit_probe, default_fit_probe
from hupbench.inference.image_statistics import ImageStatistics
from hupbench.inference.model_file import BASE_OUTPUTS, CONFIDENCE, GRAPH_SHA256, graph_sha256, write_metadata
from hupbench.inference.runtime import (
    load_onnx_model,
    run_onnx_outputs,
    split_model_images,
)
from hupbench.input_geometry import INPUT_MODALITIES, pixels_to_normalized
from hupbench.provenance import check_run_name, default_run_name, git_commit

__all__ = ["OPSET", "PARITY_MAX_3D_MM", "ContractModule", "ExportOptions", "calibrate_image_statistics",
           "check_keypoint_count", "contract_model", "export_onnx", "onnx_metadata", "run_export"]

#: the ONNX opset of every exported file (fixed: the contract with ``hupbench predict``)
OPSET = 18
#: opsets ``--opset`` may ask for: the dynamo exporter's minimum to the newest torch's exporter writes
#: (torch.onnx._constants.ONNX_MAX_OPSET, 23 in torch 2.13)
OPSET_MIN = 18
#: largest allowed |onnxruntime - PyTorch| of points3d, millimetres
PARITY_MAX_3D_MM = 0.1
#: points closer to the camera plane than this are projected as if at this depth (metres), so an
#: untrained or diverged model's points2d stay finite
EXPORT_DEPTH_CLAMP_M = 1e-3
#: frames of real images the parity check runs
PARITY_FRAMES = 8
#: largest allowed |onnxruntime - PyTorch| of the per-keypoint confidence (in [0, 1])
PARITY_MAX_CONFIDENCE = 1e-3
#: largest allowed share of input pixels whose segmentation class differs between onnxruntime and PyTorch (a pixel
#: at a near-tie of two classes' logits may flip)
PARITY_MAX_SEGMENTATION = 1e-3


@dataclass(frozen=True)
class ExportOptions:
    """What ``hupbench export`` is asked to do, checked once where it enters.

    Attributes:
        checkpoint: a hupbench checkpoint (``.pt``). out: destination ``.onnx`` (default: the checkpoint path
            with suffix ``.onnx``). dataset: of the parity images (default: the checkpoint's training dataset).
        opset: ONNX opset, from :data:`OPSET_MIN` to the newest this torch writes.
        run_name: "hupbench.run_name" metadata, a results file stem (default:
            :func:`hupbench.provenance.default_run_name` of the training run's name).
        parity_frames: images compared (from the test split, else val, else train).
        progress: a progress bar over the stages (export, parity) on a terminal.
    """

    checkpoint: Path
    out: Path | None = None
    dataset: Path | None = None
    opset: int = OPSET
    run_name: str | None = None
    parity_frames: int = PARITY_FRAMES
    progress: bool = True

    def __post_init__(self) -> None:
        from torch.onnx._constants import ONNX_MAX_OPSET

        check_int(self.opset, "opset", OPSET_MIN, ONNX_MAX_OPSET,
                  hint=" (the dynamo exporter's minimum to the newest this torch writes)")
        checkpoint = Path(self.checkpoint)
        if checkpoint.suffix.lower() not in (".pt", ".pth"):
            raise BadValueError(f"export needs a hupbench checkpoint (.pt), got {checkpoint.name!r}")
        out = Path(self.out) if self.out is not None else checkpoint.with_suffix(".onnx")
        if out.suffix.lower() != ".onnx":
            raise BadValueError(f"--out must end in .onnx, got {out.name!r}")
        assert self.parity_frames >= 1, self.parity_frames
        if self.run_name is not None:
            check_run_name(self.run_name, "--run-name")
        object.__setattr__(self, "checkpoint", checkpoint)
        object.__setattr__(self, "out", out)
        object.__setattr__(self, "dataset", None if self.dataset is None else Path(self.dataset))


class ContractModule(nn.Module):
    """A model of :mod:`models` (its output has ``points3d``, and ``points2d`` or None) behind the ONNX contract
    of :mod:`hupbench.inference.model_file`, image (and depth, for a model that reads it) -> (points2d,
    points3d), for an S = ``input_size`` pixel input with (3, 3) intrinsics ``K_input``. Without a 2D head,
    points2d is the projection of points3d with K_input (depth clamped to >= ``EXPORT_DEPTH_CLAMP_M``).
    With ``confidence`` and a model that has one (:data:`hupbench.inference.model_file.CONFIDENCE`), a third
    output: its ``confidence`` (B, N) (the exported file's); a model with a segmentation head adds its pixels'
    classes, ``segmentation`` (B, S, S) int64, last (the fits read it)."""

    def __init__(self, model: nn.Module, K_input, input_size: int, confidence: bool = False) -> None:
        super().__init__()
        K = torch.as_tensor(np.asarray(K_input, dtype=np.float64), dtype=torch.float32)
        self.model = model
        self.input_size = input_size
        self.with_confidence = confidence and getattr(getattr(model, "config", None), "name", None) in CONFIDENCE
        self.with_segmentation = bool(getattr(getattr(model, "config", None), "segmentation", False))
        channels = getattr(getattr(model, "config", None), "input_channels", INPUT_MODALITIES["rgb"])
        self.reads_depth = channels == INPUT_MODALITIES["rgb+depth"]
        # fx, fy, cx, cy as a buffer: device-agnostic and baked into the ONNX graph as a constant
        self.register_buffer("intrinsics", torch.stack([K[0, 0], K[1, 1], K[0, 2], K[1, 2]]), persistent=False)

    @property
    def input_modalities(self) -> str:
        return "rgb+depth" if self.reads_depth else "rgb"

    @property
    def outputs(self) -> tuple[str, ...]:
        """The graph outputs, in the order :meth:`forward` returns them."""
        return (*BASE_OUTPUTS, *(("confidence",) if self.with_confidence else ()),
                *(("segmentation",) if self.with_segmentation else ()))

    def forward(self, image: torch.Tensor, depth: torch.Tensor | None = None) -> tuple[torch.Tensor, ...]:
        """image (B, 3, S, S) RGB in [0, 1]; depth (B, 1, S, S) metres for a model that reads it (the model's input
        is the two side by side); or one (B, C, S, S) model image. Returns (points2d, points3d), then, with
        ``with_confidence``, confidence (B, N), and with ``with_segmentation`` (a model with a segmentation head),
        each pixel's class (B, S, S) int64: :attr:`outputs`."""
        out = self.model(image if depth is None else torch.cat([image, depth], dim=1))
        points3d = out.points3d
        points2d = getattr(out, "points2d", None)
        if points2d is None:
            fx, fy, cx, cy = self.intrinsics.unbind(0)
            z = points3d[..., 2].clamp(min=EXPORT_DEPTH_CLAMP_M)            # (B, N)
            u = fx * points3d[..., 0] / z + cx                                   # (B, N) pixels
            v = fy * points3d[..., 1] / z + cy
            points2d = pixels_to_normalized(torch.stack([u, v], dim=-1), self.input_size)
        extra = (out.confidence,) if self.with_confidence else ()
        extra += (out.segmentation.argmax(dim=1),) if self.with_segmentation else ()
        return points2d, points3d, *extra


def check_keypoint_count(n: int, source: str) -> None:
    """A model of ``n`` keypoints is one of the benchmark's (its 29, in the order of :mod:`hupbench.core.keypoints`);
    ``source`` names the model in the error."""
    if n != kp.NUM_KEYPOINTS:
        raise BadValueError(f"{source}: the model predicts {n} keypoints; the benchmark and the ONNX contract need "
                            f"{kp.NUM_KEYPOINTS} ({kp.NUM_HAND} hand + {kp.NUM_CORNERS} probe corners)")


def contract_model(model: nn.Module, payload: dict[str, Any], source: str, confidence: bool = False) -> ContractModule:
    """:class:`ContractModule` in eval mode for a model and payload of :func:`hupbench.checkpoint.load_model`
    (which checked K_input and the input size); ``source`` names the checkpoint in errors; ``confidence``: the
    third output where the model has one (the exported file's)."""
    check_keypoint_count(model.config.n_keypoints, source)
    return ContractModule(model, payload["K_input"], int(payload["input_size"]), confidence).eval()


def onnx_metadata(payload: dict[str, Any], run_name: str, git_commit: str, outputs: tuple[str, ...] = BASE_OUTPUTS,
                  image_statistics: ImageStatistics | None = None, depth_sensor: str | None = None,
                  fit_probe: FitProbe | None = None) -> dict[str, str]:
    """The metadata_props of the ONNX contract for a checkpoint's payload (:func:`model_file.write_metadata`):
    ``outputs`` those of the :class:`ContractModule` exported, ``image_statistics`` predict's calibration,
    ``depth_sensor`` the depth camera a depth model was trained on (:func:`trained_depth_sensor`), ``fit_probe`` the
    probe a fitting model's fits know (:func:`trained_fit_probe`), so that predict needs neither torch nor the
    generator to fit it."""
    channels = payload["model_config"].get("input_channels", 3)
    modalities = next(name for name, count in INPUT_MODALITIES.items() if count == channels)
    return write_metadata(payload["input_size"], payload["K_input"], kp.KEYPOINT_NAMES, kp.SKELETON_EDGES,
                          payload["model_config"], run_name, git_commit, modalities, outputs, image_statistics,
                          depth_sensor, fit_probe)


def trained_fit_probe(payload: dict[str, Any], dataset: Path | None = None) -> FitProbe | None:
    """The probe a fitting model's fits know: that of the dataset it was trained on (the one its checkpoint records,
    else ``dataset``: where it was moved to; :func:`hupbench.fits.known_probe.dataset_fit_probe`), the default
    procedural probe where neither is here; None for a model that fits nothing."""
    if not fits(payload["model_config"]):
        return None
    recorded = (payload.get("dataset") or {}).get("path")
    for trained_on in ([Path(recorded)] if recorded else []) + ([Path(dataset)] if dataset is not None else []):
        if (trained_on / "manifest.json").is_file():
            return dataset_fit_probe(trained_on)
    return default_fit_probe()


def trained_depth_sensor(payload: dict[str, Any], dataset: Path) -> str:
    """The depth camera a depth model's training read: its ``data.reader.depth_sensor``, where that is "dataset" the
    training dataset's own ("none" for its clean depth)."""
    from hupbench.core.contract import read_manifest

    asked = (((payload.get("config") or {}).get("data") or {}).get("reader") or {}).get("depth_sensor", "dataset")
    if asked != "dataset":
        return asked
    return (read_manifest(dataset).get("depth_sensor") or {}).get("preset", "none")


def export_onnx(module: ContractModule, path: str | Path, metadata: dict[str, str], opset: int = OPSET) -> Path:
    """Export a :class:`ContractModule` (eval mode, CPU) with a dynamic batch axis and ``metadata`` as its
    metadata_props to ``path``, written directly (callers that need atomicity pass a temporary name), and the
    graph's sha256 that ties them to it (``hupbench.graph_sha256``). The metadata's ``hupbench.outputs`` must be
    the module's :attr:`ContractModule.outputs`."""
    import json

    import onnx

    declared = tuple(json.loads(metadata.get("hupbench.outputs", "null")) or BASE_OUTPUTS)
    assert declared == module.outputs, (declared, module.outputs)
    size = module.input_size
    batch = torch.export.Dim("batch")
    example, names, dynamic = (torch.rand(2, 3, size, size),), ["image"], {"image": {0: batch}}
    if module.reads_depth:
        example, names = (*example, torch.rand(2, 1, size, size)), ["image", "depth"]
        dynamic["depth"] = {0: batch}
    # two exporter messages that a user cannot act on, silenced here and only here: the registry's
    # "torchvision is not installed. Skipping torchvision::roi_pool" (we use no torchvision operator)
    # and torch's own FutureWarning about LeafSpec, raised inside torch.export
    registry_log = logging.getLogger("torch.onnx._internal.exporter._registration")
    level = registry_log.level
    registry_log.setLevel(logging.ERROR)
    try:
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message=r".*isinstance\(treespec, LeafSpec\).*", category=FutureWarning)
            # the image and depth inputs share one batch axis, which the exporter notes once per input
            warnings.filterwarnings("ignore", message=r".*The axis name: batch will not be used.*", category=UserWarning)
            program = torch.onnx.export(
                module.eval(), example, dynamo=True, opset_version=opset, verbose=False,
                input_names=names, output_names=list(module.outputs), dynamic_shapes=dynamic)
    finally:
        registry_log.setLevel(level)
    proto = program.model_proto
    for key, value in metadata.items():
        entry = proto.metadata_props.add()
        entry.key, entry.value = key, value
    proto.metadata_props.add(key=GRAPH_SHA256, value=graph_sha256(proto.SerializeToString()))
    onnx.checker.check_model(proto)
    path = Path(path)
    onnx.save_model(proto, str(path))
    return path


def _parity_images(dataset: Path, input_size: int, frames: int, modalities: str = "rgb") -> torch.Tensor:
    """(B, C, S, S) real model images of the dataset (test split, else val, else train), B <= ``frames``."""
    from hupbench.data import HUPDataset, ReaderConfig, read_manifest

    counts = read_manifest(dataset)["counts"]
    # the calibration came first: the training split has frames
    split = next(s for s in ("test", "val", "train") if counts.get(s, 0) > 0)
    reader = HUPDataset(dataset, split, ReaderConfig(input_size=input_size, input_modalities=modalities))
    idx = np.linspace(0, len(reader) - 1, min(frames, len(reader))).round().astype(int)
    return torch.stack([reader[int(i)]["image"] for i in idx])


def parity(module: ContractModule, onnx_path: str | Path, images: torch.Tensor) -> dict[str, float | None]:
    """Max |onnxruntime - PyTorch| of the outputs on model ``images`` (B, C, S, S): {"points3d_mm",
    "points2d_norm", "points2d_px" (input-image pixels), "confidence" (None without that output), "segmentation"
    (the share of pixels whose class differs; None without that output), "frames"}; NaN where an output is not
    finite (:func:`parity_failures` judges them)."""
    with torch.inference_mode():
        ref = dict(zip(module.outputs, module(images)))
    got = run_onnx_outputs(load_onnx_model(onnx_path), *split_model_images(images.numpy()))

    def gap(a: np.ndarray, b: torch.Tensor) -> float:
        return float(np.max(np.abs(a.astype(np.float64) - b.numpy().astype(np.float64))))

    d3, d2 = gap(got["points3d"], ref["points3d"]) * 1000.0, gap(got["points2d"], ref["points2d"])
    dc = gap(got["confidence"], ref["confidence"]) if module.with_confidence else None
    ds = float(np.mean(got["segmentation"] != ref["segmentation"].numpy())) if module.with_segmentation else None
    return {"points3d_mm": d3, "points2d_norm": d2, "points2d_px": d2 * module.input_size / 2.0, "confidence": dc,
            "segmentation": ds, "frames": int(images.shape[0])}


def parity_failures(diff: dict[str, float | None]) -> list[str]:
    """What of a :func:`parity` check is beyond the allowed (outputs that are not finite, points3d beyond
    ``PARITY_MAX_3D_MM``, the confidence beyond ``PARITY_MAX_CONFIDENCE``), in words; empty when it passed."""
    gaps = [diff["points3d_mm"], diff["points2d_norm"]] + ([] if diff["confidence"] is None else [diff["confidence"]])
    if not np.isfinite(gaps).all():
        return ["the ONNX or PyTorch outputs hold NaN or inf on real images"]
    failed = []
    if diff["points3d_mm"] > PARITY_MAX_3D_MM:
        failed.append(f"points3d differ by up to {diff['points3d_mm']:.4f} mm (> {PARITY_MAX_3D_MM} mm) between "
                      f"onnxruntime and PyTorch")
    if diff["confidence"] is not None and diff["confidence"] > PARITY_MAX_CONFIDENCE:
        failed.append(f"the keypoint confidence differs by up to {diff['confidence']:.2e} (> "
                      f"{PARITY_MAX_CONFIDENCE:g}) between onnxruntime and PyTorch")
    if (diff.get("segmentation") or 0.0) > PARITY_MAX_SEGMENTATION:
        failed.append(f"the segmentation's class differs on {100 * diff['segmentation']:.2f} % of pixels (> "
                      f"{100 * PARITY_MAX_SEGMENTATION:g} %) between onnxruntime and PyTorch")
    return failed


def calibrate_image_statistics(dataset: Path, input_size: int, reads_depth: bool = False,
                               depth_folder: str = "depth") -> ImageStatistics:
    """Predict's out-of-distribution calibration (:func:`hupbench.inference.image_statistics.calibrate`) on the
    dataset's frames, read and resized exactly as predict reads an image: up to ``TRAIN_FRAMES`` training frames,
    the threshold from up to ``THRESHOLD_FRAMES`` validation frames (else test, else training frames); for a model
    that ``reads_depth``, the median depths of the same training frames' depth maps (``depth_folder``: the clean
    "depth", or the "sensor_depth" the model was trained on)."""
    from hupbench.data import read_manifest
    from hupbench.inference import image_statistics as stats
    from hupbench.inference.images import read_depth_png, read_image

    manifest = read_manifest(dataset)
    counts = manifest["counts"]

    def chosen(split: str, frames: int) -> list[Path]:
        files = sorted(p for p in (dataset / split / "rgb").iterdir() if p.suffix.lower() in (".jpg", ".jpeg", ".png"))
        return [files[i] for i in np.unique(np.linspace(0, len(files) - 1, min(frames, len(files))).round().astype(int))]

    def statistics(split: str, frames: int) -> np.ndarray:
        return np.stack([stats.image_statistics(read_image(path), input_size) for path in chosen(split, frames)])

    if counts.get("train", 0) < 2:
        raise BadValueError(f"{dataset} has {counts.get('train', 0)} training frames; the out-of-distribution "
                            "calibration needs at least 2")
    split = next(s for s in ("val", "test", "train") if counts.get(s, 0) > 0)
    depth = None
    if reads_depth:
        depth = np.array([stats.depth_median_m(read_depth_png(dataset / "train" / depth_folder / f"{path.stem}.png")
                                               * manifest["depth_scale_m"])
                          for path in chosen("train", stats.TRAIN_FRAMES)])
    return stats.calibrate(statistics("train", stats.TRAIN_FRAMES), statistics(split, stats.THRESHOLD_FRAMES), split,
                           depth)


def run_export(options: ExportOptions, log=print) -> dict[str, Any]:
    """Export a checkpoint to ONNX and check onnxruntime against PyTorch on real images (module docstring);
    everything is checked before the export starts, and a failure leaves no file at ``options.out``.

    Returns:
        {"onnx": str path, "parity": :func:`parity`'s dict, "dataset": str, "opset": int, "run_name": str,
         "metadata": dict, "image_statistics": the calibration's :meth:`ImageStatistics.describe`}
    """
    from tqdm import tqdm

    from hupbench.core.io import OutputLock, atomic_output, check_writable, clean_stale_tmp
    from hupbench.core.contract import SENSOR_DEPTH, read_manifest
    from hupbench.checkpoint import load_model

    out = check_writable(options.out, "--out", file=True)
    model, payload = load_model(options.checkpoint)
    module = contract_model(model, payload, f"checkpoint {options.checkpoint}", confidence=True)
    recorded = (payload.get("dataset") or {}).get("path")
    dataset = options.dataset or (Path(recorded) if recorded else None)
    if dataset is None or not dataset.exists():  # the parity check runs on real images
        missing = (f"checkpoint {options.checkpoint} records no dataset for the parity check" if dataset is None
                   else f"dataset {dataset} for the parity check does not exist")
        raise MissingFileError(f"{missing}; pass --dataset")
    recorded = (payload.get("config") or {}).get("run_name")
    run_name = options.run_name if options.run_name is not None else default_run_name(recorded, options.checkpoint)
    sensor = trained_depth_sensor(payload, dataset) if module.reads_depth else None
    stored = (read_manifest(dataset).get("depth_sensor") or {}).get("preset")
    calibration = calibrate_image_statistics(dataset, module.input_size, module.reads_depth,
                                             SENSOR_DEPTH if sensor is not None and sensor == stored else "depth")
    images = _parity_images(dataset, module.input_size, options.parity_frames, module.input_modalities)
    metadata = onnx_metadata(payload, run_name, git_commit(), module.outputs, calibration, sensor,
                             trained_fit_probe(payload, dataset))

    with OutputLock.for_file(out, "export"):
        clean_stale_tmp(out.parent, recursive=False)  # exports that were killed
        bar = tqdm(total=2, unit="stage", desc=f"export {out.name}", dynamic_ncols=True, leave=False,
                   disable=None if options.progress else True)  # None: only on a terminal
        # removed on any failure (a full disk says so); plain open() gives it the mode of every other output
        with bar, atomic_output(out) as tmp:
            bar.set_postfix_str("torch.onnx.export")
            export_onnx(module, tmp, metadata, options.opset)
            bar.update(1)
            bar.set_postfix_str(f"parity on {len(images)} images")
            diff = parity(module, tmp, images)
            bar.update(1)
            bar.close()
            log(f"parity on {diff['frames']} real images of {dataset}: max |ORT - PyTorch| points3d "
                f"{diff['points3d_mm']:.2e} mm, points2d {diff['points2d_norm']:.2e} (normalised) = "
                f"{diff['points2d_px']:.2e} px of the {module.input_size} px input"
                + ("" if diff["segmentation"] is None else
                   f", segmentation class on {100 * diff['segmentation']:.3f} % of pixels"))
            failed = parity_failures(diff)
            if failed:
                raise RunFailedError(f"ONNX parity check failed: {'; '.join(failed)}; nothing written to {out}")
    log(f"out-of-distribution check calibrated on {calibration.frames['train']} training frames; threshold "
        f"{calibration.threshold:.2f} = percentile {calibration.percentile:g} of {calibration.frames['threshold']} "
        f"{calibration.frames['threshold_split']} frames")
    return {"onnx": str(out), "parity": diff, "dataset": str(dataset), "opset": options.opset, "run_name": run_name,
            "metadata": metadata, "image_statistics": calibration.describe()}
