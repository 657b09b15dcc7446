import pytest
import torch

from models.coords import normalized_to_pixels, pixels_to_normalized


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


def test_bad_input():
    with pytest.raises(ValueError, match=r"\(\.\.\., 2\), got \(4, 3\)"):
        pixels_to_normalized(torch.zeros(4, 3), 256, 256)
    with pytest.raises(ValueError, match="width must be a positive int"):
        pixels_to_normalized(torch.zeros(4, 2), 0, 256)
    with pytest.raises(TypeError, match="floating-point"):
        normalized_to_pixels(torch.zeros(4, 2, dtype=torch.int64), 256, 256)
