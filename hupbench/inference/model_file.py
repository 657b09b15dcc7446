"""The model-file contract: what ``hupbench export`` writes into an ONNX file and how every reader checks it.

Numpy only (no torch). The exporter writes through :func:`write_metadata`, which checks with
:func:`read_metadata`, the reader of :mod:`hupbench.inference.runtime`: the two cannot drift apart.

Metadata (``metadata_props``, strings): ``hupbench.onnx_schema`` (ONNX_SCHEMA), ``hupbench.input_size``
(S), ``hupbench.K_input`` (JSON 3 x 3, the camera of the 3D output at the model input),
``hupbench.keypoint_names`` and ``hupbench.skeleton_edges`` (JSON), ``hupbench.model_config`` (JSON
object), ``hupbench.run_name`` and ``hupbench.git_commit``, ``hupbench.input_modalities`` ("rgb" or
"rgb+depth"; "rgb" when absent) and, for a model that reads depth, ``hupbench.depth_input`` (JSON: what its
depth input holds, :data:`DEPTH_INPUT`). Graph: input ``image`` (B, 3, S, S) float32 RGB in [0, 1], and for
"rgb+depth" input ``depth`` (B, 1, S, S) float32 metres (0 where no surface, clipped to ``clip_m``; resized to
the nearest pixel like the image); outputs ``points2d`` (B, N, 2) normalised [-1, 1] input coordinates and
``points3d`` (B, N, 3) metres, OpenCV camera frame of K_input, for the N keypoint names.

Optional (a file without them still reads): ``hupbench.outputs`` (JSON list of the graph outputs,
:data:`OUTPUTS`; ``["points2d", "points3d"]`` when absent), where ``confidence`` is (B, N) float32 in [0, 1]
for a model with a per-keypoint confidence (:data:`CONFIDENCE`) and ``segmentation`` (B, S, S) int64 each input
pixel's class (:data:`hupbench.core.contract.SEGMENT_CLASSES`: other, hand, probe) for a model with a segmentation
head (the fits read it); and ``hupbench.image_statistics``, the
calibration of predict's out-of-distribution check (:class:`hupbench.inference.image_statistics.ImageStatistics`);
and, for a model that fits its output to the depth input (:func:`hupbench.fits.fits`), ``hupbench.fit_probe``: the
probe those fits know (:meth:`hupbench.fits.known_probe.FitProbe.to_json`; a file without it fits the default
procedural probe).

The metadata are tied to the graph they were written for: ``hupbench.graph_sha256`` (:data:`GRAPH_SHA256`) is
the sha256 of the serialized graph (:func:`graph_sha256`), added by the exporter once the graph exists and
checked on load (:func:`check_graph`), so that metadata copied onto another graph, or a graph edited after
export, is refused.
"""

from __future__ import annotations

import hashlib
import json
from typing import Any

import numpy as np

from hupbench.core.depth_sensor import NONE, PRESETS
from hupbench.core.errors import BadValueError
from hupbench.core import keypoints as kp
from hupbench.core.input_checks import check_finite_points, check_int, is_whole
from hupbench.fits.known_probe import FitProbe
from hupbench.fits.settings import model_fit_settings
from hupbench.inference.image_statistics import ImageStatistics
from hupbench.input_geometry import DEPTH_CLIP_M, INPUT_MODALITIES, INPUT_SIZE_RANGE

__all__ = ["CONFIDENCE", "GRAPH_SHA256", "META", "ONNX_SCHEMA", "OUTPUTS", "check_graph", "check_intrinsics",
           "check_io_shapes", "graph_sha256", "read_metadata", "write_metadata"]

#: the version written into ``metadata_props["hupbench.onnx_schema"]`` and the one readers accept
ONNX_SCHEMA = "1"
#: prefix of every hupbench metadata key
META = "hupbench."
#: the metadata key of :func:`graph_sha256`, which ties the metadata to their graph
GRAPH_SHA256 = META + "graph_sha256"
#: ``ModelProto.graph``'s field number (https://github.com/onnx/onnx/blob/main/onnx/onnx.proto)
_GRAPH_FIELD = 7
#: graph outputs and the width of their last axis, in the order they are checked
OUTPUT_WIDTHS = {"points3d": 3, "points2d": 2}
#: the outputs a file may declare in ``hupbench.outputs`` (the first two always), and the default
OUTPUTS = ("points2d", "points3d", "confidence", "segmentation")
BASE_OUTPUTS = ("points2d", "points3d")
#: what the ``confidence`` output means, by model name (``hupbench.model_config["name"]``); a model without a
#: per-keypoint score of its own has no entry (why: :data:`NO_CONFIDENCE`)
CONFIDENCE = {"hupnet": "the softmax probability mass of the keypoint's heatmap within its most probable 3 x 3 "
                        "cells: 1 = one sharp peak, 9 / cells = flat"}
NO_CONFIDENCE = ("this model regresses coordinates (no heatmap): it has no per-keypoint score, and its points' "
                 "spread is not measured; null rather than a made-up number")
_REQUIRED = ("input_size", "K_input", "keypoint_names", "skeleton_edges")
#: ``hupbench.depth_input`` of every model that reads depth: the input ``depth`` is the model's depth channel
#: (:func:`hupbench.input_geometry.depth_channel`)
DEPTH_INPUT = {"units": "metres", "no_surface": 0.0, "clip_m": DEPTH_CLIP_M, "resize": "nearest"}


def write_metadata(input_size: int, K_input: Any, keypoint_names, skeleton_edges, model_config: dict,
                   run_name: str, git_commit: str, input_modalities: str = "rgb",
                   outputs: tuple[str, ...] = BASE_OUTPUTS,
                   image_statistics: ImageStatistics | None = None, depth_sensor: str | None = None,
                   fit_probe: FitProbe | None = None) -> dict[str, str]:
    """The ``metadata_props`` of an exported model, checked by :func:`read_metadata` (no time stamp: one
    checkpoint, one set of bytes). K_input: (3, 3) intrinsics at the model input, pixels. ``outputs``: the
    graph's outputs (:data:`OUTPUTS`); ``image_statistics``: the out-of-distribution calibration, or None;
    ``depth_sensor``: for a model that reads depth, the depth camera it was trained on (``hupbench.depth_sensor``:
    "none" for the clean z-buffer, or a preset of :mod:`hupbench.core.depth_sensor`); ``fit_probe``: for a model
    that fits, the probe its fits know."""
    props = {
        META + "input_modalities": input_modalities,
        META + "onnx_schema": ONNX_SCHEMA,
        META + "input_size": str(int(input_size)),
        META + "K_input": json.dumps(np.asarray(K_input, dtype=np.float64).tolist()),
        META + "keypoint_names": json.dumps(list(keypoint_names)),
        META + "skeleton_edges": json.dumps([list(e) for e in skeleton_edges]),
        META + "model_config": json.dumps(model_config, sort_keys=True),
        META + "run_name": run_name,
        META + "git_commit": git_commit,
    }
    if input_modalities == "rgb+depth":
        props[META + "depth_input"] = json.dumps(DEPTH_INPUT, sort_keys=True)
    if depth_sensor is not None:
        props[META + "depth_sensor"] = depth_sensor
    if tuple(outputs) != BASE_OUTPUTS:
        props[META + "outputs"] = json.dumps(list(outputs))
    if image_statistics is not None:
        props[META + "image_statistics"] = image_statistics.to_json()
    if fit_probe is not None:
        props[META + "fit_probe"] = fit_probe.to_json()
    read_metadata(props, "the metadata being written")
    return props


def read_metadata(props: dict[str, str], source: str = "model") -> dict[str, Any]:
    """Read and check the ``hupbench.*`` metadata of an exported model from its metadata_props (string to
    string); ``source`` names the file in errors.

    Returns:
        ``{"input_size": int, "K_input": (3, 3) float64, "keypoint_names": tuple of str, "skeleton_edges":
        tuple of (i, j), "model_config": dict ({} when absent), "run_name": str, "git_commit": str,
        "input_modalities": "rgb" or "rgb+depth", "outputs": tuple of str, "image_statistics":
        :class:`ImageStatistics` or None, "depth_sensor": the depth camera a depth model was trained on, None where
        the file does not say (exported before it was recorded), "fit_probe": the probe a fitting model's fits know,
        :class:`hupbench.fits.known_probe.FitProbe`, None where the file does not carry one}``.
    """
    if META + "onnx_schema" not in props:
        raise BadValueError(f"{source} has no hupbench metadata (metadata_props 'hupbench.onnx_schema' is missing): "
                         "not a hupbench ONNX export; predict and eval read models written by `hupbench export CKPT`")
    if props[META + "onnx_schema"] != ONNX_SCHEMA:
        raise BadValueError(f"{source} has hupbench.onnx_schema {props[META + 'onnx_schema']!r}; this hupbench reads "
                            f"{ONNX_SCHEMA!r}")
    missing = [META + key for key in _REQUIRED if META + key not in props]
    if missing:
        raise BadValueError(f"{source} lacks metadata {', '.join(missing)}")

    def load(key: str) -> Any:
        try:
            return json.loads(props[META + key])
        except json.JSONDecodeError as exc:
            raise BadValueError(f"{source}: metadata {META + key} is not JSON ({exc}): {props[META + key][:80]!r}") from None

    try:
        input_size = int(props[META + "input_size"])
    except ValueError:
        input_size = props[META + "input_size"]
    check_int(input_size, f"{source}: metadata hupbench.input_size", *INPUT_SIZE_RANGE)
    K_input = check_intrinsics(load("K_input"), f"{source}: metadata hupbench.K_input")
    names = load("keypoint_names")
    if not isinstance(names, list) or not names or not all(isinstance(n, str) for n in names):
        raise BadValueError(f"{source}: hupbench.keypoint_names must be a non-empty JSON list of strings, got {names!r:.120}")
    edges = load("skeleton_edges")
    if (not isinstance(edges, list) or not all(isinstance(e, list) and len(e) == 2 for e in edges)
            or not all(is_whole(i) and 0 <= i < len(names) for e in edges for i in e)):
        raise BadValueError(f"{source}: hupbench.skeleton_edges must be a JSON list of [i, j] with "
                            f"0 <= i, j < {len(names)}, got {props[META + 'skeleton_edges'][:120]!r}")
    model_config = load("model_config") if META + "model_config" in props else {}
    if not isinstance(model_config, dict):
        raise BadValueError(f"{source}: metadata hupbench.model_config must be a JSON object, got "
                            f"{type(model_config).__name__}")
    modalities = props.get(META + "input_modalities", "rgb")
    if modalities not in INPUT_MODALITIES:
        raise BadValueError(f"{source}: metadata hupbench.input_modalities must be "
                            f"{' or '.join(map(repr, INPUT_MODALITIES))}, got {modalities!r:.80}")
    if modalities == "rgb+depth" and (META + "depth_input" not in props or load("depth_input") != DEPTH_INPUT):
        raise BadValueError(f"{source}: a model that reads depth needs metadata hupbench.depth_input = "
                            f"{json.dumps(DEPTH_INPUT, sort_keys=True)}, got {props.get(META + 'depth_input')!r:.120}")
    channels = model_config.get("input_channels", 3)
    if channels != INPUT_MODALITIES[modalities]:
        raise BadValueError(f"{source}: hupbench.model_config has input_channels {channels!r} but "
                            f"hupbench.input_modalities is {modalities!r} ({INPUT_MODALITIES[modalities]} channels)")
    outputs = load("outputs") if META + "outputs" in props else list(BASE_OUTPUTS)
    if (not isinstance(outputs, list) or outputs[:2] != list(BASE_OUTPUTS) or len(set(outputs)) != len(outputs)
            or not set(outputs) <= set(OUTPUTS)):
        raise BadValueError(f"{source}: metadata hupbench.outputs must list {list(BASE_OUTPUTS)} and then any of "
                            f"{list(OUTPUTS[2:])}, got {props[META + 'outputs'][:120]!r}")
    statistics = props.get(META + "image_statistics")
    sensor = props.get(META + "depth_sensor")
    if sensor is not None and (modalities != "rgb+depth" or sensor not in (NONE, *PRESETS)):
        raise BadValueError(f"{source}: metadata hupbench.depth_sensor is for a model that reads depth and one of "
                            f"{', '.join((NONE, *PRESETS))}, got {sensor!r:.80} on an {modalities} model")
    probe = props.get(META + "fit_probe")
    probe = None if probe is None else FitProbe.from_json(probe, f"{source}: metadata hupbench.fit_probe")
    try:
        fit_settings = model_fit_settings(model_config)
        if model_config.get("hand_templates") is not None:
            check_finite_points(model_config["hand_templates"], ("T", kp.NUM_HAND, 3), "hand_templates")
    except BadValueError as error:
        raise BadValueError(f"{source}: metadata hupbench.model_config: {error}") from None
    return {"depth_sensor": sensor, "fit_probe": probe, "fit_settings": fit_settings, "input_size": input_size,
            "K_input": K_input,
            "keypoint_names": tuple(names), "input_modalities": modalities,
            "skeleton_edges": tuple((int(a), int(b)) for a, b in edges), "model_config": model_config,
            "run_name": props.get(META + "run_name", ""), "git_commit": props.get(META + "git_commit", ""),
            "outputs": tuple(outputs),
            "image_statistics": None if statistics is None else ImageStatistics.from_json(statistics, source)}


def check_io_shapes(inputs: dict[str, list], outputs: dict[str, list], input_size: int, num_keypoints: int,
                    source: str = "model", input_modalities: str = "rgb",
                    declared_outputs: tuple[str, ...] = BASE_OUTPUTS) -> None:
    """The graph's declared input and outputs (name -> dimensions; a name or None for a dynamic axis)
    against the contract and the metadata (``declared_outputs``: its ``hupbench.outputs``): a file whose
    metadata and graph disagree would otherwise fail deep inside onnxruntime, or be drawn with the wrong names."""
    if "image" not in inputs:
        raise BadValueError(f"{source}: the graph has no input 'image' (inputs {sorted(inputs)}); not a hupbench export")
    expected = {"image": ([3, input_size, input_size], f" for the metadata's hupbench.input_size {input_size}")}
    wanted = {"image", "depth"} if input_modalities == "rgb+depth" else {"image"}
    if set(inputs) != wanted:
        raise BadValueError(f"{source}: the graph's inputs are {sorted(inputs)}; hupbench.input_modalities "
                            f"{input_modalities!r} needs {sorted(wanted)}")
    if "depth" in wanted:
        expected["depth"] = ([1, input_size, input_size], f" for the metadata's hupbench.input_size {input_size}")
    for name, width in OUTPUT_WIDTHS.items():
        if name not in outputs:
            raise BadValueError(f"{source}: the graph has no output {name!r} (outputs {sorted(outputs)})")
        expected[name] = ([num_keypoints, width], f" for the {num_keypoints} keypoint names of hupbench.keypoint_names")
    optional = {"confidence": ([num_keypoints], f" for the {num_keypoints} keypoint names of hupbench.keypoint_names"),
                "segmentation": ([input_size, input_size], f" for the metadata's hupbench.input_size {input_size}")}
    for name in (n for n in optional if n in declared_outputs):
        if name not in outputs:
            raise BadValueError(f"{source}: hupbench.outputs declares {name!r} but the graph has no such output "
                                f"(outputs {sorted(outputs)})")
        expected[name] = optional[name]
    for name, (tail, why) in expected.items():
        dims = list(inputs.get(name, outputs.get(name)) or [])
        if len(dims) != 1 + len(tail) or any(isinstance(d, int) and d != t for d, t in zip(dims[1:], tail)):
            shown = ", ".join(str(d) for d in dims)
            raise BadValueError(f"{source}: the graph's {name} is ({shown}), expected "
                                f"(batch, {', '.join(map(str, tail))}){why}")


def check_intrinsics(K: Any, name: str) -> np.ndarray:
    """(3, 3) pinhole intrinsics: finite, fx, fy > 0, last row (0, 0, 1). Returns them as float64."""
    try:
        K = np.asarray(K, dtype=np.float64)
    except (TypeError, ValueError):
        raise BadValueError(f"{name} must be a 3 x 3 matrix of numbers, got {K!r:.80}") from None
    if K.shape != (3, 3):
        raise BadValueError(f"{name} must be (3, 3) intrinsics, got shape {K.shape}")
    if not np.all(np.isfinite(K)):
        raise BadValueError(f"{name} must be finite, got {K.tolist()}")
    if K[0, 0] <= 0 or K[1, 1] <= 0 or not np.allclose(K[2], [0.0, 0.0, 1.0]):
        raise BadValueError(f"{name} must have fx, fy > 0 and last row (0, 0, 1), got {K.tolist()}")
    return K


def _varint(data: bytes, pos: int) -> tuple[int, int]:
    """The base-128 varint at ``data[pos]`` and the position after it (protobuf encoding)."""
    value = shift = 0
    while True:
        byte = data[pos]
        value |= (byte & 0x7F) << shift
        shift, pos = shift + 7, pos + 1
        if byte < 0x80:
            return value, pos


def graph_sha256(model: bytes) -> str:
    """The hex sha256 of the graph inside the bytes of a serialized ONNX model: the payload of ``ModelProto``'s
    field 7 (``GraphProto``) as stored, found by walking the top-level fields of the protobuf wire format
    (https://protobuf.dev/programming-guides/encoding/) without parsing the graph. The metadata (field 14) and the
    other top-level fields are left out, so the digest of a model before its metadata are added is the digest of
    the file written with them. ``model`` must be a well-formed ModelProto (onnxruntime opened it)."""
    digest = hashlib.sha256()
    pos = 0
    while pos < len(model):
        key, pos = _varint(model, pos)
        wire = key & 7
        if wire == 0:
            _, pos = _varint(model, pos)
        elif wire in (1, 5):  # 64-bit and 32-bit fixed
            pos += 8 if wire == 1 else 4
        elif wire == 2:  # length-delimited: bytes, strings and messages
            length, pos = _varint(model, pos)
            if key >> 3 == _GRAPH_FIELD:
                digest.update(model[pos:pos + length])
            pos += length
        # wire types 3 and 4 (group start and end) carry no payload of their own
    return digest.hexdigest()


def check_graph(props: dict[str, str], model: bytes, source: str = "model") -> None:
    """The metadata ``props`` were written for the graph in ``model`` (the file's bytes): their
    ``hupbench.graph_sha256`` is the graph's :func:`graph_sha256`; ``source`` names the file in the error."""
    recorded, actual = props.get(GRAPH_SHA256), graph_sha256(model)
    if recorded != actual:
        found = f"its hupbench.graph_sha256 is {recorded[:12]!r}..." if recorded else "it has no hupbench.graph_sha256"
        raise BadValueError(f"{source}: its hupbench metadata were not written for this graph ({found}, the graph's "
                            f"sha256 is {actual[:12]}...): metadata copied onto another model, or a graph changed "
                            "after export; export the checkpoint again with `hupbench export CKPT`")
