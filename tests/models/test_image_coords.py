import pytest
import torch

from hupbench.models.coords import normalized_to_pixels, pixels_to_normalized


def test_known_values_edges_and_centre():
    # a 256 x 128 image spans [-0.5, 255.5] x [-0.5, 127.5] in OpenCV pixel coordinates
    px = torch.tensor([[-0.5, -0.5], [255.5, 127.5], [127.5, 63.5], [0.0, 0.0]])
    expected = torch.tensor([[-1.0, -1.0], [1.0, 1.0], [0.0, 0.0], [1 / 256 - 1, 1 / 128 - 1]])
    torch.testing.assert_close(pixels_to_normalized(px, width=256, height=128), expected)


def test_round_trip_and_resize_invariance():
    px = torch.rand(3, 29, 2, dtype=torch.float64) * 256
    norm = pixels_to_normalized(px, 256, 256)
    torch.testing.assert_close(normalized_to_pixels(norm, 256, 256), px)
    # the same point in a 224 x 224 resize of the image: (u + 0.5) * s - 0.5
    resized = (px + 0.5) * (224 / 256) - 0.5
    torch.testing.assert_close(pixels_to_normalized(resized, 224, 224), norm)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("width,height", [(256, 256), (64, 48), (1, 2048)])
def test_the_torch_twin_equals_input_geometry(width, height, dtype):
    """hupbench.models.coords is hupbench.input_geometry's formula in torch, value for value."""
    import numpy as np

    from hupbench import input_geometry

    px = (torch.rand(4, 29, 2, dtype=torch.float64) * 1.4 - 0.2) * torch.tensor([width, height])
    norm = torch.rand(4, 29, 2, dtype=torch.float64) * 2.4 - 1.2
    size = np.array([width, height])
    for ours, theirs, points in ((pixels_to_normalized, input_geometry.pixels_to_normalized, px),
                                 (normalized_to_pixels, input_geometry.normalized_to_pixels, norm)):
        got = ours(points.to(dtype), width, height)
        assert got.dtype == dtype
        expected = theirs(points.to(dtype).double().numpy(), size)
        if dtype == torch.float64:
            np.testing.assert_array_equal(got.numpy(), expected)
        else:
            np.testing.assert_allclose(got.numpy(), expected, rtol=1e-6, atol=1e-6)
