"""The frame cache: every frame of a split decoded and resized once into a memory-mapped (N, S, S, 3) uint8
file, ``<cache_dir>/<split>_<S>px.npy``, so that a training batch is a gather instead of N JPEG decodes; for a
model that reads depth, its depth maps likewise into (N, S, S) uint16 ``<split>_<S>px_depth.npy``, and for one
that learns segmentation, its per-pixel classes into (N, S, S) uint8 ``<split>_<S>px_seg.npy``.

The file is built under a temporary name with a progress bar and renamed when whole; its key file
``<split>_<S>px.json`` is written last and checked on every open. The key holds what the frames depend
on: the size and modification time of every frame file (in row order), the input size, the stored image
size, the resize and the file layout, and for depth its source, for seg the class mapping. A cache whose key
differs is rebuilt, so a frame replaced or damaged after the build is read again (and a damaged one refused,
naming it).
"""

from __future__ import annotations

import errno
import hashlib
import json
import os
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
from tqdm import tqdm

from hupbench.core.contract import SEGMENT_CLASSES
from hupbench.core.processes import usable_cores
from hupbench.core.io import atomic_output, clean_stale_tmp, write_json, writing


#: bump when the cache file layout or the resize changes: every older cache is then rebuilt
CACHE_FORMAT = 1
#: how the stored image is resized to the input size (:func:`hupbench.input_geometry.pad_and_resize`)
RESIZE = "cv2.INTER_AREA"
#: frames decoded per thread task, and decoding threads while building (OpenCV releases the GIL): one a core this
#: process may run on (a GPU machine's 16 build the paper protocol's caches in seconds), at least 2
_BUILD_CHUNK, _BUILD_THREADS = 64, max(2, usable_cores())


#: what each cached modality holds: (the dataset's per-row reader, dtype, trailing shape after (N, S, S))
_MODALITIES = {"rgb": ("frame", np.uint8, (3,)), "depth": ("depth_frame", np.uint16, ()),
               "seg": ("seg_frame", np.uint8, ())}


def cache_paths(cache_dir, split: str, input_size: int, modality: str = "rgb") -> tuple[Path, Path]:
    """(frames .npy, key .json) of one split at one input size, for its RGB frames or its "depth" or "seg" maps."""
    stem = f"{split}_{input_size}px" + ("" if modality == "rgb" else f"_{modality}")
    return Path(cache_dir) / f"{stem}.npy", Path(cache_dir) / f"{stem}.json"


def _sources(dataset, modality: str) -> tuple[tuple[str, ...], dict]:
    """(the modalities whose files a row of the ``modality`` cache reads, what else its rows depend on)."""
    if modality == "rgb":
        return ("rgb",), {}
    if modality == "depth":
        return dataset.depth_files, {"depth_source": dataset.depth_source, "sensor": (
            None if dataset.sensor is None else dataset.sensor.parameters())}
    return ("seg",), {"classes": list(SEGMENT_CLASSES), "seg_labels": dataset.manifest["seg_labels"]}


def cache_key(dataset, modality: str = "rgb") -> dict:
    """What the cache of ``dataset`` (a :class:`hupbench.data.HUPDataset`) depends on, as JSON.

    Each frame file it reads counts by name, size and modification time (ns): about 0.1 s for 20,000 frames,
    where hashing their contents would read the whole split. A missing file counts as such; the
    rebuild it causes then names it.
    """
    stamps = hashlib.sha256()
    files, source = _sources(dataset, modality)
    for row in range(len(dataset)):
        for path in (dataset.path(row, m) for m in files):
            name = path.name if modality == "rgb" else f"{path.parent.name}/{path.name}"
            try:
                stat = path.stat()
                stamps.update(f"{name} {stat.st_size} {stat.st_mtime_ns}\n".encode())
            except FileNotFoundError:
                stamps.update(f"{name} missing\n".encode())
    return {"format": CACHE_FORMAT, **source, "split": dataset.split, "modality": modality,
            "input_size": dataset.config.input_size, "image_size": dataset.manifest["image_size"],
            "resize": RESIZE if modality == "rgb" else "cv2.INTER_NEAREST",
            "frames": len(dataset), "frame_files_sha256": stamps.hexdigest()}


def _reserve(path: Path) -> None:
    """Allocate the whole file now: pages of a sparse memory map that find the disk full kill the process
    with SIGBUS when written (measured on a full tmpfs); allocated here, a full disk is an OSError (ENOSPC)."""
    with open(path, "r+b") as f:
        try:
            os.posix_fallocate(f.fileno(), 0, os.fstat(f.fileno()).st_size)
        except OSError as exc:
            if exc.errno not in (errno.EOPNOTSUPP, errno.ENOSYS, errno.EINVAL):  # not supported: write as before
                raise


def open_frame_cache(dataset, cache_dir=None, progress: bool = True, log=print, modality: str = "rgb") -> np.ndarray:
    """(N, S, S, 3) uint8 RGB read-only memory map whose row i is ``dataset.frame(i)`` (for ``modality="depth"``,
    (N, S, S) uint16 rows of ``dataset.depth_frame(i)``; for "seg", (N, S, S) uint8 rows of ``dataset.seg_frame(i)``),
    built (or rebuilt when stale, said to ``log``) first in ``cache_dir`` (default ``<dataset root>/cache``)."""
    cache_dir = dataset.root / "cache" if cache_dir is None else Path(cache_dir)
    size, split = dataset.config.input_size, dataset.split
    reader_name, dtype, tail = _MODALITIES[modality]
    read_row, shape = getattr(dataset, reader_name), (len(dataset), size, size, *tail)
    npy_path, key_path = cache_paths(cache_dir, split, size, modality)
    key = cache_key(dataset, modality)
    if key_path.is_file() and npy_path.is_file():
        try:
            stored = json.loads(key_path.read_text())
        except (OSError, json.JSONDecodeError):
            stored = None
        if stored == key:
            frames = np.load(npy_path, mmap_mode="r")
            if frames.shape == shape and frames.dtype == dtype:
                return frames
        log(f"frame cache {npy_path} is stale (the dataset or the reader changed); rebuilding it")
    # e.g. the default <dataset>/cache of a shared dataset on a read-only mount, or a data.cache_dir that is a file
    with writing(cache_dir, "the frame cache", fix="set data.cache_dir to a writable folder"):
        key_path.unlink(missing_ok=True)  # the key file goes first so that no reader trusts a half-replaced cache
        cache_dir.mkdir(parents=True, exist_ok=True)
    clean_stale_tmp(cache_dir, recursive=False)  # builds of killed runs
    n = len(dataset)
    # written under a temporary name, renamed when whole; a failure removes it (a full disk says so)
    with atomic_output(npy_path) as tmp:
        out = np.lib.format.open_memmap(tmp, mode="w+", dtype=dtype, shape=shape)
        _reserve(tmp)

        def fill(start: int) -> int:
            stop = min(n, start + _BUILD_CHUNK)
            for row in range(start, stop):
                out[row] = read_row(row)
            return stop - start

        desc = f"frame cache {split} {size}px" + ("" if modality == "rgb" else f" {modality}")
        with tqdm(total=n, unit="frame", desc=desc, dynamic_ncols=True,
                  disable=not progress) as bar, ThreadPoolExecutor(max_workers=_BUILD_THREADS) as pool:
            for done in pool.map(fill, range(0, n, _BUILD_CHUNK)):
                bar.update(done)
        out.flush()
        del out
    write_json(key_path, key)
    return np.load(npy_path, mmap_mode="r")
