"""A training run's data: the splits' uint8 frames from one of two sources, their loaders, and the
augmentation that turns each training batch on the device.

``data.pipeline`` picks the source only: ``cache`` gathers rows of the frame cache (:mod:`hupbench.data.cache`,
decoded once), ``jpeg`` decodes each frame when a batch needs it. Both give the same batches, bit for bit,
to the same :class:`hupbench.data.augment.BatchAugment`.
"""

from __future__ import annotations

import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import torch

from hupbench.core.errors import BadValueError
from hupbench.core.input_checks import check_choice, check_int
from hupbench.data.augment import BatchAugment
from hupbench.data.cache import open_frame_cache
from hupbench.data.reader import HUPDataset, ReaderConfig

#: where a training batch's uint8 frames come from: the frame cache, or each JPEG decoded when needed
PIPELINES = ("cache", "jpeg")


@dataclass(frozen=True)
class DataConfig:
    """The ``data`` node of conf/train.yaml (conf/data/default.yaml documents its fields): the dataset a run
    reads and how its frames reach the model (:func:`setup_data`), checked here and nowhere else."""

    reader: ReaderConfig
    root: str = "hupbench_out/dataset"
    train_split: str = "train"
    val_split: str = "val"
    batch_size: int = 32
    num_workers: int = 0
    val_frames: int | None = 1440
    pipeline: str = "cache"
    cache_dir: str | None = None

    def __post_init__(self) -> None:
        check_int(self.batch_size, "data.batch_size", 1)
        check_int(self.num_workers, "data.num_workers", 0, 1024)
        check_int(self.val_frames, "data.val_frames", 1, optional=True)
        check_choice(self.pipeline, "data.pipeline", PIPELINES)


class Placement(NamedTuple):
    """Where this process trains: one of ``world`` processes (torchrun's), number ``rank``, on ``device``."""

    world: int
    rank: int
    device: torch.device

    @property
    def is_main(self) -> bool:
        """Rank 0: the process that writes the run folder and talks to the user."""
        return self.rank == 0


class EpochSampler(torch.utils.data.Sampler):
    """A seeded permutation per epoch, sliced for this rank, starting at a batch offset (for resume).

    Every rank draws the same permutation from (seed, epoch) and takes every world-th index, so
    the ranks see disjoint frames; the tail that does not fill a whole global batch is dropped.
    """

    def __init__(self, n: int, batch_size: int, seed: int, world: int = 1, rank: int = 0,
                 tag_epoch: bool = False) -> None:
        self.n, self.batch_size, self.seed, self.world, self.rank = n, batch_size, seed, world, rank
        self.tag_epoch = tag_epoch  # yield i + epoch * n: the loader workers read the epoch from the index
        self.epoch, self.start_batch = 0, 0
        self.batches_per_epoch = n // (batch_size * world)
        if self.batches_per_epoch < 1:
            raise BadValueError(f"the training split has {n} frames, fewer than one batch of {batch_size} x {world} "
                             "processes; lower data.batch_size")

    def set_position(self, epoch: int, start_batch: int) -> None:
        self.epoch, self.start_batch = epoch, start_batch

    def __iter__(self) -> Iterator[int]:
        order = torch.randperm(self.n, generator=torch.Generator().manual_seed(self.seed * 100_003 + self.epoch))
        used = order[: self.batches_per_epoch * self.batch_size * self.world]
        mine = used[self.rank:: self.world] + (self.epoch * self.n if self.tag_epoch else 0)
        return iter(mine[self.start_batch * self.batch_size:].tolist())

    def __len__(self) -> int:
        return (self.batches_per_epoch - self.start_batch) * self.batch_size


class FrameBatches(torch.utils.data.Dataset):
    """A split's uint8 frames with their labels, a whole batch per call (``__getitems__``).

    Args:
        dataset: the split (its labels, annotations and frames).
        frames: (N, S, S, 3) uint8, the split's frame cache; None decodes each frame when a batch needs it.
        depths: (N, S, S) uint16, the split's depth cache, for a model that reads depth (None decodes each map).
        fresh: the sensor's noise is drawn afresh per epoch (``data.reader.fresh_sensor_noise``): index
            ``i + e * N`` is row i of epoch e (:class:`EpochSampler` with ``tag_epoch``), whose depth is draw e + 1.
        segs: (N, S, S) uint8, the split's seg cache (None reads each map when ``with_seg``).
        with_seg: batches carry per-pixel segmentation labels, for a model that learns segmentation.

    Batches: "image" (B, S, S, 3) uint8 RGB, with depth "depth" (B, S, S) float32 metres (the model's depth
    channel), with ``with_seg`` "seg" (B, S, S) int64 ``SEGMENT_CLASSES`` indices on the same pixels
    (:meth:`HUPDataset.seg_frame`), "index" (B,) int64 (the row in the split: the augmentation key), and rows of
    every label of ``HUPDataset.labels``. ``ann`` is the split's annotation arrays.
    """

    def __init__(self, dataset: HUPDataset, frames: np.ndarray | None = None, depths: np.ndarray | None = None,
                 fresh: bool = False, segs: np.ndarray | None = None, with_seg: bool = False) -> None:
        self.dataset, self.ann, self.frames, self.depths, self.fresh = dataset, dataset.ann, frames, depths, fresh
        self.segs, self.with_seg = segs, with_seg

    def __len__(self) -> int:
        return len(self.ann["frame_id"])

    def __getitems__(self, indices: list[int]) -> dict:
        tagged = np.asarray(indices, dtype=np.int64)
        order = tagged % len(self)
        index = torch.from_numpy(order)
        batch = {"image": torch.from_numpy(self._gather(self.frames, self.dataset.frame, order)), "index": index,
                 **{name: value[index] for name, value in self.dataset.labels.items()}}
        if self.dataset.config.depth:
            if self.fresh:
                depth = np.stack([self.dataset.depth_frame(int(i), int(d))
                                  for i, d in zip(order, tagged // len(self) + 1)])
            else:
                depth = self._gather(self.depths, self.dataset.depth_frame, order)
            batch["depth"] = self.dataset.depth_metres(depth)
        if self.with_seg:
            seg = self._gather(self.segs, self.dataset.seg_frame, order)                      # (B, S, S) uint8
            batch["seg"] = torch.from_numpy(seg.astype(np.int64))
        return batch

    @staticmethod
    def _gather(cache: np.ndarray | None, read_row, order: np.ndarray) -> np.ndarray:
        """Rows ``order`` of a cache, or read one by one without it."""
        if cache is None:
            return np.stack([read_row(row) for row in order.tolist()])
        rows = np.sort(order)  # a sorted gather reads the memory map front to back
        return cache[rows][np.searchsorted(rows, order)]

    def __getitem__(self, index: int) -> dict:
        batch = self.__getitems__([int(index)])
        return {name: value[0] for name, value in batch.items()}


def _stacked(batch: dict) -> dict:
    """The loaders' collate: :meth:`FrameBatches.__getitems__` stacks the batch already."""
    return batch


class TrainData(NamedTuple):
    """What :func:`setup_data` builds: the splits, their loaders and the per-batch augmentation."""

    train_set: FrameBatches
    val_set: FrameBatches
    sampler: EpochSampler
    train_loader: Any
    val_loader: Any
    bn_loader: Any
    augment: BatchAugment


def _worker_setup(_worker_id: int) -> None:
    """A loader worker: one thread each for decoding and gathering (OpenCV and OpenMP pools in every worker
    oversubscribe the machine, measured: load 140-170 on 16 cores), and silent on a batch handoff its main
    process dropped.

    A worker hands each batch's shared memory over through multiprocessing's resource sharer, a thread that
    reports its errors through ``sys.excepthook``. Ctrl-C reaches the main process in the middle of such a
    handoff now and then: it drops the connection, and the worker's thread would print a
    ``ConnectionResetError`` traceback under the run's one line. A dropped handoff loses nothing (the main
    process is ending), so the worker's hook passes over a closed connection and prints every other error.
    """
    import cv2

    cv2.setNumThreads(1)
    torch.set_num_threads(1)
    sys.excepthook = _quiet_on_dropped_connection


def _quiet_on_dropped_connection(kind, value, traceback) -> None:
    """A loader worker's ``sys.excepthook`` (:func:`_worker_setup`)."""
    if not issubclass(kind, (ConnectionError, EOFError)):
        sys.__excepthook__(kind, value, traceback)


def setup_data(data: DataConfig, seed: int, bn_frames: int, place: Placement, progress: bool = True,
               log=print, with_seg: bool = False) -> TrainData:
    """The training and validation data of a run, this process's share of them.

    Args:
        data: the run's data node. seed: the run's seed (the epochs' frame order, the batch-norm frames).
        bn_frames: training frames of the batch-norm re-estimation (``train.bn_recompute_frames``; 0: none).
        place: this process among the run's. progress: a bar while a frame cache is built (rank 0 only).
        log: where a stale cache's rebuild is said.
        with_seg: training and validation batches carry "seg" labels (:class:`FrameBatches`), for a model that
            learns segmentation; the dataset must have seg maps (with ``data.pipeline: cache``, cached too).

    Validation and batch-norm batches are un-augmented; ``TrainData.augment`` turns training batches on
    ``place.device``.
    """
    reader = data.reader
    splits = [HUPDataset(Path(data.root), split, reader) for split in (data.train_split, data.val_split)]
    K = splits[0].ann["K"]
    if reader.rotate_deg > 0 and not np.allclose(K[:, 0, 0], K[:, 1, 1]):
        raise BadValueError(f"in-plane rotation needs square pixels (fx == fy), got fx={K[0, 0, 0]}, fy={K[0, 1, 1]}")
    lacking = [split.split for split in splits if "seg" not in split.manifest["modalities"]] if with_seg else []
    if lacking:
        raise BadValueError(f"{data.root} has no seg maps for the {' and '.join(lacking)} split (modalities lack "
                            "seg); a model that learns segmentation needs them")
    show = progress and place.is_main
    wanted = {"rgb": True, "depth": reader.depth, "seg": with_seg}

    def cached(split: HUPDataset, modality: str) -> np.ndarray | None:
        use = data.pipeline == "cache" and wanted[modality]
        return open_frame_cache(split, data.cache_dir, show, log, modality) if use else None

    fresh = reader.fresh_sensor_noise  # training depth drawn per epoch: no cache of it
    train_set = FrameBatches(splits[0], cached(splits[0], "rgb"), None if fresh else cached(splits[0], "depth"),
                             fresh=fresh, segs=cached(splits[0], "seg"), with_seg=with_seg)
    val_set = FrameBatches(splits[1], cached(splits[1], "rgb"), cached(splits[1], "depth"),
                           segs=cached(splits[1], "seg"), with_seg=with_seg)
    workers = data.num_workers
    loader_args = {"batch_size": data.batch_size, "num_workers": workers, "collate_fn": _stacked,
                   "pin_memory": place.device.type == "cuda", "worker_init_fn": _worker_setup if workers else None,
                   "persistent_workers": workers > 0}
    sampler = EpochSampler(len(train_set), data.batch_size, seed, place.world, place.rank, tag_epoch=fresh)
    train_loader = torch.utils.data.DataLoader(train_set, sampler=sampler, drop_last=True, **loader_args)
    val_indices = np.arange(len(val_set))
    if data.val_frames is not None and data.val_frames < len(val_set):
        val_indices = np.linspace(0, len(val_set) - 1, data.val_frames).round().astype(int)
    mine = val_indices[place.rank::place.world].tolist()
    val_loader = torch.utils.data.DataLoader(torch.utils.data.Subset(val_set, mine), shuffle=False, **loader_args)
    bn_loader = None
    if bn_frames:
        # un-augmented training frames, a fixed draw: the statistics the model meets at test time
        bn_indices = np.random.default_rng(seed).choice(len(train_set), min(bn_frames, len(train_set)), replace=False)
        bn_loader = torch.utils.data.DataLoader(torch.utils.data.Subset(train_set, sorted(bn_indices.tolist())),
                                                shuffle=False, **loader_args)
    return TrainData(train_set, val_set, sampler, train_loader, val_loader, bn_loader, BatchAugment(reader))
