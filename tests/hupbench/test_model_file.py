"""The model-file contract (hupbench/inference/model_file.py): one metadata writer and reader, one graph
check, and the input geometry as one 3 x 3 map."""

import json

import numpy as np
import pytest

from datagen import keypoints as kp
from datagen.camera import project_points, resize_intrinsics, resize_points
from hupbench.inference.model_file import (
    INPUT_SIZE_RANGE,
    InputGeometry,
    check_io_shapes,
    read_metadata,
    write_metadata,
)

K = np.array([[480.0, 0.0, 317.5], [0.0, 470.0, 242.25], [0.0, 0.0, 1.0]])
SIZES = [(640, 480, 128), (480, 640, 64), (100, 100, 100), (37, 301, 16), (2000, 3, 256)]


@pytest.mark.parametrize("width,height,S", SIZES)
def test_geometry_matrix_equals_pad_then_resize(width, height, S):
    """The 3 x 3 map (built with datagen.camera.resize_intrinsics) against resize_points, a separate formula
    of the same pad-then-resize; its inverse; and projection: projecting through the mapped K lands where
    the mapped pixel is."""
    g = InputGeometry(width, height, S)
    offset = (g.pad_left, g.pad_top)
    uv = np.random.default_rng(0).uniform(-50, 700, (4, 7, 2))
    np.testing.assert_allclose(g.image_to_input_px(uv), resize_points(uv, g.scale, offset), atol=1e-9)
    np.testing.assert_allclose(g.intrinsics_to_input(K), resize_intrinsics(K, g.scale, offset), atol=1e-9)
    np.testing.assert_allclose(g.input_to_image @ g.image_to_input, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(g.input_to_image_px(g.image_to_input_px(uv)), uv, atol=1e-9)
    np.testing.assert_allclose(g.intrinsics_to_image(g.intrinsics_to_input(K)), K, atol=1e-9)
    points = np.random.default_rng(1).uniform([-0.2, -0.2, 0.3], [0.2, 0.2, 1.0], (9, 3))
    np.testing.assert_allclose(project_points(points, g.intrinsics_to_input(K)),
                               g.image_to_input_px(project_points(points, K)), atol=1e-8)


def test_geometry_matrix_known_values():
    """200 x 100 to 50 px: L = 200, s = 0.25, pad_top = 50; u_in = 0.25 (u + 0.5) - 0.5,
    v_in = 0.25 (v + 50.5) - 0.5."""
    np.testing.assert_allclose(InputGeometry(200, 100, 50).image_to_input,
                               [[0.25, 0.0, -0.375], [0.0, 0.25, 12.125], [0.0, 0.0, 1.0]])


def test_normalised_coordinates_map_to_pixel_centres():
    """x_n = -1 and 1 are the outer edges of the input (half a pixel beyond the first and last centres); the
    image's corners come back through the inverse."""
    g = InputGeometry(200, 100, 50)  # L = 200, pad_top = 50, s = 0.25
    np.testing.assert_allclose(g.normalized_to_input_px([[-1, -1], [1, 1], [0, 0]]),
                               [[-0.5, -0.5], [49.5, 49.5], [24.5, 24.5]])
    np.testing.assert_allclose(g.normalized_to_image_px([[-1, -1], [1, 1]]), [[-0.5, -50.5], [199.5, 149.5]])


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
])
def test_metadata_errors_name_the_key(changes, needles):
    with pytest.raises(ValueError) as info:
        read_metadata(_props(**changes), "m.onnx")
    for needle in needles:
        assert needle in str(info.value), (needle, str(info.value))


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
])
def test_graph_shapes_against_the_metadata(inputs, outputs, needles):
    if needles is None:
        check_io_shapes(inputs, outputs, 64, 29, "m.onnx")
        return
    with pytest.raises(ValueError) as info:
        check_io_shapes(inputs, outputs, 64, 29, "m.onnx")
    for needle in needles:
        assert needle in str(info.value), (needle, str(info.value))
