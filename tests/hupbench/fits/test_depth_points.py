"""hupbench.fits.depth_points: a depth map's pixels unprojected and projected back land on their own pixels; the
sample of measured points holds only wanted points, in one order for every frame."""

import numpy as np
import pytest
from hupbench.fits.depth_points import MIN_PROJECTION_Z_M, input_points2d, sample_points, unproject_depth
from hupbench.input_geometry import normalized_to_pixels

S = 8
K = np.array([[20.0, 0.0, 3.5], [0.0, 24.0, 4.0], [0.0, 0.0, 1.0]])


def test_a_pixel_unprojected_and_projected_back_is_that_pixel():
    depth = np.random.default_rng(0).uniform(0.3, 0.9, (2, S, S)).astype(np.float32)
    points = unproject_depth(depth, K)                                                         # (2, S * S, 3)
    np.testing.assert_allclose(points[..., 2], depth.reshape(2, -1))
    v, u = np.mgrid[0:S, 0:S]
    pixels = normalized_to_pixels(input_points2d(points, K, S), S)
    np.testing.assert_allclose(pixels, np.broadcast_to(np.stack([u.ravel(), v.ravel()], -1), pixels.shape), atol=1e-4)


def test_a_point_behind_the_camera_projects_as_if_just_in_front():
    behind, near = np.array([[0.01, 0.02, -0.5]]), np.array([[0.01, 0.02, MIN_PROJECTION_Z_M]])
    np.testing.assert_array_equal(input_points2d(behind, K, S), input_points2d(near, K, S))


@pytest.mark.parametrize("max_points", [3, 64])
def test_the_sample_holds_the_wanted_points_in_one_order_for_every_frame(max_points):
    points = np.arange(2 * 10 * 3, dtype=np.float64).reshape(2, 10, 3)
    wanted = np.zeros((2, 10), dtype=bool)
    wanted[:, [1, 4, 6, 9]] = True
    chosen, weight = sample_points(points, wanted, max_points)
    count = min(max_points, 10)
    assert chosen.shape == (2, count, 3) and weight.shape == (2, count)
    assert weight.sum(1).tolist() == [min(count, 4)] * 2
    rows = chosen[..., 0] // 3 % 10                                                  # the point's index in its frame
    assert rows[0].tolist() == rows[1].tolist()
    assert set(rows[0][weight[0] > 0].astype(int).tolist()) <= {1, 4, 6, 9}
    assert weight[0, :min(count, 4)].all(), "the padding comes last"
