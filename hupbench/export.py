"""``hupbench export CKPT``: ONNX export with a parity check of onnxruntime against PyTorch.

The ONNX file follows the contract that ``hupbench predict`` reads (notes/common.md):

    input   "image"    (B, 3, S, S) float32 RGB in [0, 1], dynamic batch axis "batch"
    output  "points2d" (B, 29, 2) float32, normalised [-1, 1] coordinates of the input image
            "points3d" (B, 29, 3) float32, metres, OpenCV camera frame of the model-input camera K_input
    opset   18 (fixed)
    metadata_props  hupbench.onnx_schema "1", hupbench.input_size, hupbench.K_input (JSON 3x3),
            hupbench.keypoint_names, hupbench.skeleton_edges, hupbench.model_config (JSON),
            hupbench.run_name, hupbench.git_commit (the commit of the code that exported it)

:class:`ContractModule` wraps any model of :mod:`models` into that interface; ``hupbench eval``
runs the same wrapper, so the PyTorch and ONNX numbers mean the same thing. A ResNetRegressor
built without a 2D head gets ``points2d`` from the pinhole projection of its ``points3d`` with
K_input (models/coords.py convention: x_norm = (2 u + 1) / S - 1).

Export uses the dynamo exporter (``torch.onnx.export(..., dynamo=True)``), which handles every
layer of the models here, the graph convolutions and the Graph U-Net's learned pooling included.

Writes are atomic and checked: the file is written under a temporary name, onnxruntime runs it
on real dataset images next to PyTorch, and only when the 3D outputs agree within
``PARITY_MAX_3D_MM`` is it renamed to its final name. A failed check removes the temporary
file and raises, so no file that looks valid is left behind.
"""

from __future__ import annotations

import json
import logging
import os
import tempfile
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from datagen import keypoints as kp

__all__ = [
    "OPSET",
    "PARITY_MAX_3D_MM",
    "ContractModule",
    "contract_model",
    "default_run_name",
    "export_onnx",
    "onnx_metadata",
    "read_onnx_metadata",
    "run_export",
]

#: the ONNX opset of every exported file (fixed: the contract with ``hupbench predict``)
OPSET = 18
#: ONNX schema version written into metadata_props["hupbench.onnx_schema"]
ONNX_SCHEMA = "1"
#: largest allowed |onnxruntime - PyTorch| of points3d, millimetres
PARITY_MAX_3D_MM = 0.1
#: points closer to the camera plane than this are projected as if at this depth (metres), so an
#: untrained or diverged model's points2d stay finite
MIN_PROJECTION_DEPTH_M = 1e-3
#: frames of real images the parity check runs
PARITY_FRAMES = 8
#: metadata key prefix
META = "hupbench."


class ContractModule(nn.Module):
    """A model of :mod:`models` behind the ONNX contract: image -> (points2d, points3d).

    Args:
        model: a HOPENet or ResNetRegressor (anything returning a named tuple with ``points3d``
            and ``points2d`` that may be None), in eval mode.
        K_input: (3, 3) intrinsics of the model input image, pixels.
        input_size: S, side of the square model input, pixels.

    Forward:
        image: (B, 3, S, S) float32 RGB in [0, 1].
        Returns ``(points2d, points3d)``: (B, N, 2) normalised [-1, 1] of the input image and
        (B, N, 3) metres, OpenCV camera frame of K_input. Without a 2D head, points2d is the
        projection of points3d with K_input (depth clamped to >= ``MIN_PROJECTION_DEPTH_M``).
    """

    def __init__(self, model: nn.Module, K_input, input_size: int) -> None:
        super().__init__()
        K = torch.as_tensor(np.asarray(K_input, dtype=np.float64), dtype=torch.float32)
        if K.shape != (3, 3):
            raise ValueError(f"K_input must be (3, 3), got {tuple(K.shape)}")
        if isinstance(input_size, bool) or not isinstance(input_size, int) or input_size < 1:
            raise ValueError(f"input_size must be a positive int, got {input_size!r}")
        self.model = model
        self.input_size = input_size
        # fx, fy, cx, cy as a buffer: device-agnostic and baked into the ONNX graph as a constant
        self.register_buffer("intrinsics", torch.stack([K[0, 0], K[1, 1], K[0, 2], K[1, 2]]), persistent=False)

    def forward(self, image: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        out = self.model(image)
        points3d = out.points3d
        points2d = getattr(out, "points2d", None)
        if points2d is None:
            fx, fy, cx, cy = self.intrinsics.unbind(0)
            z = points3d[..., 2].clamp(min=MIN_PROJECTION_DEPTH_M)            # (B, N)
            u = fx * points3d[..., 0] / z + cx                                   # (B, N) pixels
            v = fy * points3d[..., 1] / z + cy
            points2d = torch.stack([u, v], dim=-1) * (2.0 / self.input_size) + (1.0 / self.input_size - 1.0)
        return points2d, points3d


def contract_model(model: nn.Module, payload: dict[str, Any]) -> ContractModule:
    """:class:`ContractModule` for a checkpoint's model, with its K_input and input size, in eval mode."""
    n = model.config.get("n_keypoints", kp.NUM_KEYPOINTS) if hasattr(model, "config") else kp.NUM_KEYPOINTS
    if n != kp.NUM_KEYPOINTS:
        raise ValueError(f"the model predicts {n} keypoints; the benchmark and the ONNX contract need "
                         f"{kp.NUM_KEYPOINTS} ({kp.NUM_HAND} hand + {kp.NUM_CORNERS} probe corners)")
    return ContractModule(model, payload["K_input"], int(payload["input_size"])).eval()


def default_run_name(checkpoint: str | Path, payload: dict[str, Any]) -> str:
    """The run name of a checkpoint: its training config's ``run_name``, else the file stem.

    Characters outside ``[A-Za-z0-9._-]`` become "_" so the name is a valid results file stem.
    """
    name = None
    config = payload.get("config")
    if isinstance(config, dict) and isinstance(config.get("run_name"), str) and config["run_name"].strip():
        name = config["run_name"]
    name = name or Path(checkpoint).stem
    clean = "".join(c if c.isalnum() or c in "._-" else "_" for c in name).lstrip("._-")
    return clean[:128] or "model"


def onnx_metadata(payload: dict[str, Any], run_name: str, git_commit: str) -> dict[str, str]:
    """The metadata_props of the ONNX contract, all strings (JSON where structured)."""
    return {
        META + "onnx_schema": ONNX_SCHEMA,
        META + "input_size": str(int(payload["input_size"])),
        META + "K_input": json.dumps(np.asarray(payload["K_input"], dtype=np.float64).tolist()),
        META + "keypoint_names": json.dumps(list(kp.KEYPOINT_NAMES)),
        META + "skeleton_edges": json.dumps([list(e) for e in kp.SKELETON_EDGES]),
        META + "model_config": json.dumps(payload["model_config"], sort_keys=True),
        META + "run_name": run_name,
        META + "git_commit": git_commit,
    }


def read_onnx_metadata(path: str | Path) -> dict[str, Any]:
    """Read and check the hupbench metadata of an exported ONNX file (weights are not loaded).

    Returns:
        {"input_size": int, "K_input": (3, 3) list, "model_config": dict, "run_name": str,
         "git_commit": str, "keypoint_names": list, "skeleton_edges": list}
    """
    import onnx

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"ONNX model {path} does not exist")
    try:
        proto = onnx.load(str(path), load_external_data=False)
    except Exception as exc:  # onnx raises DecodeError, OSError and others for a foreign file
        raise ValueError(f"{path} is not a readable ONNX model: {type(exc).__name__}: {exc}") from exc
    props = {p.key: p.value for p in proto.metadata_props}
    if props.get(META + "onnx_schema") != ONNX_SCHEMA:
        raise ValueError(f"{path} is not a hupbench ONNX export (metadata hupbench.onnx_schema is "
                         f"{props.get(META + 'onnx_schema')!r}, expected {ONNX_SCHEMA!r})")
    try:
        meta = {
            "input_size": int(props[META + "input_size"]),
            "K_input": json.loads(props[META + "K_input"]),
            "model_config": json.loads(props[META + "model_config"]),
            "keypoint_names": json.loads(props[META + "keypoint_names"]),
            "skeleton_edges": json.loads(props[META + "skeleton_edges"]),
            "run_name": props.get(META + "run_name", ""),
            "git_commit": props.get(META + "git_commit", ""),
        }
    except (KeyError, ValueError) as exc:
        raise ValueError(f"{path}: bad or missing hupbench metadata: {type(exc).__name__}: {exc}") from exc
    return meta


def export_onnx(module: ContractModule, path: str | Path, metadata: dict[str, str], opset: int = OPSET) -> Path:
    """Export a :class:`ContractModule` to ONNX with a dynamic batch axis and write it to ``path``.

    ``path`` is written directly (callers that need atomicity pass a temporary name).

    Args:
        module: the wrapped model, eval mode, on the CPU.
        path: destination ``.onnx``.
        metadata: metadata_props, str -> str.
        opset: ONNX opset (the contract fixes 18).

    Returns:
        ``path``.
    """
    import onnx

    if isinstance(opset, bool) or not isinstance(opset, int) or opset < 18:
        raise ValueError(f"opset must be an int >= 18 (the dynamo exporter's minimum), got {opset!r}")
    size = module.input_size
    example = torch.rand(2, 3, size, size)
    # two exporter messages that a user cannot act on, silenced here and only here: the registry's
    # "torchvision is not installed. Skipping torchvision::roi_pool" (we use no torchvision operator)
    # and torch's own FutureWarning about LeafSpec, raised inside torch.export
    registry_log = logging.getLogger("torch.onnx._internal.exporter._registration")
    level = registry_log.level
    registry_log.setLevel(logging.ERROR)
    try:
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message=r".*isinstance\(treespec, LeafSpec\).*", category=FutureWarning)
            program = torch.onnx.export(
                module.eval(), (example,), dynamo=True, opset_version=opset, verbose=False,
                input_names=["image"], output_names=["points2d", "points3d"],
                dynamic_shapes={"image": {0: torch.export.Dim("batch")}})
    finally:
        registry_log.setLevel(level)
    proto = program.model_proto
    for key, value in metadata.items():
        entry = proto.metadata_props.add()
        entry.key, entry.value = key, value
    onnx.checker.check_model(proto)
    path = Path(path)
    onnx.save_model(proto, str(path))
    return path


def ort_session(path: str | Path, threads: int | None = None):
    """An onnxruntime CPU session; ``threads`` intra-op threads (default: torch's thread count, for a fair timing)."""
    import onnxruntime as ort

    options = ort.SessionOptions()
    options.intra_op_num_threads = int(threads or torch.get_num_threads())
    options.log_severity_level = 3
    return ort.InferenceSession(str(path), sess_options=options, providers=["CPUExecutionProvider"])


def _parity_images(dataset: Path, input_size: int, frames: int) -> torch.Tensor:
    """(B, 3, S, S) real images of the dataset (test split, else val, else train), B <= ``frames``."""
    from hupbench.data import HUPDataset, ReaderConfig, read_manifest

    counts = read_manifest(dataset)["counts"]
    split = next((s for s in ("test", "val", "train") if counts.get(s, 0) > 0), None)
    if split is None:
        raise ValueError(f"{dataset} has no frames in any split")
    reader = HUPDataset(dataset, split, ReaderConfig(input_size=input_size))
    idx = np.linspace(0, len(reader) - 1, min(frames, len(reader))).round().astype(int)
    return torch.stack([reader[int(i)]["image"] for i in idx])


def parity(module: ContractModule, onnx_path: str | Path, images: torch.Tensor) -> dict[str, float]:
    """Max |onnxruntime - PyTorch| of both outputs on ``images`` (B, 3, S, S).

    Returns:
        {"points3d_mm": float, "points2d_norm": float, "points2d_px": float (input-image pixels),
         "frames": int}
    """
    with torch.inference_mode():
        ref2d, ref3d = module(images)
    got2d, got3d = ort_session(onnx_path).run(["points2d", "points3d"], {"image": images.numpy()})
    d3 = float(np.max(np.abs(got3d.astype(np.float64) - ref3d.numpy().astype(np.float64)))) * 1000.0
    d2 = float(np.max(np.abs(got2d.astype(np.float64) - ref2d.numpy().astype(np.float64))))
    if not (np.isfinite(d3) and np.isfinite(d2)):
        raise RuntimeError("the ONNX or PyTorch outputs hold NaN or inf on real images")
    return {"points3d_mm": d3, "points2d_norm": d2, "points2d_px": d2 * module.input_size / 2.0,
            "frames": int(images.shape[0])}


def run_export(checkpoint: str | Path, out: str | Path | None = None, dataset: str | Path | None = None,
               opset: int = OPSET, run_name: str | None = None, parity_frames: int = PARITY_FRAMES,
               log=print) -> dict[str, Any]:
    """Export a checkpoint to ONNX and check onnxruntime against PyTorch on real images.

    Args:
        checkpoint: a hupbench checkpoint (``.pt``).
        out: destination ``.onnx`` (default: the checkpoint path with suffix ``.onnx``).
        dataset: dataset for the parity images (default: the checkpoint's training dataset).
        opset: ONNX opset (18).
        run_name: "hupbench.run_name" metadata (default: :func:`default_run_name`).
        parity_frames: images compared (from the test split, else val, else train).
        log: called with progress lines.

    Returns:
        {"onnx": str path, "parity": {"points3d_mm", "points2d_norm", "points2d_px", "frames"},
         "dataset": str, "opset": int, "run_name": str, "metadata": dict}

    Raises:
        RuntimeError: the 3D outputs differ by more than ``PARITY_MAX_3D_MM``; no file is left at ``out``.
    """
    from hupbench.checkpoint import load_model
    from hupbench.provenance import git_commit

    checkpoint = Path(checkpoint)
    if checkpoint.suffix.lower() not in (".pt", ".pth"):
        raise ValueError(f"export needs a hupbench checkpoint (.pt), got {checkpoint.name!r}")
    model, payload = load_model(checkpoint)
    module = contract_model(model, payload)
    out = Path(out) if out is not None else checkpoint.with_suffix(".onnx")
    if out.suffix.lower() != ".onnx":
        raise ValueError(f"--out must end in .onnx, got {out.name!r}")
    if dataset is None:
        recorded = (payload.get("dataset") or {}).get("path")
        if not recorded:
            raise ValueError("the checkpoint records no dataset for the parity check; pass --dataset")
        dataset = recorded
    dataset = Path(dataset)
    if not dataset.is_dir():
        raise FileNotFoundError(f"dataset {dataset} for the parity check does not exist; pass --dataset")
    images = _parity_images(dataset, module.input_size, parity_frames)
    run_name = run_name or default_run_name(checkpoint, payload)
    metadata = onnx_metadata(payload, run_name, git_commit())

    out.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(prefix=f".{out.name}.", suffix=".tmp", dir=out.parent)
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        export_onnx(module, tmp, metadata, opset)
        diff = parity(module, tmp, images)
        log(f"parity on {diff['frames']} real images of {dataset}: max |ORT - PyTorch| points3d "
            f"{diff['points3d_mm']:.2e} mm, points2d {diff['points2d_norm']:.2e} (normalised) = "
            f"{diff['points2d_px']:.2e} px of the {module.input_size} px input")
        if diff["points3d_mm"] > PARITY_MAX_3D_MM:
            raise RuntimeError(f"ONNX parity check failed: points3d differ by up to {diff['points3d_mm']:.4f} mm "
                               f"(> {PARITY_MAX_3D_MM} mm) between onnxruntime and PyTorch; nothing written to {out}")
        os.replace(tmp, out)
    finally:
        if tmp.exists():
            tmp.unlink()
    return {"onnx": str(out), "parity": diff, "dataset": str(dataset), "opset": opset, "run_name": run_name,
            "metadata": metadata}
