"""Per-pixel segmentation labels of the training data: the stored seg maps as SEGMENT_CLASSES indices on the
depth's pixels (HUPDataset.seg_frame), cached like the frames, in batches when asked, and turned with the depth
by the augmentation."""

import json
import os
import shutil

import cv2
import numpy as np
import pytest
import torch

from hupbench.core.contract import SEGMENT_CLASSES, segment_classes
from hupbench.core.errors import BadValueError
from hupbench.data import BatchAugment, DataConfig, FrameBatches, HUPDataset, Placement, ReaderConfig, setup_data
from hupbench.data.cache import cache_paths, open_frame_cache
from hupbench.data.reader import read_seg
from hupbench.input_geometry import pixels_to_normalized

SIZE = 48  # not the stored 64 px: the resize is not the identity
HAND, PROBE = SEGMENT_CLASSES.index("hand"), SEGMENT_CLASSES.index("probe")


def reader(root, split="train", **config):
    """The split with the clean depth (a hand or probe pixel always has depth there)."""
    return HUPDataset(root, split, ReaderConfig(input_size=SIZE, depth_sensor="none", **config))


def test_seg_frame_is_the_stored_classes_on_the_depth_pixels(tiny_dataset):
    ds = reader(tiny_dataset)
    counts = np.zeros(len(SEGMENT_CLASSES), int)
    for index in (0, 7, 19):
        seg = ds.seg_frame(index)
        stored = read_seg(ds.path(index, "seg"), ds.manifest["image_size"])           # (64, 64) uint8 labels
        expected = cv2.resize(segment_classes(stored, ds.manifest["seg_labels"]), (SIZE, SIZE),
                              interpolation=cv2.INTER_NEAREST)
        assert seg.dtype == np.uint8 and seg.shape == (SIZE, SIZE) and np.array_equal(seg, expected)
        # the arm is "other": no stored label but the hand's and the probe's becomes a class > 0
        resized = cv2.resize(stored, (SIZE, SIZE), interpolation=cv2.INTER_NEAREST)
        assert np.array_equal(seg == HAND, resized == ds.manifest["seg_labels"]["hand"])
        assert np.array_equal(seg == PROBE, resized == ds.manifest["seg_labels"]["probe"])
        depth = ds.depth_frame(index)
        assert (depth[seg > 0] > 0).all()  # every hand or probe pixel lies on a surface of the depth map
        counts += np.bincount(seg.ravel(), minlength=len(SEGMENT_CLASSES))
    assert counts[HAND] > 50 and counts[PROBE] > 10 and counts[0] > 0


def test_seg_cache_equals_seg_frame_and_is_rebuilt_when_its_inputs_change(tiny_dataset, tmp_path):
    ds = reader(tiny_dataset, "val")
    logs = []
    first = open_frame_cache(ds, tmp_path, False, logs.append, modality="seg")
    npy, key = cache_paths(tmp_path, "val", SIZE, "seg")
    assert npy.name == "val_48px_seg.npy" and first.dtype == np.uint8 and first.shape == (len(ds), SIZE, SIZE)
    assert all(np.array_equal(first[i], ds.seg_frame(i)) for i in range(len(ds)))
    assert json.loads(key.read_text())["seg_labels"] == ds.manifest["seg_labels"]
    stamp = npy.stat().st_mtime_ns
    again = open_frame_cache(ds, tmp_path, False, logs.append, modality="seg")
    assert npy.stat().st_mtime_ns == stamp and not logs and np.array_equal(again, first)
    seg_file = ds.path(3, "seg")  # touched: the same bytes, a new modification time
    os.utime(seg_file, ns=(seg_file.stat().st_atime_ns, seg_file.stat().st_mtime_ns + 1))
    try:
        rebuilt = open_frame_cache(ds, tmp_path, False, logs.append, modality="seg")
    finally:
        os.utime(seg_file, ns=(seg_file.stat().st_atime_ns, seg_file.stat().st_mtime_ns - 1))  # tiny_dataset is shared
    assert len(logs) == 1 and "stale" in logs[0] and np.array_equal(rebuilt, first)
    # another class mapping (hand and probe swapped) is another cache
    labels = ds.manifest["seg_labels"]
    ds.manifest = {**ds.manifest, "seg_labels": {**labels, "hand": labels["probe"], "probe": labels["hand"]}}
    swapped = open_frame_cache(ds, tmp_path, False, logs.append, modality="seg")
    assert len(logs) == 2 and np.array_equal(swapped, np.array([0, PROBE, HAND], np.uint8)[first])


def test_batches_carry_seg_only_when_asked(tiny_dataset, tmp_path):
    ds = reader(tiny_dataset)
    indices = [5, 0, 17, 5]
    assert "seg" not in FrameBatches(ds).__getitems__(indices)
    decoded = FrameBatches(ds, with_seg=True).__getitems__(indices)
    cached = FrameBatches(ds, segs=open_frame_cache(ds, tmp_path, False, modality="seg"), with_seg=True)
    for batch in (decoded, cached.__getitems__(indices)):
        assert batch["seg"].dtype == torch.int64 and batch["seg"].shape == (4, SIZE, SIZE)
        assert all(np.array_equal(batch["seg"][row].numpy(), ds.seg_frame(i)) for row, i in enumerate(indices))


def _train_data(root, cache_dir, with_seg):
    data = DataConfig(ReaderConfig(input_size=32), root=str(root), cache_dir=str(cache_dir), batch_size=4)
    return setup_data(data, 0, 0, Placement(1, 0, torch.device("cpu")), progress=False, with_seg=with_seg)


def test_setup_data_caches_seg_for_both_splits_when_asked(tiny_dataset, tmp_path):
    plain = _train_data(tiny_dataset, tmp_path, with_seg=False)
    assert "seg" not in next(iter(plain.train_loader)) and not list(tmp_path.glob("*_seg.*"))
    data = _train_data(tiny_dataset, tmp_path, with_seg=True)
    assert sorted(p.name for p in tmp_path.glob("*_seg.npy")) == ["train_32px_seg.npy", "val_32px_seg.npy"]
    for loader, split in ((data.train_loader, data.train_set), (data.val_loader, data.val_set)):
        batch = next(iter(loader))
        expected = np.stack([split.dataset.seg_frame(i) for i in batch["index"].tolist()])
        assert batch["seg"].dtype == torch.int64 and np.array_equal(batch["seg"].numpy(), expected)


def test_setup_data_with_seg_refuses_a_dataset_without_seg_maps(tiny_dataset, tmp_path):
    copy = shutil.copytree(tiny_dataset, tmp_path / "no_seg", ignore=shutil.ignore_patterns("cache", "seg"))
    manifest = json.loads((copy / "manifest.json").read_text())
    manifest["modalities"] = [m for m in manifest["modalities"] if m != "seg"]
    (copy / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(BadValueError, match="has no seg maps for the train and val split"):
        _train_data(copy, tmp_path / "cache", with_seg=True)
    assert "seg" not in next(iter(_train_data(copy, tmp_path / "cache", with_seg=False).train_loader))


def test_rotation_turns_seg_with_the_depth_and_jitter_leaves_it(tiny_dataset):
    ds = reader(tiny_dataset, input_modalities="rgb+depth", rotate_deg=60.0, photometric=1.0, seed=2)
    indices = [0, 1, 2, 3]
    batch = FrameBatches(ds, with_seg=True).__getitems__(indices)
    out = BatchAugment(ds.config)(dict(batch), epoch=0)
    seg, depth = out["seg"], out["image"][:, 3]
    assert seg.dtype == torch.int64 and seg.shape == (4, SIZE, SIZE)
    assert (seg > 0).sum() > 50 and (depth[seg > 0] > 0).all()  # the labels stayed on their surfaces
    assert set(seg.unique().tolist()) <= {0, HAND, PROBE}
    angles, _ = BatchAugment(ds.config).draws(indices, 0)
    for row in range(4):  # the same turn as cv2's nearest warp with class 0 beyond the border, nearly every pixel
        K = batch["K"][row].double().numpy()
        M = cv2.getRotationMatrix2D((K[0, 2], K[1, 2]), float(np.rad2deg(angles[row])), 1.0)
        ref = cv2.warpAffine(batch["seg"][row].numpy().astype(np.uint8), M, (SIZE, SIZE), flags=cv2.INTER_NEAREST,
                             borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        assert np.mean(seg[row].numpy() == ref) > 0.97
    assert not torch.equal(seg, batch["seg"])  # a real turn
    unturned = BatchAugment(reader(tiny_dataset, photometric=1.0).config)(dict(batch), epoch=0)
    assert unturned["seg"].dtype == torch.int64 and torch.equal(unturned["seg"], batch["seg"])


def test_pixels_turned_in_from_beyond_the_border_are_other():
    """A frame that is hand and 1 m of depth everywhere, turned: the corners come from outside the image."""
    augment = BatchAugment(ReaderConfig(rotate_deg=90.0, seed=5))
    index = next(i for i in range(10) if abs(np.rad2deg(augment.draws([i], 0)[0][0])) > 20)
    uv = torch.tensor([[[31.5, 31.5]]])
    batch = {"image": torch.zeros(1, 64, 64, 3, dtype=torch.uint8), "index": torch.tensor([index]),
             "K": torch.tensor([[[100.0, 0.0, 31.5], [0.0, 100.0, 31.5], [0.0, 0.0, 1.0]]]),
             "keypoints_3d": torch.tensor([[[0.0, 0.0, 0.5]]]), "keypoints_2d_px": uv,
             "keypoints_2d": pixels_to_normalized(uv, 64).float(), "visible": torch.tensor([[True]]),
             "depth": torch.ones(1, 64, 64), "seg": torch.full((1, 64, 64), HAND, dtype=torch.uint8)}
    out = augment(batch, epoch=0)
    seg, depth = out["seg"][0], out["image"][0, 3]
    assert seg.dtype == torch.int64
    assert seg[0, 0] == 0 and seg[63, 63] == 0 and seg[32, 32] == HAND
    assert torch.equal(seg == 0, depth == 0) and 0.05 < (seg == 0).float().mean() < 0.5
