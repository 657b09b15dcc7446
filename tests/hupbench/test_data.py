import json
import cv2
import numpy as np
import pytest

from conftest import TINY_SPEC
from datagen.camera import project_points
from datagen.dataset.spec import DatasetSpec
from datagen.dataset.writer import generate
from hupbench.data import HUPDataset, ReaderConfig, resize_intrinsics, resize_points, rotate_in_plane


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


@pytest.mark.parametrize("angle_deg", [-30.0, 12.0, 90.0])
def test_rotation_moves_a_drawn_point_where_the_label_goes(angle_deg):
    K = np.array([[240.0, 0, 63.5], [0, 240.0, 63.5], [0, 0, 1]])
    image = np.zeros((128, 128, 3), np.uint8)
    cv2.circle(image, (90, 40), 4, (255, 255, 255), -1)
    point_3d = np.array([[(90 - 63.5) / 240 * 0.6, (40 - 63.5) / 240 * 0.6, 0.6]])
    uv = project_points(point_3d, K)
    rotated, p3, uv_rot = rotate_in_plane(image, point_3d, uv, K, np.deg2rad(angle_deg))
    np.testing.assert_allclose(_bright_spot(rotated[..., 0]), uv_rot[0], atol=0.1)
    # the 3D point turned about the optical axis projects onto the moved label
    np.testing.assert_allclose(project_points(p3, K), uv_rot, atol=1e-9)
    assert p3[0, 2] == pytest.approx(point_3d[0, 2])


def test_items_reproject_exactly_after_resize_and_rotation(tiny_dataset):
    ds = HUPDataset(tiny_dataset, "train", ReaderConfig(input_size=32, rotate_deg=45.0, photometric=0.5))
    assert len(ds) == 20
    for i in (0, 7, 19):
        item = ds[i]
        assert item["image"].shape == (3, 32, 32) and 0.0 <= float(item["image"].min()) <= float(item["image"].max()) <= 1.0
        uv = project_points(item["keypoints_3d"].double().numpy(), item["K"].double().numpy())
        np.testing.assert_allclose(uv, item["keypoints_2d_px"].numpy(), atol=1e-3)
        np.testing.assert_allclose(item["keypoints_2d"].numpy(), (item["keypoints_2d_px"].numpy() + 0.5) / 32 * 2 - 1,
                                   atol=1e-6)
    # the same epoch gives the same draws; another epoch other ones
    a, b = ds[3], ds[3]
    np.testing.assert_array_equal(a["image"].numpy(), b["image"].numpy())
    ds.set_epoch(1)
    assert not np.allclose(ds[3]["keypoints_2d"].numpy(), a["keypoints_2d"].numpy())


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
    with pytest.raises(ValueError, match="input_size must be a whole number from 16 to 2048"):
        ReaderConfig(input_size=8)
