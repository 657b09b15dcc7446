"""A frame cache is keyed by the frame files it was built from: a training frame damaged or replaced after
the build is read again, not served from the cache."""

import shutil

import cv2
import numpy as np
import pytest
import torch

from hupbench.data import DataConfig, Placement, ReaderConfig, setup_data


def _train_data(dataset, cache_dir, logs):
    data = DataConfig(ReaderConfig(input_size=32), root=str(dataset), cache_dir=str(cache_dir), batch_size=4)
    return setup_data(data, 0, 0, Placement(1, 0, torch.device("cpu")), progress=False, log=logs.append)


@pytest.fixture
def dataset(tiny_dataset, tmp_path):
    """A copy of the tiny dataset whose frame cache has been built, and that cache's folder."""
    root = shutil.copytree(tiny_dataset, tmp_path / "dataset", ignore=shutil.ignore_patterns("cache"))
    _train_data(root, tmp_path / "cache", [])
    return root, tmp_path / "cache"


def test_a_frame_damaged_after_the_build_is_refused_naming_it(dataset):
    root, cache = dataset
    frame = sorted((root / "train" / "rgb").iterdir())[3]
    frame.write_bytes(np.random.default_rng(0).integers(0, 256, 2000, dtype=np.uint8).tobytes())
    logs = []
    with pytest.raises(ValueError, match=f"^cannot decode {frame} as an image"):
        _train_data(root, cache, logs)
    assert len(logs) == 1 and "stale" in logs[0]


def test_a_frame_replaced_after_the_build_is_read_again(dataset):
    root, cache = dataset
    frames = sorted((root / "train" / "rgb").iterdir())
    shutil.copyfile(frames[7], frames[3])  # another valid frame of the same size in its place
    data = _train_data(root, cache, [])
    batch = data.train_set.__getitems__([3, 7])
    assert torch.equal(batch["image"][0], batch["image"][1])
    expected = cv2.resize(cv2.imread(str(frames[7]))[..., ::-1], (32, 32), interpolation=cv2.INTER_AREA)
    assert np.array_equal(batch["image"][0].numpy(), expected)
