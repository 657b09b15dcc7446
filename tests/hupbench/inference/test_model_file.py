"""The model-file contract (hupbench/inference/model_file.py): one metadata writer and reader, one graph
check."""

import json

import numpy as np
import pytest

from hupbench.core import keypoints as kp
from hupbench.inference.model_file import check_io_shapes, read_metadata, write_metadata
from hupbench.input_geometry import INPUT_SIZE_RANGE

K = np.array([[480.0, 0.0, 317.5], [0.0, 470.0, 242.25], [0.0, 0.0, 1.0]])


def _props(**changes):
    props = write_metadata(64, K, kp.KEYPOINT_NAMES, kp.SKELETON_EDGES, {"name": "hopenet"}, "run", "0" * 40)
    props.update(changes)
    return {k: v for k, v in props.items() if v is not None}


def test_metadata_round_trips():
    meta = read_metadata(_props(), "m.onnx")
    assert meta["input_size"] == 64 and meta["keypoint_names"] == kp.KEYPOINT_NAMES
    assert meta["skeleton_edges"] == tuple(tuple(e) for e in kp.SKELETON_EDGES)
    assert meta["model_config"] == {"name": "hopenet"} and meta["run_name"] == "run"
    np.testing.assert_array_equal(meta["K_input"], K)
    assert read_metadata(_props(**{"hupbench.model_config": None}))["model_config"] == {}


@pytest.mark.parametrize("changes,needles", [
    ({"hupbench.onnx_schema": None}, ("m.onnx", "no hupbench metadata", "not a hupbench ONNX export")),
    ({"hupbench.onnx_schema": "2"}, ("onnx_schema '2'",)),
    ({"hupbench.input_size": "big"}, ("hupbench.input_size", "whole number", "'big'")),
    ({"hupbench.input_size": str(INPUT_SIZE_RANGE[0] - 1)}, ("hupbench.input_size", "whole number from 16 to 2048", "15")),
    ({"hupbench.input_size": None, "hupbench.K_input": None}, ("lacks metadata hupbench.input_size, hupbench.K_input",)),
    ({"hupbench.K_input": "[[1, 2"}, ("hupbench.K_input", "not JSON")),
    ({"hupbench.K_input": json.dumps([[0, 0, 1], [0, 1, 1], [0, 0, 1]])}, ("hupbench.K_input", "fx, fy > 0")),
    ({"hupbench.K_input": json.dumps([[1e400, 0, 1], [0, 1, 1], [0, 0, 1]])}, ("hupbench.K_input", "finite")),
    ({"hupbench.K_input": json.dumps([["a"]])}, ("hupbench.K_input", "3 x 3")),
    ({"hupbench.keypoint_names": "[]"}, ("keypoint_names", "non-empty")),
    ({"hupbench.skeleton_edges": "[[0, 29]]"}, ("skeleton_edges", "0 <= i, j < 29")),
    ({"hupbench.skeleton_edges": "[[true, 1]]"}, ("skeleton_edges",)),
    ({"hupbench.model_config": "[1]"}, ("model_config", "JSON object")),
    ({"hupbench.input_modalities": "depth"}, ("hupbench.input_modalities", "'rgb' or 'rgb+depth'", "'depth'")),
    ({"hupbench.input_modalities": "rgb+depth"}, ("reads depth needs metadata hupbench.depth_input", "metres")),
    ({"hupbench.model_config": json.dumps({"name": "hopenet", "input_channels": 4})},
     ("input_channels 4", "hupbench.input_modalities is 'rgb'")),
    ({"hupbench.model_config": json.dumps({"name": "hopenet", "hand_templates": [[[0.0, 0.0, 0.5]] * 20]})},
     ("metadata hupbench.model_config", "hand_templates must be (T, 21, 3), got (1, 20, 3)")),
    ({"hupbench.model_config": json.dumps({"name": "hopenet", "hand_templates": [[[0.0, 0.0, "x"]] * 21]})},
     ("metadata hupbench.model_config", "hand_templates must be an array of numbers")),
])
def test_metadata_errors_name_the_key(changes, needles):
    with pytest.raises(ValueError) as info:
        read_metadata(_props(**changes), "m.onnx")
    for needle in needles:
        assert needle in str(info.value), (needle, str(info.value))


def test_depth_metadata_round_trips():
    props = write_metadata(64, K, kp.KEYPOINT_NAMES, kp.SKELETON_EDGES, {"name": "hupnet", "input_channels": 4}, "run",
                           "0" * 40, "rgb+depth")
    assert json.loads(props["hupbench.depth_input"]) == {"units": "metres", "no_surface": 0.0, "clip_m": 2.0,
                                                         "resize": "nearest"}
    assert read_metadata(props)["input_modalities"] == "rgb+depth"
    assert read_metadata(_props(**{"hupbench.input_modalities": None}))["input_modalities"] == "rgb"  # older files


def test_writer_refuses_what_the_reader_would():
    with pytest.raises(ValueError, match="input_size must be a whole number from 16"):
        write_metadata(8, K, kp.KEYPOINT_NAMES, kp.SKELETON_EDGES, {}, "run", "")


@pytest.mark.parametrize("inputs,outputs,needles", [
    ({"image": ["batch", 3, 64, 64]}, {"points3d": ["batch", 29, 3], "points2d": ["batch", 29, 2]}, None),
    ({"image": [None, 3, None, None]}, {"points3d": [None, None, 3], "points2d": [None, None, 2]}, None),
    ({"x": [1]}, {}, ("m.onnx", "no input 'image'")),
    ({"image": [1, 3, 64, 64]}, {"points3d": [1, 29, 3]}, ("no output 'points2d'",)),
    ({"image": [1, 3, 128, 128]}, {"points3d": [1, 29, 3], "points2d": [1, 29, 2]},
     ("image is (1, 3, 128, 128)", "(batch, 3, 64, 64)", "input_size 64")),
    ({"image": [1, 3, 64, 64]}, {"points3d": [1, 21, 3], "points2d": [1, 21, 2]},
     ("points3d is (1, 21, 3)", "(batch, 29, 3)", "29 keypoint names")),
    ({"image": [1, 3, 64, 64]}, {"points3d": [1, 29, 3], "points2d": [1, 29, 3]}, ("points2d", "(batch, 29, 2)")),
    ({"image": [3, 64, 64]}, {"points3d": [1, 29, 3], "points2d": [1, 29, 2]}, ("image is (3, 64, 64)",)),
    ({"image": [1, 3, 64, 64], "depth": [1, 1, 64, 64]}, {"points3d": [1, 29, 3], "points2d": [1, 29, 2]},
     ("inputs are ['depth', 'image']", "'rgb' needs ['image']")),
])
def test_graph_shapes_against_the_metadata(inputs, outputs, needles, modalities="rgb"):
    if needles is None:
        check_io_shapes(inputs, outputs, 64, 29, "m.onnx", modalities)
        return
    with pytest.raises(ValueError) as info:
        check_io_shapes(inputs, outputs, 64, 29, "m.onnx", modalities)
    for needle in needles:
        assert needle in str(info.value), (needle, str(info.value))


@pytest.mark.parametrize("inputs,needles", [
    ({"image": ["batch", 3, 64, 64], "depth": ["batch", 1, 64, 64]}, None),
    ({"image": [1, 3, 64, 64]}, ("inputs are ['image']", "'rgb+depth' needs ['depth', 'image']")),
    ({"image": [1, 3, 64, 64], "depth": [1, 3, 64, 64]}, ("depth is (1, 3, 64, 64)", "(batch, 1, 64, 64)")),
])
def test_a_depth_model_has_a_depth_input(inputs, needles):
    test_graph_shapes_against_the_metadata(inputs, {"points3d": [1, 29, 3], "points2d": [1, 29, 2]}, needles,
                                           "rgb+depth")


def test_graph_sha256_is_the_graphs_alone(tmp_path):
    """The digest is the sha256 of the serialized graph as stored (known answer), unchanged by the metadata and the
    other top-level fields, changed by any edit to the graph; check_graph names a file whose metadata came from
    another graph, or that has no digest."""
    import hashlib

    import onnx
    from helpers.dot_model import make_dot_model

    from hupbench.core.errors import BadValueError
    from hupbench.inference.model_file import GRAPH_SHA256, check_graph, graph_sha256

    proto = onnx.load(str(make_dot_model(tmp_path / "dot.onnx")))
    data = proto.SerializeToString()
    assert graph_sha256(data) == hashlib.sha256(proto.graph.SerializeToString()).hexdigest()
    props = {p.key: p.value for p in proto.metadata_props}
    assert props[GRAPH_SHA256] == graph_sha256(data)
    check_graph(props, data, "dot.onnx")
    proto.metadata_props.add(key="note", value="x" * 1000)
    proto.doc_string, proto.producer_name = "edited", "someone"
    assert graph_sha256(proto.SerializeToString()) == props[GRAPH_SHA256]
    proto.graph.node[0].name = "renamed"
    with pytest.raises(BadValueError, match=r"^m.onnx: its hupbench metadata were not written for this graph \(its "
                                            r"hupbench.graph_sha256 is '[0-9a-f]{12}'..., the graph's sha256 is "):
        check_graph(props, proto.SerializeToString(), "m.onnx")
    with pytest.raises(BadValueError, match=r"\(it has no hupbench.graph_sha256, "):
        check_graph({k: v for k, v in props.items() if k != GRAPH_SHA256}, data, "m.onnx")
