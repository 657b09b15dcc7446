"""The input geometry (hupbench/input_geometry.py): normalised coordinates, inside-the-input, pad-and-resize
as one 3 x 3 map, and the in-plane rotation."""

import cv2
import numpy as np
import pytest

from hupbench.core.camera import project_points, resize_intrinsics, resize_points
from hupbench.input_geometry import (
    InputGeometry,
    apply_affine,
    camera_rotation,
    inside_input,
    normalized_to_pixels,
    pad_and_resize,
    pixels_to_normalized,
    rotation_pixel_map,
)

K = np.array([[480.0, 0.0, 317.5], [0.0, 470.0, 242.25], [0.0, 0.0, 1.0]])
SIZES = [(640, 480, 128), (480, 640, 64), (100, 100, 100), (37, 301, 16), (2000, 3, 256)]


def test_normalised_known_values_and_round_trip():
    """-1 and 1 are the outer edges (half a pixel beyond the first and last centres), 0 the centre; a
    (W, H) size scales each axis by its own side."""
    np.testing.assert_allclose(pixels_to_normalized(np.array([[-0.5, -0.5], [63.5, 63.5], [31.5, 0.0]]), 64),
                               [[-1.0, -1.0], [1.0, 1.0], [0.0, 1 / 64 - 1]])
    np.testing.assert_allclose(pixels_to_normalized(np.array([255.5, 127.5]), (256, 128)), [1.0, 1.0])
    uv = np.random.default_rng(0).uniform(-20, 300, (3, 29, 2))
    np.testing.assert_allclose(normalized_to_pixels(pixels_to_normalized(uv, 128), 128), uv, atol=1e-9)
    np.testing.assert_allclose(normalized_to_pixels(pixels_to_normalized(uv, (256, 96)), (256, 96)), uv, atol=1e-9)


def test_normalised_coordinates_survive_a_resize():
    """The same point in a resize of the image keeps its normalised coordinates."""
    uv = np.random.default_rng(1).uniform(0, 256, (29, 2))
    np.testing.assert_allclose(pixels_to_normalized(resize_points(uv, 224 / 256), 224), pixels_to_normalized(uv, 256),
                               atol=1e-12)


def test_inside_input_is_the_half_open_pixel_span():
    uv = np.array([[-0.5, 0.0], [-0.51, 0.0], [63.49, 63.49], [63.5, 0.0], [10.0, 64.0]])
    np.testing.assert_array_equal(inside_input(uv, 64), [True, False, True, False, False])
    assert inside_input(np.zeros((2, 5, 2)), 64).shape == (2, 5)


def test_torch_tensors_pass_through_the_arithmetic():
    torch = pytest.importorskip("torch")
    uv = torch.tensor([[-0.5, 63.4], [70.0, 3.0]], dtype=torch.float64)
    assert isinstance(pixels_to_normalized(uv, 64), torch.Tensor)
    np.testing.assert_allclose(pixels_to_normalized(uv, 64).numpy(), pixels_to_normalized(uv.numpy(), 64))
    assert inside_input(uv, 64).tolist() == [True, False]


@pytest.mark.parametrize("width,height,S", SIZES)
def test_geometry_matrix_equals_pad_then_resize(width, height, S):
    """The 3 x 3 map against resize_points, a separate formula of the same pad-then-resize; its inverse;
    and projection: projecting through the mapped K lands where the mapped pixel is."""
    g = InputGeometry(width, height, S)
    offset = (g.pad_left, g.pad_top)
    uv = np.random.default_rng(0).uniform(-50, 700, (4, 7, 2))
    np.testing.assert_allclose(apply_affine(g.image_to_input, uv), resize_points(uv, g.scale, offset), atol=1e-9)
    np.testing.assert_allclose(g.intrinsics_to_input(K), resize_intrinsics(K, g.scale, offset), atol=1e-9)
    np.testing.assert_allclose(g.input_to_image @ g.image_to_input, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(apply_affine(g.input_to_image, apply_affine(g.image_to_input, uv)), uv, atol=1e-9)
    np.testing.assert_allclose(g.intrinsics_to_image(g.intrinsics_to_input(K)), K, atol=1e-9)
    points = np.random.default_rng(1).uniform([-0.2, -0.2, 0.3], [0.2, 0.2, 1.0], (9, 3))
    np.testing.assert_allclose(project_points(points, g.intrinsics_to_input(K)),
                               apply_affine(g.image_to_input, project_points(points, K)), atol=1e-8)


def test_geometry_known_values():
    """200 x 100 to 50 px: L = 200, s = 0.25, pad_top = 50: u_in = 0.25 (u + 0.5) - 0.5,
    v_in = 0.25 (v + 50.5) - 0.5; the normalised corners of the input come back outside the image."""
    g = InputGeometry(200, 100, 50)
    np.testing.assert_allclose(g.image_to_input, [[0.25, 0.0, -0.375], [0.0, 0.25, 12.125], [0.0, 0.0, 1.0]])
    np.testing.assert_allclose(g.normalized_to_input_px([[-1, -1], [1, 1], [0, 0]]),
                               [[-0.5, -0.5], [49.5, 49.5], [24.5, 24.5]])
    np.testing.assert_allclose(g.normalized_to_image_px([[-1, -1], [1, 1]]), [[-0.5, -50.5], [199.5, 149.5]])


@pytest.mark.parametrize("dtype,pad", [(np.float32, 0.5), (np.uint8, 128)])
def test_pad_and_resize_pads_centred_then_resizes(dtype, pad):
    """A 60 x 20 image (L = 60, pad_top = 20) to 30 px: rows 0..9 and 20..29 are the padding, the image
    sits between them; a square image of the input size comes back unchanged."""
    image = np.full((20, 60, 3), 1 if dtype is np.uint8 else 0.25, dtype)
    out, g = pad_and_resize(image, 30, pad)
    assert out.shape == (30, 30, 3) and out.dtype == dtype and (g.pad_left, g.pad_top, g.scale) == (0, 20, 0.5)
    np.testing.assert_array_equal(out[:10], pad)
    np.testing.assert_array_equal(out[20:], pad)
    np.testing.assert_array_equal(out[10:20], image[0, 0, 0])
    same, g = pad_and_resize(image[:, :20], 20)
    assert same is image[:, :20] or np.array_equal(same, image[:, :20])
    assert g.as_dict() == {"side": 20, "pad_left": 0, "pad_top": 0, "scale": 1.0}
    grey, _ = pad_and_resize(np.zeros((8, 16), dtype), 16, pad)
    assert grey.shape == (16, 16)


def test_rotation_pixel_map_is_opencvs_and_batches():
    angles, centres = np.array([0.3, -1.2]), np.array([[31.5, 20.0], [5.0, 60.0]])
    maps = rotation_pixel_map(angles, centres)
    assert maps.shape == (2, 3, 3)
    for a, c, m in zip(angles, centres, maps):
        np.testing.assert_allclose(m[:2], cv2.getRotationMatrix2D(tuple(c), np.rad2deg(a), 1.0), atol=1e-12)
        np.testing.assert_allclose(m[2], [0.0, 0.0, 1.0])
        np.testing.assert_allclose(rotation_pixel_map(a, c), m)
    uv = np.random.default_rng(2).uniform(0, 64, (2, 5, 2))
    np.testing.assert_allclose(apply_affine(maps, uv)[1], apply_affine(maps[1], uv[1]), atol=1e-12)
    np.testing.assert_allclose(apply_affine(maps[0], centres[0]), centres[0], atol=1e-12)


def test_camera_rotation_matches_the_pixel_map():
    """Turning the camera-frame points and projecting lands where the pixel map sends the projection
    (square pixels, about the principal point); a quarter turn moves the image right (+u) to up (-v)."""
    K_square = np.array([[300.0, 0.0, 40.0], [0.0, 300.0, 25.0], [0.0, 0.0, 1.0]])
    points = np.random.default_rng(3).uniform([-0.1, -0.1, 0.4], [0.1, 0.1, 0.9], (7, 3))
    for angle in (0.4, -2.5):
        R = camera_rotation(angle)
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
        np.testing.assert_allclose(project_points(points @ R.T, K_square),
                                   apply_affine(rotation_pixel_map(angle, K_square[:2, 2]), project_points(points, K_square)),
                                   atol=1e-9)
    np.testing.assert_allclose(apply_affine(rotation_pixel_map(np.pi / 2, (0.0, 0.0)), [1.0, 0.0]), [0.0, -1.0],
                               atol=1e-12)
    assert camera_rotation(np.zeros(4)).shape == (4, 3, 3)
