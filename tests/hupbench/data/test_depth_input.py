"""The depth channel of data.reader.input_modalities=rgb+depth: read from the dataset's depth PNGs, resized and
turned to the nearest pixel (every value a real surface's), cached like the frames, never colour-jittered."""

import cv2
import numpy as np
import pytest
import torch

from hupbench.core.errors import BadValueError
from hupbench.data import FrameBatches, HUPDataset, ReaderConfig, open_frame_cache
from hupbench.data.augment import BatchAugment, model_images
from hupbench.data.reader import read_depth
from hupbench.input_geometry import DEPTH_CLIP_M, depth_channel

SIZE = 64


def rgbd(root, split="train", **augment):
    return HUPDataset(root, split, ReaderConfig(input_size=SIZE, input_modalities="rgb+depth", **augment))


def test_the_fourth_channel_is_the_stored_depth_in_metres(tiny_dataset):
    ds, rgb = rgbd(tiny_dataset), HUPDataset(tiny_dataset, "train", ReaderConfig(input_size=SIZE))
    item = ds[3]
    assert item["image"].shape == (4, SIZE, SIZE) and torch.equal(item["image"][:3], rgb[3]["image"])
    stored = read_depth(ds.path(3, "depth"), ds.manifest["image_size"])            # (256, 256) uint16
    metres = depth_channel(stored, ds.manifest["depth_scale_m"])
    channel = item["image"][3].numpy()
    # nearest: every value of the resized map is one of the stored map's, background stays 0
    assert set(np.unique(channel)) <= set(np.unique(metres))
    assert 0.3 < channel[channel > 0].min() and channel.max() < 1.0 and (channel == 0).mean() > 0.3
    # the depth under a visible hand keypoint's pixel lies within a few cm of that keypoint's depth
    uv = item["keypoints_2d_px"][:21].round().long().clamp(0, SIZE - 1).numpy()
    z = item["keypoints_3d"][:21, 2].numpy()
    seen = item["visible"][:21].numpy() & (channel[uv[:, 1], uv[:, 0]] > 0)
    assert seen.sum() >= 5
    assert np.median(np.abs(channel[uv[seen, 1], uv[seen, 0]] - z[seen])) < 0.03


def test_depth_channel_clips_and_keeps_background():
    depth = np.array([[0, 5000, 65535]], dtype=np.uint16)
    assert depth_channel(depth, 1e-4).tolist() == [[0.0, np.float32(0.5), np.float32(DEPTH_CLIP_M)]]


def test_cached_depth_equals_the_decoded_depth(tiny_dataset, tmp_path):
    ds = rgbd(tiny_dataset)
    cached = FrameBatches(ds, open_frame_cache(ds, tmp_path, False), open_frame_cache(ds, tmp_path, False, modality="depth"))
    indices = [4, 0, 11, 4]
    a, b = cached.__getitems__(indices), FrameBatches(ds).__getitems__(indices)
    assert a["depth"].dtype == torch.float32 and a["depth"].shape == (4, SIZE, SIZE)
    assert a.keys() == b.keys() and all(torch.equal(a[key], b[key]) for key in a)
    assert torch.equal(model_images(a["image"], torch.device("cpu"), depth=a["depth"])[0], ds[4]["image"])


def test_rotation_turns_depth_to_the_nearest_pixel_and_jitter_leaves_it(tiny_dataset):
    ds = rgbd(tiny_dataset, rotate_deg=30.0, photometric=1.0)
    batch = FrameBatches(ds).__getitems__([0, 1, 2, 3])
    out = BatchAugment(ds.config)(dict(batch), epoch=0)
    assert out["image"].shape == (4, 4, SIZE, SIZE) and "depth" not in out
    gaps = []
    for row in range(4):
        before, after = batch["depth"][row], out["image"][row, 3]
        assert set(after.unique().tolist()) <= set(before.unique().tolist()) | {0.0}  # no blended depths
        # the surface moved with the labels: the rotated keypoints' depth under them as before
        uv = out["keypoints_2d_px"][row, :21].round().long().clamp(0, SIZE - 1)
        seen = out["visible"][row, :21] & (after[uv[:, 1], uv[:, 0]] > 0)
        gaps.append(after[uv[seen, 1], uv[seen, 0]] - out["keypoints_3d"][row, :21, 2][seen])
    gaps = torch.cat(gaps)
    assert len(gaps) >= 10 and gaps.abs().median() < 0.03
    angles, _ = BatchAugment(ds.config).draws([0, 1, 2, 3], 0)
    for row in range(4):  # the same turn as cv2's nearest warp with 0 beyond the border, nearly every pixel
        K = batch["K"][row].double().numpy()
        M = cv2.getRotationMatrix2D((K[0, 2], K[1, 2]), float(np.rad2deg(angles[row])), 1.0)
        ref = cv2.warpAffine(batch["depth"][row].numpy(), M, (SIZE, SIZE), flags=cv2.INTER_NEAREST,
                             borderMode=cv2.BORDER_CONSTANT, borderValue=0.0)
        assert np.mean(out["image"][row, 3].numpy() == ref) > 0.97  # depth not turned: 0.82 (measured, first frame)
    jitter_only = BatchAugment(rgbd(tiny_dataset, photometric=1.0).config)(dict(batch), epoch=0)
    assert torch.equal(jitter_only["image"][:, 3], batch["depth"])
    assert not torch.equal(jitter_only["image"][:, :3], model_images(batch["image"], torch.device("cpu")))


def test_a_dataset_without_depth_is_refused(tiny_dataset, tmp_path):
    import json
    import shutil

    copy = tmp_path / "no_depth"
    shutil.copytree(tiny_dataset, copy, ignore=shutil.ignore_patterns("cache"))
    manifest = json.loads((copy / "manifest.json").read_text())
    manifest["modalities"] = [m for m in manifest["modalities"] if m != "depth"]
    (copy / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(BadValueError, match="has no depth maps .*input_modalities=rgb\\+depth needs them"):
        rgbd(copy)
