"""hupbench.fits.depth_points: a depth map's pixels unprojected and projected back land on their own pixels; the
sample of measured points holds only wanted points, in one order for every frame."""

import numpy as np
import pytest
from hupbench.fits.depth_points import (MIN_PROJECTION_Z_M, input_points2d, sample_points, surface_pixels,
                                        unproject_pixels)
from hupbench.input_geometry import normalized_to_pixels

S = 8
K = np.array([[20.0, 0.0, 3.5], [0.0, 24.0, 4.0], [0.0, 0.0, 1.0]])


def test_a_pixel_unprojected_and_projected_back_is_that_pixel():
    depth = np.random.default_rng(0).uniform(0.3, 0.9, (2, S, S)).astype(np.float32)
    points = np.stack([unproject_pixels(d, K, np.arange(S * S)) for d in depth])           # (2, S * S, 3)
    np.testing.assert_allclose(points[..., 2], depth.reshape(2, -1))
    v, u = np.mgrid[0:S, 0:S]
    pixels = normalized_to_pixels(input_points2d(points, K, S), S)
    np.testing.assert_allclose(pixels, np.broadcast_to(np.stack([u.ravel(), v.ravel()], -1), pixels.shape), atol=1e-4)


def test_a_point_behind_the_camera_projects_as_if_just_in_front():
    behind, near = np.array([[0.01, 0.02, -0.5]]), np.array([[0.01, 0.02, MIN_PROJECTION_Z_M]])
    np.testing.assert_array_equal(input_points2d(behind, K, S), input_points2d(near, K, S))


@pytest.mark.parametrize("max_points", [3, 100])
def test_the_sample_holds_the_wanted_points_in_one_order_for_every_frame(max_points):
    depth = np.stack([np.full((S, S), 0.5), np.full((S, S), 0.7)])
    wanted = np.zeros((2, S * S), dtype=bool)
    wanted[:, [1, 12, 30, 63]] = True
    chosen, weight = sample_points(depth, K, wanted, max_points)
    count = min(max_points, S * S)
    assert chosen.shape == (2, count, 3) and weight.shape == (2, count)
    assert weight.sum(1).tolist() == [min(count, 4)] * 2
    u, v = np.round(normalized_to_pixels(input_points2d(chosen, K, S), S)).astype(int).transpose(2, 0, 1)
    rows = v * S + u                                                                 # the point's pixel in its frame
    real = weight[0] > 0
    assert rows[0][real].tolist() == rows[1][real].tolist()
    assert set(rows[0][real].tolist()) <= {1, 12, 30, 63}
    assert (chosen[0, real, 2] == 0.5).all() and (chosen[1, real, 2] == 0.7).all(), "each frame's own depth"
    assert weight[0, :min(count, 4)].all(), "the padding comes last"


def test_the_pixels_with_a_surface_are_those_with_depth_among_the_allowed():
    depth = np.zeros((1, S, S))
    depth[0, 2, 3] = depth[0, 5, 1] = 0.4
    allowed = np.zeros((1, S, S), dtype=bool)
    allowed[0, 5, 1] = allowed[0, 6, 6] = True
    assert np.flatnonzero(surface_pixels(depth)[0]).tolist() == [2 * S + 3, 5 * S + 1]
    assert np.flatnonzero(surface_pixels(depth, allowed)[0]).tolist() == [5 * S + 1]
