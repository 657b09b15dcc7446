"""The training augmentation (hupbench/data/augment.py): the in-plane rotation of image and labels, the
colour jitter, and draws that depend only on (seed, epoch, item)."""

import cv2
import numpy as np
import pytest
import torch

from hupbench.data import BatchAugment, FrameBatches, HUPDataset, ReaderConfig
from hupbench.input_geometry import pixels_to_normalized

SIZE = 48


def project(points, K):
    """(B, N, 3) camera-frame points -> (B, N, 2) pixels with (B, 3, 3) intrinsics, float64."""
    uvw = points.double() @ K.double().transpose(1, 2)
    return uvw[..., :2] / uvw[..., 2:]


@pytest.fixture(scope="module")
def frames(tiny_dataset):
    ds = HUPDataset(tiny_dataset, "train", ReaderConfig(input_size=SIZE))
    return FrameBatches(ds)


def _spot_batch(angle_index):
    """One 64 px frame, black but for a white disc at (40, 20) px, whose label is the disc's centre."""
    image = np.zeros((1, 64, 64, 3), np.uint8)
    cv2.circle(image[0], (40, 20), 3, (255, 255, 255), -1)
    K = torch.tensor([[[100.0, 0.0, 31.5], [0.0, 100.0, 31.5], [0.0, 0.0, 1.0]]])
    point = torch.tensor([[[(40 - 31.5) / 100 * 0.5, (20 - 31.5) / 100 * 0.5, 0.5]]])
    uv = torch.tensor([[[40.0, 20.0]]])
    return {"image": torch.from_numpy(image), "index": torch.tensor([angle_index]), "K": K, "keypoints_3d": point,
            "keypoints_2d_px": uv, "keypoints_2d": pixels_to_normalized(uv, 64).float(),
            "visible": torch.tensor([[True]])}


@pytest.mark.parametrize("index", [0, 1, 2])
def test_rotation_moves_a_drawn_point_where_the_label_goes(index):
    augment = BatchAugment(ReaderConfig(rotate_deg=90.0, seed=5))
    out = augment(_spot_batch(index), epoch=0)
    grey = out["image"][0, 0].numpy()
    ys, xs = np.mgrid[:64, :64]
    spot = np.array([(xs * grey).sum(), (ys * grey).sum()]) / grey.sum()
    np.testing.assert_allclose(spot, out["keypoints_2d_px"][0, 0].numpy(), atol=0.1)
    # the turned 3D point projects onto the turned label, and the normalised label follows it
    np.testing.assert_allclose(project(out["keypoints_3d"], out["K"])[0, 0], spot, atol=0.1)
    np.testing.assert_allclose(out["keypoints_2d"].numpy(), pixels_to_normalized(out["keypoints_2d_px"].numpy(), 64),
                               atol=1e-6)
    assert abs(np.rad2deg(augment.draws([index], 0)[0][0])) > 5  # a real turn, not the identity


def test_rotated_labels_stay_consistent_on_a_dataset(frames):
    augment = BatchAugment(ReaderConfig(input_size=SIZE, rotate_deg=45.0, seed=3))
    indices = list(range(len(frames)))
    plain = frames.__getitems__(indices)
    for epoch in (0, 4):
        out = augment(frames.__getitems__(indices), epoch)
        err = (project(out["keypoints_3d"], out["K"]) - out["keypoints_2d_px"].double()).abs().max()
        assert err < 1e-3
        # depth and distance to the optical axis are kept; points that leave the input are not visible
        torch.testing.assert_close(out["keypoints_3d"][..., 2], plain["keypoints_3d"][..., 2])
        inside = ((out["keypoints_2d_px"] >= -0.5) & (out["keypoints_2d_px"] < SIZE - 0.5)).all(-1)
        assert torch.equal(out["visible"], plain["visible"] & inside)
        angles, _ = augment.draws(indices, epoch)
        assert np.abs(np.rad2deg(angles)).max() <= 45.0 and np.std(angles) > 0.1


def test_rotated_image_matches_cv2_warp(frames):
    """kornia's warp of the batch equals cv2.warpAffine (reflect-101 border) of the same map, per pixel."""
    augment = BatchAugment(ReaderConfig(rotate_deg=30.0, seed=1))
    batch = frames.__getitems__([0, 1, 2])
    out = augment(batch, epoch=0)
    angles, _ = augment.draws([0, 1, 2], 0)
    for row in range(3):
        K = batch["K"][row].double().numpy()
        M = cv2.getRotationMatrix2D((K[0, 2], K[1, 2]), float(np.rad2deg(angles[row])), 1.0)
        ref = cv2.warpAffine(batch["image"][row].numpy(), M, (SIZE, SIZE), flags=cv2.INTER_LINEAR,
                             borderMode=cv2.BORDER_REFLECT_101)
        ours = out["image"][row].permute(1, 2, 0).numpy() * 255.0
        assert np.abs(ours - ref.astype(np.float64)).max() < 1.0  # cv2 rounds to uint8 (a wrong turn: 24-160)


def test_colour_jitter_known_values_and_range(frames):
    grey = torch.full((2, 3, 4, 4), 0.5)
    order = np.arange(4)
    identity = torch.tensor([[1.0, 1.0, 1.0, 0.0]] * 2)
    assert torch.allclose(BatchAugment._jitter(grey, identity, order), grey)
    brighter = torch.tensor([[1.2, 1.0, 1.0, 0.0], [0.7, 1.0, 1.0, 0.0]])
    out = BatchAugment._jitter(grey, brighter, order)
    assert torch.allclose(out[:, :, 0, 0], torch.tensor([[0.7] * 3, [0.2] * 3]))
    augment = BatchAugment(ReaderConfig(photometric=0.5, seed=0))
    _, factors = augment.draws(list(range(200)), epoch=0)
    assert factors[:, :3].min() >= 0.8 and factors[:, :3].max() <= 1.2 and np.abs(factors[:, 3]).max() <= 0.025
    assert factors[:, :3].std() > 0.1
    images = augment(frames.__getitems__(list(range(len(frames)))), epoch=0)["image"]
    assert 0.0 <= float(images.min()) and float(images.max()) <= 1.0


def test_without_augmentation_the_batch_is_the_frames(frames):
    batch = frames.__getitems__([4, 1])
    out = BatchAugment(ReaderConfig())(batch, epoch=3)
    assert torch.equal(out["image"], batch["image"].permute(0, 3, 1, 2).float() / 255.0)
    for key in ("keypoints_3d", "keypoints_2d", "keypoints_2d_px", "visible", "K"):
        assert out[key] is batch[key]


def test_draws_depend_only_on_seed_epoch_and_item():
    augment = BatchAugment(ReaderConfig(rotate_deg=15.0, photometric=0.5, seed=7))
    a_angles, a_factors = augment.draws([3, 9, 4], epoch=2)
    b_angles, b_factors = augment.draws([4, 3], epoch=2)
    assert a_angles[0] == b_angles[1] and a_angles[2] == b_angles[0]
    assert np.array_equal(a_factors[[2, 0]], b_factors)
    c_angles, _ = augment.draws([3, 9, 4], epoch=3)
    assert not np.array_equal(a_angles, c_angles)
