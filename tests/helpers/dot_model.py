"""A tiny hand-written ONNX graph that follows the ONNX contract and whose answer is known.

It finds the most red pixel of the input (largest R - G), puts keypoint k at that pixel plus a fixed
offset (normalised units), and places keypoint k at a fixed depth z_k on the ray of its 2D point through
K_input (a pinhole-consistent network). Images with one red dot then have a known prediction in original
pixels, up to half a model-input pixel.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

from hupbench.core import keypoints as kp

S = 32
K_TRAIN = np.array([[60.0, 0.0, 16.0], [0.0, 60.0, 16.0], [0.0, 0.0, 1.0]])
N = kp.NUM_KEYPOINTS
_rng = np.random.default_rng(7)
OFFSETS_NORM = np.concatenate([np.zeros((1, 2)), _rng.uniform(-0.3, 0.3, size=(N - 1, 2))]).astype(np.float32)
DEPTHS_M = _rng.uniform(0.4, 0.9, size=N).astype(np.float32)
RED = (0, 0, 255)  # BGR for cv2.imwrite


def _const(name, array, dtype=np.float32):
    return helper.make_node("Constant", [], [name], value=numpy_helper.from_array(np.asarray(array, dtype), name))


def seal(model: onnx.ModelProto) -> onnx.ModelProto:
    """``model`` with hupbench.graph_sha256, as the exporter ties its metadata to its graph."""
    from hupbench.inference.model_file import GRAPH_SHA256, graph_sha256

    model.metadata_props.add(key=GRAPH_SHA256, value=graph_sha256(model.SerializeToString()))
    return model


def make_dot_model(path: Path, metadata: dict[str, str] | None = None, sealed: bool = True,
                   reads_depth: bool = False) -> Path:
    """Write the known-answer ONNX graph described in this module's docstring, with ``metadata`` (default
    :func:`contract_metadata`) and, where they are hupbench's and ``sealed``, the graph's sha256 (:func:`seal`);
    ``reads_depth``: a second input ``depth`` (B, 1, S, S) that the graph reads and multiplies by 0."""
    nodes = [
        _const("starts0", [0], np.int64), _const("ends1", [1], np.int64), _const("ends2", [2], np.int64),
        _const("axis1", [1], np.int64), _const("axis2", [2], np.int64),
        _const("flat_shape", [0, -1], np.int64), _const("side", [S], np.int64),
        helper.make_node("Slice", ["image", "starts0", "ends1", "axis1"], ["red"]),
        helper.make_node("Slice", ["image", "ends1", "ends2", "axis1"], ["green"]),
        helper.make_node("Sub", ["red", "green"], ["redness"]),  # (B, 1, S, S): 0 on grey, 1 on pure red
        helper.make_node("Reshape", ["redness", "flat_shape"], ["flat"]),  # (B, S * S)
        helper.make_node("ArgMax", ["flat"], ["index"], axis=1, keepdims=1),  # (B, 1) int64
        helper.make_node("Mod", ["index", "side"], ["u_int"]),
        helper.make_node("Div", ["index", "side"], ["v_int"]),
        helper.make_node("Concat", ["u_int", "v_int"], ["uv_int"], axis=1),  # (B, 2)
        helper.make_node("Cast", ["uv_int"], ["uv"], to=TensorProto.FLOAT),
        _const("two_over_s", 2.0 / S), _const("norm_shift", 1.0 / S - 1.0),
        helper.make_node("Mul", ["uv", "two_over_s"], ["uv_scaled"]),
        helper.make_node("Add", ["uv_scaled", "norm_shift"], ["xy_norm"]),  # (2u + 1) / S - 1
        helper.make_node("Unsqueeze", ["xy_norm", "axis1"], ["xy_norm3"]),  # (B, 1, 2)
        _const("offsets", OFFSETS_NORM[None]),
        helper.make_node("Add", ["xy_norm3", "offsets"], ["points2d"]),  # (B, N, 2)
        _const("half_s", S / 2.0), _const("px_shift", S / 2 - 0.5 - K_TRAIN[:2, 2]),
        helper.make_node("Mul", ["points2d", "half_s"], ["p_half"]),
        helper.make_node("Add", ["p_half", "px_shift"], ["uv_centred"]),  # u_in - cx
        _const("z_over_f", np.stack([DEPTHS_M / K_TRAIN[0, 0], DEPTHS_M / K_TRAIN[1, 1]], axis=1)[None]),
        helper.make_node("Mul", ["uv_centred", "z_over_f"], ["xy3"]),  # (B, N, 2) metres
        _const("zero", 0.0), _const("depths", DEPTHS_M[None, :, None]),
        helper.make_node("Slice", ["xy3", "starts0", "ends1", "axis2"], ["x3"]),
        helper.make_node("Mul", ["x3", "zero"], ["zeros"]),
        helper.make_node("Add", ["zeros", "depths"], ["z3"]),  # (B, N, 1)
        helper.make_node("Concat", ["xy3", "z3"], ["points3d" if not reads_depth else "points3d_rgb"], axis=2),
    ]
    inputs = [helper.make_tensor_value_info("image", TensorProto.FLOAT, ["batch", 3, S, S])]
    if reads_depth:
        inputs.append(helper.make_tensor_value_info("depth", TensorProto.FLOAT, ["batch", 1, S, S]))
        nodes += [_const("depth_axes", [1, 2, 3], np.int64),
                  helper.make_node("ReduceMean", ["depth", "depth_axes"], ["depth_mean"], keepdims=1),  # (B, 1, 1, 1)
                  helper.make_node("Squeeze", ["depth_mean", "depth_axes"], ["depth_b"]),  # (B,)
                  _const("depth_shape", [-1, 1, 1], np.int64),
                  helper.make_node("Reshape", ["depth_b", "depth_shape"], ["depth_b11"]),  # (B, 1, 1)
                  helper.make_node("Mul", ["depth_b11", "zero"], ["depth_zero"]),
                  helper.make_node("Add", ["points3d_rgb", "depth_zero"], ["points3d"])]
    graph = helper.make_graph(
        nodes, "dot",
        inputs,
        [helper.make_tensor_value_info("points2d", TensorProto.FLOAT, ["batch", N, 2]),
         helper.make_tensor_value_info("points3d", TensorProto.FLOAT, ["batch", N, 3])],
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)])
    model.ir_version = 9
    if metadata is None:
        metadata = contract_metadata()
    helper.set_model_props(model, metadata)
    if sealed and "hupbench.onnx_schema" in metadata:
        seal(model)
    onnx.checker.check_model(model)
    onnx.save(model, path)
    return path


def contract_metadata(**changes) -> dict[str, str]:
    meta = {
        "hupbench.onnx_schema": "1", "hupbench.input_size": str(S), "hupbench.K_input": json.dumps(K_TRAIN.tolist()),
        "hupbench.keypoint_names": json.dumps(list(kp.KEYPOINT_NAMES)),
        "hupbench.skeleton_edges": json.dumps([list(e) for e in kp.SKELETON_EDGES]),
        "hupbench.model_config": json.dumps({"name": "dot"}), "hupbench.run_name": "dot-run",
        "hupbench.git_commit": "0" * 40,
    }
    meta.update(changes)
    return {k: v for k, v in meta.items() if v is not None}


def depth_metadata(depth_median_m: tuple[float, float] = (0.4, 0.8)) -> dict[str, str]:
    """:func:`contract_metadata` of a model that reads depth (``make_dot_model(..., reads_depth=True)``), with a
    calibration whose training frames' median depths span ``depth_median_m`` metres and whose image-statistics
    threshold flags no image."""
    from hupbench.inference.image_statistics import calibrate
    from hupbench.inference.model_file import DEPTH_INPUT

    calibration = calibrate(np.random.default_rng(0).normal(size=(20, 10)), np.full((2, 10), 1e3), "val",
                            np.array(depth_median_m))
    return contract_metadata(**{"hupbench.input_modalities": "rgb+depth",
                                "hupbench.depth_input": json.dumps(DEPTH_INPUT, sort_keys=True),
                                "hupbench.model_config": json.dumps({"name": "dot", "input_channels": 4}),
                                "hupbench.image_statistics": calibration.to_json()})


def dot_image(width: int, height: int, dot_uv: tuple[int, int], gray: bool = False) -> np.ndarray:
    """Black BGR image (or grey-scale) with one pure red pixel."""
    if gray:
        return np.full((height, width), 40, dtype=np.uint8)
    image = np.zeros((height, width, 3), dtype=np.uint8)
    image[dot_uv[1], dot_uv[0]] = RED
    return image


def photo_like(width: int, height: int, seed: int = 0) -> np.ndarray:
    """BGR uint8 with gradients, noise and shapes: JPEG-typical content, not from the dataset."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:height, 0:width].astype(np.float32)
    image = np.stack([xx / width * 200, yy / height * 180, (xx + yy) / (width + height) * 150 + 50], axis=2)
    image += rng.normal(0, 12, size=image.shape)
    image = np.clip(image, 0, 255).astype(np.uint8)
    cv2.circle(image, (width // 3, height // 2), height // 5, (30, 160, 220), -1)
    cv2.rectangle(image, (width // 2, height // 4), (width - 20, height - 30), (200, 90, 40), -1)
    cv2.ellipse(image, (width // 2, height // 2), (width // 6, height // 9), 30, 0, 360, (240, 240, 240), 3)
    return image
