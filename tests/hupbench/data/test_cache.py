"""The frame cache (hupbench/data/cache.py): the same frames as decoding each file, built once, rebuilt when
what it was built from changes, never trusted half-built."""

import json
import os

import numpy as np
import pytest
import torch

from hupbench.data import FrameBatches, HUPDataset, ReaderConfig, open_frame_cache
from hupbench.data.cache import cache_paths

SIZE = 48


def test_cached_frames_equal_the_decoded_frames(tiny_dataset, tmp_path):
    ds = HUPDataset(tiny_dataset, "train", ReaderConfig(input_size=SIZE))
    cached = FrameBatches(ds, open_frame_cache(ds, cache_dir=tmp_path, progress=False))
    decoded = FrameBatches(ds)
    indices = [5, 0, 17, 3, 5]
    a, b = cached.__getitems__(indices), decoded.__getitems__(indices)
    assert a["image"].dtype == torch.uint8 and a["image"].shape == (5, SIZE, SIZE, 3)
    assert a.keys() == b.keys() and all(torch.equal(a[key], b[key]) for key in a)  # bit for bit
    assert a["index"].tolist() == indices
    for row, index in enumerate(indices):
        item = ds[index]
        assert torch.equal(a["image"][row].permute(2, 0, 1).float() / 255.0, item["image"])
        assert all(torch.equal(a[key][row], item[key]) for key in item if key != "image")


def test_cache_is_built_once_and_rebuilt_when_stale(tiny_dataset, tmp_path):
    ds = HUPDataset(tiny_dataset, "val", ReaderConfig(input_size=32))
    logs = []
    first = open_frame_cache(ds, cache_dir=tmp_path, progress=False, log=logs.append)
    npy, key = cache_paths(tmp_path, "val", 32)
    assert first.shape == (len(ds), 32, 32, 3) and json.loads(key.read_text())["frames"] == len(ds)
    stamp = npy.stat().st_mtime_ns
    again = open_frame_cache(ds, cache_dir=tmp_path, progress=False, log=logs.append)
    assert npy.stat().st_mtime_ns == stamp and not logs and np.array_equal(first, again)
    # a frame file touched (the same bytes, a new modification time) or a broken key file: rebuilt, said
    # so, the same content for the same images
    frame = ds.path(3)
    os.utime(frame, ns=(frame.stat().st_atime_ns, frame.stat().st_mtime_ns + 1))
    try:
        rebuilt = open_frame_cache(ds, cache_dir=tmp_path, progress=False, log=logs.append)
    finally:
        os.utime(frame, ns=(frame.stat().st_atime_ns, frame.stat().st_mtime_ns - 1))  # tiny_dataset is shared
    assert len(logs) == 1 and "stale" in logs[0] and np.array_equal(rebuilt, first)
    key.write_text("{not json")
    rebuilt = open_frame_cache(ds, cache_dir=tmp_path, progress=False, log=logs.append)
    assert len(logs) == 2 and np.array_equal(rebuilt, first)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["val_32px.json", "val_32px.npy"]  # no temporary left


def test_a_killed_build_leaves_no_trusted_cache(tiny_dataset, tmp_path, monkeypatch):
    ds = HUPDataset(tiny_dataset, "val", ReaderConfig(input_size=32))

    def broken(index):
        raise OSError(f"disk gone reading {ds.path(index)}")

    monkeypatch.setattr(ds, "frame", broken)
    with pytest.raises(OSError, match="disk gone"):
        open_frame_cache(ds, cache_dir=tmp_path, progress=False)
    assert list(tmp_path.iterdir()) == []
