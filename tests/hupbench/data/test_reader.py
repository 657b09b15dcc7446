"""The dataset reader (hupbench/data/reader.py): frames at the input size, labels in the input image, and
the checks of the ``data.reader`` config node."""

import json

import cv2
import numpy as np
import pytest
import torch

from hupbench.core.camera import project_points, resize_intrinsics, resize_points
from hupbench.data import HUPDataset, ReaderConfig, model_images
from hupbench.input_geometry import pixels_to_normalized


def _bright_spot(image):
    """Intensity-weighted centroid of a grey image (x, y)."""
    image = image.astype(np.float64)
    ys, xs = np.mgrid[: image.shape[0], : image.shape[1]]
    return np.array([(xs * image).sum(), (ys * image).sum()]) / image.sum()


def test_resize_moves_a_drawn_point_where_the_label_goes():
    image = np.zeros((256, 256), np.uint8)
    point = np.array([100.0, 60.0])
    cv2.circle(image, (100, 60), 6, 255, -1)
    small = cv2.resize(image, (64, 64), interpolation=cv2.INTER_AREA)
    np.testing.assert_allclose(_bright_spot(small), resize_points(point[None], 0.25)[0], atol=0.05)
    K = resize_intrinsics(np.array([[480.0, 0, 128], [0, 480.0, 128], [0, 0, 1]]), 0.5)
    np.testing.assert_allclose(K, [[240, 0, 63.75], [0, 240, 63.75], [0, 0, 1]])


def test_items_reproject_exactly_after_resize(tiny_dataset):
    ds = HUPDataset(tiny_dataset, "train", ReaderConfig(input_size=32, rotate_deg=45.0, photometric=0.5))
    assert len(ds) == 20
    for i in (0, 7, 19):
        item = ds[i]
        frame = cv2.resize(cv2.imread(str(ds.path(i)))[..., ::-1], (32, 32), interpolation=cv2.INTER_AREA)
        # un-augmented whatever the config's augmentation: the decoded frame resized, as float in [0, 1]
        assert torch.equal(item["image"], torch.from_numpy(frame.copy()).permute(2, 0, 1).float() / 255.0)
        assert torch.equal(item["image"], model_images(torch.from_numpy(ds.frame(i))[None], torch.device("cpu"))[0])
        uv = project_points(item["keypoints_3d"].double().numpy(), item["K"].double().numpy())
        np.testing.assert_allclose(uv, item["keypoints_2d_px"].numpy(), atol=1e-3)
        np.testing.assert_allclose(item["keypoints_2d"].numpy(),
                                   pixels_to_normalized(item["keypoints_2d_px"].double().numpy(), 32), atol=1e-6)
        assert int(item["frame_id"]) == int(ds.ann["frame_id"][i])


def test_reader_rejects_bad_input(tiny_dataset, tmp_path):
    with pytest.raises(FileNotFoundError, match="no manifest.json"):
        HUPDataset(tmp_path, "train")
    with pytest.raises(ValueError, match="split must be one of"):
        HUPDataset(tiny_dataset, "dev")
    no_val = tmp_path / "no_val"
    no_val.mkdir()
    manifest = json.loads((tiny_dataset / "manifest.json").read_text())
    manifest["counts"]["val"] = 0
    manifest["layout"]["shape"][0] -= 1  # one grasp fewer: a consistent dataset without validation frames
    (no_val / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(ValueError, match="split 'val' .* is empty"):
        HUPDataset(no_val, "val")


@pytest.mark.parametrize("field,value,message", [
    ("input_size", 8, "data.reader.input_size must be a whole number from 16 to 2048, got 8"),
    ("input_size", 100_000, "data.reader.input_size must be a whole number from 16 to 2048, got 100000"),
    ("input_size", 64.0, "data.reader.input_size must be a whole number from 16 to 2048, got 64.0"),
    ("rotate_deg", -5, r"data.reader.rotate_deg must be a finite number in \[0, 180\], got -5"),
    ("rotate_deg", float("nan"), r"data.reader.rotate_deg must be a finite number in \[0, 180\], got nan"),
    ("photometric", 1.5, r"data.reader.photometric must be a finite number in \[0, 1\], got 1.5"),
    ("photometric", True, r"data.reader.photometric must be a finite number in \[0, 1\], got True"),
    ("seed", -1, "data.reader.seed must be a whole number >= 0, got -1"),
    ("input_modalities", "depth", r"data.reader.input_modalities must be 'rgb' or 'rgb\+depth', got 'depth'"),
    ("input_modalities", ["rgb"], r"data.reader.input_modalities must be 'rgb' or 'rgb\+depth', got \['rgb'\]"),
])
def test_reader_config_checks_each_field(field, value, message):
    with pytest.raises(ValueError, match=f"^{message}$"):
        ReaderConfig(**{field: value})
    assert ReaderConfig(input_size=2048, rotate_deg=180, photometric=1.0, seed=2**40).rotate_deg == 180
