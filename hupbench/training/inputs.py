"""The training run's inputs: the dataset read through the contract, the frame cache, the loaders and their threads."""

from __future__ import annotations

from pathlib import Path
from typing import Any, NamedTuple
from omegaconf import DictConfig

import numpy as np
import torch

from hupbench.config import build
from hupbench.training.schedule import EpochSampler
from datagen.errors import BadValueError


class TrainData(NamedTuple):
    """What :func:`setup_data` builds: the splits, their loaders and the per-batch augmentation.

    ``augment`` is None for the reference JPEG reader (it augments per item in its workers).
    """

    train_set: Any
    val_set: Any
    sampler: EpochSampler
    train_loader: Any
    val_loader: Any
    bn_loader: Any
    augment: Any


def _bounded_threads(_worker_id: int) -> None:
    """Loader workers decode or gather with one thread each: OpenCV and OpenMP pools in every worker
    oversubscribe the machine (the issue 12 measurement: load 140-170 on 16 cores)."""
    import cv2

    cv2.setNumThreads(1)
    torch.set_num_threads(1)


def setup_data(cfg: DictConfig, world: int, rank: int, device: torch.device, log=print) -> TrainData:
    """The training and validation data of a run (``data.pipeline``: cache or jpeg).

    cache (default): frames decoded and resized once into a memory-mapped frame cache
    (:mod:`hupbench.training.frame_cache`), batches gathered in one call, augmentation per batch on ``device``.
    jpeg: the reference reader, a JPEG decoded and augmented per item in the loader workers.
    """
    from hupbench.data import HUPDataset
    from hupbench.training.frame_cache import BatchAugment, CachedFrames, collate_batch

    root = Path(cfg.data.root)
    reader = build(cfg.data.reader)
    pipeline = cfg.data.get("pipeline", "cache")
    if pipeline not in ("cache", "jpeg"):
        raise BadValueError(f"data.pipeline must be 'cache' or 'jpeg', got {pipeline!r}")
    plain = type(reader)(input_size=reader.input_size, rotate_deg=0.0, photometric=0.0, seed=reader.seed)
    train_set = HUPDataset(root, cfg.data.train_split, reader if pipeline == "jpeg" else plain)
    val_set = HUPDataset(root, cfg.data.val_split, plain)
    bn_set = HUPDataset(root, cfg.data.train_split, plain) if pipeline == "jpeg" else train_set
    augment = None
    extra = {}
    if pipeline == "cache":
        show = bool(cfg.train.progress) and rank == 0
        cache_dir = cfg.data.get("cache_dir")
        train_frames = CachedFrames(train_set, cache_dir=cache_dir, progress=show, log=log)
        val_frames = CachedFrames(val_set, cache_dir=cache_dir, progress=show, log=log)
        augment = BatchAugment(reader.rotate_deg, reader.photometric, reader.seed)
        train_set, val_set, bn_set = train_frames, val_frames, train_frames
        extra = {"collate_fn": collate_batch}
    workers = int(cfg.data.num_workers)
    loader_args = {"batch_size": int(cfg.data.batch_size), "num_workers": workers,
                   "pin_memory": device.type == "cuda", "worker_init_fn": _bounded_threads if workers else None,
                   # the reference reader's workers must see set_epoch: they are forked anew each epoch
                   "persistent_workers": workers > 0 and pipeline == "cache", **extra}
    sampler = EpochSampler(len(train_set), int(cfg.data.batch_size), int(cfg.seed), world, rank)
    train_loader = torch.utils.data.DataLoader(train_set, sampler=sampler, drop_last=True, **loader_args)
    val_indices = np.arange(len(val_set))
    if cfg.data.val_frames is not None and cfg.data.val_frames < len(val_set):
        val_indices = np.linspace(0, len(val_set) - 1, int(cfg.data.val_frames)).round().astype(int)
    val_loader = torch.utils.data.DataLoader(torch.utils.data.Subset(val_set, val_indices[rank::world].tolist()),
                                             shuffle=False, **loader_args)
    bn_loader = None
    if cfg.train.bn_recompute_frames:
        # un-augmented training frames, a fixed draw: the statistics the model meets at test time
        n_bn = min(int(cfg.train.bn_recompute_frames), len(bn_set))
        bn_indices = np.random.default_rng(int(cfg.seed)).choice(len(bn_set), n_bn, replace=False)
        bn_loader = torch.utils.data.DataLoader(torch.utils.data.Subset(bn_set, sorted(bn_indices.tolist())),
                                                shuffle=False, **loader_args)
    return TrainData(train_set, val_set, sampler, train_loader, val_loader, bn_loader, augment)
