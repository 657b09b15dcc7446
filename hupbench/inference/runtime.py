"""The ONNX runtime of every verb: open an exported model with onnxruntime, check it against the model-file
contract, and run it (``hupbench eval``, export's parity check and ``hupbench predict``).

Numpy and onnxruntime only (no torch): the predict path imports it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import onnxruntime as ort
from onnxruntime.capi import onnxruntime_pybind11_state as ort_errors

from hupbench.core.errors import BadValueError, MissingFileError, RunFailedError
from hupbench.core.io import file_sha256
from hupbench.fits.known_probe import FitProbe
from hupbench.fits.settings import HandFitSettings, ProbeFitSettings
from hupbench.inference.image_statistics import ImageStatistics
from hupbench.inference.model_file import BASE_OUTPUTS, check_graph, check_io_shapes, read_metadata

__all__ = ["OnnxModel", "load_onnx_model", "run_onnx", "run_onnx_outputs", "run_onnx_with_confidence",
           "split_model_images"]

# onnxruntime raises its own exception types (not RuntimeError) for unreadable, invalid or failing models
_LOAD_ERRORS = (ort_errors.Fail, ort_errors.InvalidProtobuf, ort_errors.InvalidGraph, ort_errors.InvalidArgument,
                ort_errors.NoSuchFile, ort_errors.NotImplemented)
_RUN_ERRORS = (ort_errors.Fail, ort_errors.InvalidArgument, ort_errors.RuntimeException, ort_errors.NotImplemented,
               ort_errors.EPFail)
_TORCH_MAGIC = (b"PK\x03\x04", b"\x80\x02")  # torch.save's zip format (PyTorch >= 1.6) and its legacy pickle


@dataclass(frozen=True)
class OnnxModel:
    """An exported model opened with onnxruntime (CPU), with its checked hupbench metadata.

    Attributes:
        path: the .onnx file. session: the onnxruntime session. input_size: S, pixels.
        K_input: (3, 3) float64 intrinsics of the model input, the camera of the 3D output.
        keypoint_names: N names. skeleton_edges: pairs (i, j) of keypoint indices.
        model_config: the architecture's config ({} when the file has none). run_name, git_commit: provenance.
        sha256: hash of the file. input_modalities: "rgb", or "rgb+depth" for a model with a ``depth`` input.
        outputs: the graph's outputs (``hupbench.outputs``). image_statistics: the out-of-distribution
            calibration, None for a file exported without it. depth_sensor: the depth camera a depth model was
            trained on ("none": the clean z-buffer; a preset of :mod:`hupbench.core.depth_sensor`), None unknown.
        fit_probe: the probe a fitting model's fits know (:class:`hupbench.fits.known_probe.FitProbe`), None where
            the file carries none (the fits then know the default procedural probe).
        fit_settings: (probe, hand) the settings its fits run with (:func:`hupbench.fits.model_fit_settings`, read
            once from its model config when the file is loaded).
    """

    path: Path
    session: ort.InferenceSession
    input_size: int
    K_input: np.ndarray
    keypoint_names: tuple[str, ...]
    skeleton_edges: tuple[tuple[int, int], ...]
    model_config: dict
    run_name: str
    git_commit: str
    sha256: str
    input_modalities: str = "rgb"
    outputs: tuple[str, ...] = BASE_OUTPUTS
    image_statistics: ImageStatistics | None = None
    depth_sensor: str | None = None
    fit_probe: FitProbe | None = None
    fit_settings: tuple[ProbeFitSettings, HandFitSettings] = (ProbeFitSettings(), HandFitSettings())

    @property
    def reads_depth(self) -> bool:
        return self.input_modalities == "rgb+depth"

    @property
    def has_confidence(self) -> bool:
        return "confidence" in self.outputs


def _reason(exc: BaseException, limit: int) -> str:
    return " ".join(str(exc).split())[:limit]


def load_onnx_model(path: str | Path, threads: int | None = None) -> OnnxModel:
    """Open a file written by ``hupbench export``, check its metadata against its graph, and run it once;
    ``threads``: onnxruntime's intra-op threads (default: one per core)."""
    path = Path(path)
    if path.is_dir():
        raise BadValueError(f"model {path} is a folder, not an .onnx file")
    if not path.is_file():
        raise MissingFileError(f"model {path} does not exist")
    data = path.read_bytes()
    if not data:
        raise BadValueError(f"model {path} is an empty file (0 bytes), not an ONNX model")
    if data.startswith(_TORCH_MAGIC):
        raise BadValueError(f"model {path} is a PyTorch checkpoint, not an ONNX model: predict runs without torch; "
                            f"export it first with `hupbench export {path}`")
    options = ort.SessionOptions()
    options.log_severity_level = 4  # fatal only: a failure reaches the user as one line naming the file
    if threads is not None:
        options.intra_op_num_threads = threads
    # onnxruntime's threads wait for work by spinning: on a small CPU they then take the cores from the fits that run
    # after the network (benchmarks/latency.py: end to end against the sum of its stages)
    options.add_session_config_entry("session.intra_op.allow_spinning", "0")
    try:
        # from the bytes, not the path: onnxruntime's message for a damaged file then names no path twice
        session = ort.InferenceSession(data, sess_options=options, providers=["CPUExecutionProvider"])
    except _LOAD_ERRORS as exc:
        raise BadValueError(f"{path} is not a readable ONNX model: {type(exc).__name__}: {_reason(exc, 200)}") from None
    props = dict(session.get_modelmeta().custom_metadata_map)
    meta = read_metadata(props, str(path))
    check_io_shapes({i.name: list(i.shape or []) for i in session.get_inputs()},
                    {o.name: list(o.shape or []) for o in session.get_outputs()},
                    meta["input_size"], len(meta["keypoint_names"]), str(path), meta["input_modalities"],
                    meta["outputs"])
    check_graph(props, data, str(path))
    model = OnnxModel(path=path, session=session, sha256=file_sha256(path), **meta)
    # one blank image: a graph made for another input size under edited metadata fails here, before any work
    S = model.input_size
    run_onnx_outputs(model, np.zeros((1, 3, S, S), np.float32),
                     np.zeros((1, 1, S, S), np.float32) if model.reads_depth else None)
    return model


def split_model_images(images: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """(B, C, S, S) float32 model images (RGB, then depth when C = 4) as the graph's inputs: image (B, 3, S, S)
    and depth (B, 1, S, S) or None."""
    depth = np.ascontiguousarray(images[:, 3:]) if images.shape[1] > 3 else None
    return np.ascontiguousarray(images[:, :3]), depth


def run_onnx(model: OnnxModel, images: np.ndarray, depth: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The outputs on (B, 3, S, S) float32 RGB ``images`` in [0, 1] and, for a model that reads depth, (B, 1, S, S)
    float32 ``depth`` (its depth input, :data:`hupbench.inference.model_file.DEPTH_INPUT`): points2d (B, N, 2)
    float32, normalised input coordinates; points3d (B, N, 3) float32, metres, OpenCV camera frame of K_input."""
    points2d, points3d = _run(model, images, depth, BASE_OUTPUTS)
    return points2d, points3d


def run_onnx_with_confidence(model: OnnxModel, images: np.ndarray,
                             depth: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """:func:`run_onnx`'s outputs and the per-keypoint confidence (B, N) float32 in [0, 1], or None for a file
    without that output (``hupbench.outputs``)."""
    if not model.has_confidence:
        return (*run_onnx(model, images, depth), None)
    points2d, points3d, confidence = _run(model, images, depth, (*BASE_OUTPUTS, "confidence"))
    return points2d, points3d, confidence


def run_onnx_outputs(model: OnnxModel, images: np.ndarray, depth: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Every output the file declares (``hupbench.outputs``: points2d, points3d, then confidence (B, N) float32 and
    segmentation (B, S, S) int64 where it has them), by name, for :func:`run_onnx`'s inputs."""
    return dict(zip(model.outputs, _run(model, images, depth, tuple(model.outputs))))


def _run(model: OnnxModel, images: np.ndarray, depth: np.ndarray | None, names: tuple[str, ...]) -> list[np.ndarray]:
    """The named outputs of one run (:func:`run_onnx`), points2d and points3d first, their shapes checked."""
    S = model.input_size
    assert images.dtype == np.float32 and images.shape[1:] == (3, S, S), (images.shape, images.dtype)
    feed = {"image": images}
    if model.reads_depth:
        assert depth is not None and depth.dtype == np.float32 and depth.shape == (len(images), 1, S, S), depth
        feed["depth"] = depth
    else:
        assert depth is None, "the model reads no depth"
    try:
        outputs = model.session.run(list(names), feed)
    except _RUN_ERRORS as exc:
        # the declared input shape and the metadata agree (load_onnx_model), so the graph inside wants
        # something else: a model made for another input size whose header was edited, or a broken graph
        raise RunFailedError(f"{model.path}: onnxruntime could not run the model on a {tuple(images.shape)} batch at "
                             f"the input size its metadata declare ({S} px): {type(exc).__name__}: "
                             f"{_reason(exc, 240)}") from None
    n, b = len(model.keypoint_names), images.shape[0]
    expected = {"points2d": (b, n, 2), "points3d": (b, n, 3), "confidence": (b, n), "segmentation": (b, S, S)}
    shapes = [tuple(output.shape) for output in outputs]
    if shapes != [expected[name] for name in names]:
        raise RunFailedError(f"{model.path}: outputs {', '.join(names)} must be "
                             f"{' and '.join(str(expected[name]) for name in names)} for {n} keypoint names, got "
                             f"{' and '.join(map(str, shapes))}")
    return outputs
