"""The frame cache and the per-batch augmentation against the reference reader (hupbench.data)."""

import json

import cv2
import numpy as np
import pytest
import torch

from hupbench.data import HUPDataset, ReaderConfig
from hupbench.training.frame_cache import BatchAugment, CachedFrames, cache_paths, model_images, open_frame_cache

SIZE = 48


def project(points, K):
    """(B, N, 3) camera-frame points -> (B, N, 2) pixels with (B, 3, 3) intrinsics, float64."""
    uvw = points.double() @ K.double().transpose(1, 2)
    return uvw[..., :2] / uvw[..., 2:]


@pytest.fixture(scope="module")
def cached(tiny_dataset, tmp_path_factory):
    ds = HUPDataset(tiny_dataset, "train", ReaderConfig(input_size=SIZE))
    return ds, CachedFrames(ds, cache_dir=tmp_path_factory.mktemp("cache"), progress=False, log=lambda *_: None)


def test_cached_frames_equal_the_reference_reader(cached):
    ds, frames = cached
    batch = frames.__getitems__([5, 0, 17, 3])
    assert batch["image"].dtype == torch.uint8 and batch["image"].shape == (4, SIZE, SIZE, 3)
    images = model_images(batch["image"], torch.device("cpu"))
    for row, index in enumerate([5, 0, 17, 3]):
        ref = ds[index]
        assert torch.equal(images[row], ref["image"])  # the same decode and resize, bit for bit
        assert int(batch["index"][row]) == index and int(batch["frame_id"][row]) == int(ref["frame_id"])
        for key in ("keypoints_3d", "keypoints_2d_px", "K", "visible"):
            assert torch.equal(batch[key][row], ref[key]), key
        assert torch.allclose(batch["keypoints_2d"][row], ref["keypoints_2d"], atol=1e-6)


def test_rotation_turns_labels_exactly_as_the_reference(tiny_dataset, cached):
    _, frames = cached
    config = ReaderConfig(input_size=SIZE, rotate_deg=45.0, seed=3)
    reference = HUPDataset(tiny_dataset, "train", config)
    augment = BatchAugment(config.rotate_deg, 0.0, config.seed)
    indices = list(range(len(frames)))
    for epoch in (0, 4):
        reference.set_epoch(epoch)
        out = augment(frames.__getitems__(indices), epoch)
        for row in indices:
            ref = reference[row]
            assert torch.allclose(out["keypoints_3d"][row], ref["keypoints_3d"], atol=1e-7)
            assert torch.allclose(out["keypoints_2d_px"][row], ref["keypoints_2d_px"], atol=1e-4)
            assert torch.equal(out["visible"][row], ref["visible"])
        # the label geometry: the turned 3D points project onto the turned 2D points
        err = (project(out["keypoints_3d"], out["K"]) - out["keypoints_2d_px"].double()).abs().max()
        assert err < 1e-3
        angles, _ = augment.draws(indices, epoch)
        assert np.abs(np.rad2deg(angles)).max() <= 45.0 and np.abs(angles).min() >= 0 and np.std(angles) > 0.1


def test_rotated_image_matches_cv2_warp(cached):
    """kornia's warp of the batch equals the reference's cv2.warpAffine (reflect-101 border) per pixel."""
    _, frames = cached
    augment = BatchAugment(30.0, 0.0, seed=1)
    batch = frames.__getitems__([0, 1, 2])
    out = augment(batch, epoch=0)
    angles, _ = augment.draws([0, 1, 2], 0)
    for row in range(3):
        K = batch["K"][row].double().numpy()
        M = cv2.getRotationMatrix2D((K[0, 2], K[1, 2]), float(np.rad2deg(angles[row])), 1.0)
        ref = cv2.warpAffine(batch["image"][row].numpy(), M, (SIZE, SIZE), flags=cv2.INTER_LINEAR,
                             borderMode=cv2.BORDER_REFLECT_101)
        ours = out["image"][row].permute(1, 2, 0).numpy() * 255.0
        diff = np.abs(ours - ref.astype(np.float64))
        assert diff.max() < 1.0   # cv2 rounds to uint8: at most half a level apart (a wrong turn: 24-160)


def test_colour_jitter_is_statistically_the_reference(tiny_dataset, cached):
    """Per-image brightness and saturation changes have the reference's spread (ColorJiggle, p = 0.5)."""
    _, frames = cached
    config = ReaderConfig(input_size=SIZE, photometric=0.5, seed=0)
    reference, plain = HUPDataset(tiny_dataset, "train", config), HUPDataset(tiny_dataset, "train",
                                                                           ReaderConfig(input_size=SIZE))
    augment = BatchAugment(0.0, config.photometric, config.seed)
    n = len(frames)

    def stats(images, base):                           # (B, 3, S, S) -> per-image mean ratio, channel spread
        return (images.mean(dim=(1, 2, 3)) / base.mean(dim=(1, 2, 3))).numpy(), images.std(dim=1).mean(dim=(1, 2)).numpy()

    base = torch.stack([plain[i]["image"] for i in range(n)])
    ours_ratio, ours_sat, ref_ratio, ref_sat = [], [], [], []
    for epoch in range(8):
        reference.set_epoch(epoch)
        out = augment(frames.__getitems__(list(range(n))), epoch)["image"]
        ref = torch.stack([reference[i]["image"] for i in range(n)])
        r, sat = stats(out, base)
        ours_ratio.append(r), ours_sat.append(sat)
        r, sat = stats(ref, base)
        ref_ratio.append(r), ref_sat.append(sat)
    ours_ratio, ref_ratio = np.concatenate(ours_ratio), np.concatenate(ref_ratio)
    ours_sat, ref_sat = np.concatenate(ours_sat), np.concatenate(ref_sat)
    assert abs(ours_ratio.mean() - ref_ratio.mean()) < 0.05
    assert 0.7 < ours_ratio.std() / ref_ratio.std() < 1.4 and ours_ratio.std() > 0.05
    assert abs(ours_sat.mean() - ref_sat.mean()) / ref_sat.mean() < 0.15
    # nothing leaves [0, 1]
    assert 0.0 <= float(out.min()) and float(out.max()) <= 1.0


def test_draws_depend_only_on_seed_epoch_and_item():
    augment = BatchAugment(15.0, 0.5, seed=7)
    a_angles, a_factors = augment.draws([3, 9, 4], epoch=2)
    b_angles, b_factors = augment.draws([4, 3], epoch=2)
    assert a_angles[0] == b_angles[1] and a_angles[2] == b_angles[0]
    assert np.array_equal(a_factors[[2, 0]], b_factors)
    c_angles, _ = augment.draws([3, 9, 4], epoch=3)
    assert not np.array_equal(a_angles, c_angles)
    with pytest.raises(ValueError, match="rotate_deg must be in \\[0, 180\\], got 200"):
        BatchAugment(200, 0.0)


def test_cache_is_built_once_and_rebuilt_when_stale(tiny_dataset, tmp_path):
    with np.load(tiny_dataset / "val" / "annotations.npz") as data:
        ids = data["frame_id"]
    logs = []
    first = open_frame_cache(tiny_dataset, "val", 32, ids, "jpg", "a" * 64, cache_dir=tmp_path, progress=False,
                             log=logs.append)
    npy, key = cache_paths(tmp_path, "val", 32)
    assert first.shape == (len(ids), 32, 32, 3) and json.loads(key.read_text())["manifest_sha256"] == "a" * 64
    stamp = npy.stat().st_mtime_ns
    again = open_frame_cache(tiny_dataset, "val", 32, ids, "jpg", "a" * 64, cache_dir=tmp_path, progress=False,
                             log=logs.append)
    assert npy.stat().st_mtime_ns == stamp and not logs and np.array_equal(first, again)
    # another dataset (manifest hash) or a broken key file: rebuilt, said so, same content for the same images
    open_frame_cache(tiny_dataset, "val", 32, ids, "jpg", "b" * 64, cache_dir=tmp_path, progress=False,
                     log=logs.append)
    assert len(logs) == 1 and "stale" in logs[0] and json.loads(key.read_text())["manifest_sha256"] == "b" * 64
    key.write_text("{not json")
    rebuilt = open_frame_cache(tiny_dataset, "val", 32, ids, "jpg", "b" * 64, cache_dir=tmp_path, progress=False,
                               log=logs.append)
    assert len(logs) == 2 and np.array_equal(rebuilt, first)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["val_32px.json", "val_32px.npy"]  # no temporary left


def test_a_killed_build_leaves_no_trusted_cache(tiny_dataset, tmp_path, monkeypatch):
    import hupbench.training.frame_cache as frames_module

    with np.load(tiny_dataset / "val" / "annotations.npz") as data:
        ids = data["frame_id"]

    def broken(path, size, image_size=None):
        raise OSError(f"disk gone reading {path}")

    monkeypatch.setattr(frames_module, "_decode_resized", broken)
    with pytest.raises(OSError, match="disk gone"):
        open_frame_cache(tiny_dataset, "val", 32, ids, "jpg", "c" * 64, cache_dir=tmp_path, progress=False)
    assert list(tmp_path.iterdir()) == []
