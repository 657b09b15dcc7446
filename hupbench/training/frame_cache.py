"""The fast input pipeline: a decoded frame cache and augmentation per batch on the training device.

The reference reader (:class:`hupbench.data.HUPDataset`) decodes a JPEG, resizes, rotates and
colour-jitters one image at a time in a loader worker. Here each frame is decoded and resized once
into a frame cache, and the augmentation runs on whole batches where the model runs:

1. :func:`open_frame_cache` returns the (N, S, S, 3) uint8 RGB frames of one split at one input
   size, memory-mapped from ``<cache_dir>/<split>_<S>px.npy``. The first call builds the file
   (decode + ``cv2.INTER_AREA`` resize, exactly the reference reader's un-augmented image) under a
   temporary name with a progress bar, renames it, and writes its key file ``<split>_<S>px.json``
   last; the key (the dataset's manifest sha256, the split's frame ids, S, the resize method and
   the cache format) is checked on every open, and a cache whose key differs is rebuilt.
2. :class:`CachedFrames` serves un-augmented items from the cache with every label moved into the
   input image (the reader's own label code), a whole batch per call (``__getitems__``).
3. :class:`BatchAugment` turns a batch on the device into the model's input: the in-plane rotation
   about the principal point with the 2D and 3D labels turned exactly as the reference reader turns
   them (the angle of item i in epoch e is the reference reader's draw from (seed, e, i)), then
   colour jitter with kornia's colour operations, per-sample factors drawn from the same per-item
   stream (the reference uses kornia's ColorJiggle with the same ranges), the order of the four
   operations drawn once per batch as ColorJiggle does.

Convention:
    Images: uint8 (B, S, S, 3) RGB in the cache and loader; float32 (B, 3, S, S) in [0, 1] after
    :meth:`BatchAugment.__call__`. Labels as :mod:`hupbench.data`: 3D metres in the OpenCV camera
    frame, 2D in input pixels (pixel centres at integers) and normalised [-1, 1]; a positive angle
    turns the image content counter-clockwise on screen.
"""

from __future__ import annotations

import errno
import json
import math
import os
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import cv2
import numpy as np
import torch

from datagen.io import atomic_output, clean_stale_tmp, write_json
from datagen.errors import BadValueError, NotWritableError

__all__ = ["CACHE_FORMAT", "BatchAugment", "CachedFrames", "cache_paths", "model_images", "open_frame_cache"]

#: bump when the cache file layout or the resize changes: every older cache is then rebuilt
CACHE_FORMAT = 1
#: how the stored image is resized to the input size (the reference reader's choice)
RESIZE = "cv2.INTER_AREA"
#: frames decoded per thread task while building
_BUILD_CHUNK = 64


def cache_paths(cache_dir, split: str, input_size: int) -> tuple[Path, Path]:
    """(frames .npy, key .json) of one split at one input size."""
    stem = f"{split}_{int(input_size)}px"
    return Path(cache_dir) / f"{stem}.npy", Path(cache_dir) / f"{stem}.json"


def _cache_key(manifest_sha256: str, split: str, input_size: int, frame_ids: np.ndarray) -> dict:
    import hashlib

    ids = np.ascontiguousarray(frame_ids, dtype=np.int64)
    return {"format": CACHE_FORMAT, "manifest_sha256": manifest_sha256, "split": split,
            "input_size": int(input_size), "frames": int(len(ids)), "resize": RESIZE,
            "frame_ids_sha256": hashlib.sha256(ids.tobytes()).hexdigest()}


def _decode_resized(path: Path, size: int, image_size=None) -> np.ndarray:
    """(S, S, 3) uint8 RGB: the stored image decoded (and checked, :func:`hupbench.data.read_rgb`) and
    resized as the reference reader does."""
    from hupbench.data import read_rgb

    image = read_rgb(path, image_size)
    if image.shape[0] != image.shape[1]:
        raise BadValueError(f"{path}: the reader expects square images, got {image.shape[1]} x {image.shape[0]}")
    return cv2.resize(image, (size, size), interpolation=cv2.INTER_AREA)


def _reserve(path: Path) -> None:
    """Allocate the whole file now: pages of a sparse memory map that find the disk full kill the process
    with SIGBUS when written (measured on a full tmpfs); allocated here, a full disk is an OSError (ENOSPC)."""
    with open(path, "r+b") as f:
        try:
            os.posix_fallocate(f.fileno(), 0, os.fstat(f.fileno()).st_size)
        except OSError as exc:
            if exc.errno not in (errno.EOPNOTSUPP, errno.ENOSYS, errno.EINVAL):  # not supported: write as before
                raise


def open_frame_cache(root, split: str, input_size: int, frame_ids: np.ndarray, rgb_format: str,
                     manifest_sha256: str, cache_dir=None, progress: bool = True, threads: int = 2,
                     log=print, image_size=None) -> np.ndarray:
    """The split's frames at the input size, memory-mapped; built (or rebuilt when stale) first.

    Args:
        root: dataset folder.
        split: the split whose frames are cached.
        input_size: S, side of the square model input, pixels.
        frame_ids: (N,) int64, the split's frame ids in annotation order (row i of the cache is
            frame_ids[i]).
        rgb_format: the dataset's image extension ("jpg" or "png").
        manifest_sha256: sha256 of the dataset's manifest.json: a regenerated dataset gets a new cache.
        cache_dir: where the cache lives; None for ``<root>/cache``.
        progress: show a progress bar while building.
        threads: decoding threads while building (OpenCV releases the GIL).
        image_size: (width, height) of every stored frame (the manifest's), checked while building.

    Returns:
        (N, S, S, 3) uint8 read-only memory map, RGB.
    """
    from datagen.dataset.contract import frame_path

    cache_dir = Path(root) / "cache" if cache_dir is None else Path(cache_dir)
    npy_path, key_path = cache_paths(cache_dir, split, input_size)
    key = _cache_key(manifest_sha256, split, input_size, frame_ids)
    if key_path.is_file() and npy_path.is_file():
        try:
            stored = json.loads(key_path.read_text())
        except (OSError, json.JSONDecodeError):
            stored = None
        if stored == key:
            frames = np.load(npy_path, mmap_mode="r")
            if frames.shape == (len(frame_ids), input_size, input_size, 3) and frames.dtype == np.uint8:
                return frames
        log(f"frame cache {npy_path} is stale (the dataset or the reader changed); rebuilding it")
    try:
        # the key file goes first so that no reader trusts a half-replaced cache
        key_path.unlink(missing_ok=True)
        cache_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        if exc.errno in (errno.EROFS, errno.EACCES, errno.EPERM):  # e.g. the default <dataset>/cache of a shared dataset
            raise NotWritableError(exc.errno, f"cannot write the frame cache in {cache_dir} ({exc.strerror}); set "
                                             "data.cache_dir to a writable folder") from exc
        raise
    clean_stale_tmp(cache_dir, recursive=False)  # builds of killed runs
    n = len(frame_ids)
    # written under a temporary name, renamed when whole; a failure removes it (a full disk says so)
    with atomic_output(npy_path) as tmp:
        out = np.lib.format.open_memmap(tmp, mode="w+", dtype=np.uint8, shape=(n, input_size, input_size, 3))
        _reserve(tmp)
        bar = None
        if progress:
            from tqdm import tqdm

            bar = tqdm(total=n, unit="frame", desc=f"frame cache {split} {input_size}px", dynamic_ncols=True)

        def fill(start: int) -> int:
            stop = min(n, start + _BUILD_CHUNK)
            for row in range(start, stop):
                path = frame_path(root, split, "rgb", int(frame_ids[row]), rgb_format)
                out[row] = _decode_resized(path, input_size, image_size)
            return stop - start

        try:
            with ThreadPoolExecutor(max_workers=max(1, int(threads))) as pool:
                for done in pool.map(fill, range(0, n, _BUILD_CHUNK)):
                    if bar is not None:
                        bar.update(done)
        finally:
            if bar is not None:
                bar.close()
        out.flush()
        del out
    write_json(key_path, key)
    return np.load(npy_path, mmap_mode="r")


class CachedFrames(torch.utils.data.Dataset):
    """Un-augmented frames of one split from the frame cache, labels in the input image.

    Args:
        dataset: a :class:`hupbench.data.HUPDataset` of the split (its annotations, manifest and
            reader config give the labels and the input size; its augmentation settings are not
            used here: :class:`BatchAugment` applies them per batch).
        cache_dir: see :func:`open_frame_cache`.
        progress: progress bar while a cache is built.

    Items (and, through ``__getitems__``, whole batches with a leading B axis): "image" (S, S, 3)
    uint8 RGB; "keypoints_3d" (29, 3) float32 metres; "keypoints_2d_px" (29, 2) float32 input
    pixels; "keypoints_2d" (29, 2) float32 normalised; "visible" (29,) bool; "K" (3, 3) float32 of
    the input image; "frame_id" int64; "index" int64, the row in the split (the augmentation key).
    ``ann`` is the split's annotation arrays (as ``HUPDataset.ann``).
    """

    def __init__(self, dataset, cache_dir=None, progress: bool = True, log=print) -> None:
        from datagen.io import file_sha256
        from hupbench.data import input_labels

        self.size = int(dataset.config.input_size)
        self.ann = ann = dataset.ann
        self.frames = open_frame_cache(dataset.root, dataset.split, self.size, ann["frame_id"],
                                       dataset.manifest["rgb_format"], file_sha256(dataset.root / "manifest.json"),
                                       cache_dir=cache_dir, progress=progress, log=log,
                                       image_size=dataset.manifest["image_size"])
        scale = self.size / int(dataset.manifest["image_size"][0])
        labels = input_labels(ann, scale, self.size)
        self.labels = {name: torch.from_numpy(np.ascontiguousarray(array)) for name, array in labels.items()}
        self.labels["frame_id"] = torch.from_numpy(ann["frame_id"].astype(np.int64))

    def __len__(self) -> int:
        return len(self.frames)

    def __getitems__(self, indices: list[int]) -> dict:
        order = np.asarray(indices, dtype=np.int64)
        rows = np.sort(order)  # a sorted gather reads the memory map front to back
        images = self.frames[rows][np.searchsorted(rows, order)]
        index = torch.from_numpy(order)
        return {"image": torch.from_numpy(images), "index": index,
                **{name: value[index] for name, value in self.labels.items()}}

    def __getitem__(self, index: int) -> dict:
        batch = self.__getitems__([int(index)])
        return {name: value[0] for name, value in batch.items()}


def collate_batch(batch: dict) -> dict:
    """The DataLoader's collate for :class:`CachedFrames`: its batches are already stacked."""
    return batch


def _rotation_matrices(angles: torch.Tensor, centre: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Affine image maps (B, 2, 3) and camera-frame rotations (B, 3, 3) for in-plane turns.

    Args:
        angles: (B,) radians, counter-clockwise on screen.
        centre: (B, 2) principal points (cx, cy), pixels.

    Returns:
        M (B, 2, 3): destination pixel = M[:, :2] @ source pixel + M[:, 2] (cv2.getRotationMatrix2D's
        map); R (B, 3, 3): the matching rotation of camera-frame points, -angle about +z
        (:func:`hupbench.data.rotation_about_optical_axis`).
    """
    c, s = torch.cos(angles), torch.sin(angles)
    cx, cy = centre[:, 0], centre[:, 1]
    # cv2.getRotationMatrix2D(centre, angle, 1): [[c, s, (1-c) cx - s cy], [-s, c, s cx + (1-c) cy]]
    M = torch.stack([torch.stack([c, s, (1 - c) * cx - s * cy], dim=-1),
                     torch.stack([-s, c, s * cx + (1 - c) * cy], dim=-1)], dim=1)
    zero, one = torch.zeros_like(c), torch.ones_like(c)
    R = torch.stack([torch.stack([c, s, zero], dim=-1), torch.stack([-s, c, zero], dim=-1),
                     torch.stack([zero, zero, one], dim=-1)], dim=1)
    return M, R


class BatchAugment:
    """The reference reader's augmentation, applied to a whole batch on its device.

    Args:
        rotate_deg: in-plane rotation range (+-), degrees; 0 disables it.
        photometric: colour jitter strength in [0, 1] (brightness, contrast and saturation factors
            in [1 - 0.4 p, 1 + 0.4 p], hue shift in [-0.05 p, 0.05 p] turns, as the reference's
            kornia ColorJiggle); 0 disables it.
        seed: the augmentation seed (the reader config's).

    Call with a batch of :class:`CachedFrames` on the device and the epoch; returns the batch with
    "image" (B, 3, S, S) float32 in [0, 1] and "keypoints_3d", "keypoints_2d", "keypoints_2d_px",
    "visible" turned with the image. Draws depend only on (seed, epoch, item index), so a run and
    its resume see the same augmentation in any batch composition but the jitter's operation order,
    which is drawn from (seed, epoch, the batch's first item).
    """

    def __init__(self, rotate_deg: float = 0.0, photometric: float = 0.0, seed: int = 0) -> None:
        if not 0.0 <= float(rotate_deg) <= 180.0:
            raise BadValueError(f"rotate_deg must be in [0, 180], got {rotate_deg!r}")
        if not 0.0 <= float(photometric) <= 1.0:
            raise BadValueError(f"photometric must be in [0, 1], got {photometric!r}")
        self.rotate_deg, self.photometric, self.seed = float(rotate_deg), float(photometric), int(seed)

    def draws(self, indices, epoch: int) -> tuple[np.ndarray, np.ndarray]:
        """Per-item (angles (B,) radians, jitter factors (B, 4): brightness, contrast, saturation, hue)."""
        angles = np.zeros(len(indices))
        factors = np.tile([1.0, 1.0, 1.0, 0.0], (len(indices), 1))
        p = self.photometric
        for row, index in enumerate(np.asarray(indices, dtype=np.int64).tolist()):
            rng = np.random.default_rng([self.seed, int(epoch), index])
            if self.rotate_deg > 0:
                angles[row] = np.deg2rad(rng.uniform(-self.rotate_deg, self.rotate_deg))  # the reference's first draw
            if p > 0:
                jitter = np.random.default_rng([self.seed, int(epoch), index, 1])
                factors[row, :3] = jitter.uniform(1.0 - 0.4 * p, 1.0 + 0.4 * p, size=3)
                factors[row, 3] = jitter.uniform(-0.05 * p, 0.05 * p)
        return angles, factors

    def __call__(self, batch: dict, epoch: int) -> dict:
        import kornia

        images = model_images(batch["image"], batch["image"].device)
        out = dict(batch)
        device = images.device
        indices = batch["index"].cpu().numpy()
        angles, factors = self.draws(indices, epoch)
        size = images.shape[-1]
        if self.rotate_deg > 0:
            K = batch["K"].double()
            M, R = _rotation_matrices(torch.from_numpy(angles).to(device), K[:, :2, 2])  # float64
            images = kornia.geometry.transform.warp_affine(images, M.float(), (size, size), mode="bilinear",
                                                           padding_mode="reflection", align_corners=True)
            uv = batch["keypoints_2d_px"].double() @ M[:, :, :2].transpose(1, 2) + M[:, None, :, 2]
            out["keypoints_3d"] = (batch["keypoints_3d"].double() @ R.transpose(1, 2)).float()
            out["keypoints_2d_px"] = uv.float()
            inside = ((uv >= -0.5) & (uv < size - 0.5)).all(dim=-1)
            out["visible"] = batch["visible"] & inside
            out["keypoints_2d"] = ((2.0 * uv + 1.0) / size - 1.0).float()
        if self.photometric > 0:
            images = self._jitter(images, torch.from_numpy(factors).to(device, images.dtype),
                                  np.random.default_rng([self.seed, int(epoch), int(indices[0]), 2]).permutation(4))
        out["image"] = images
        return out

    @staticmethod
    def _jitter(images: torch.Tensor, factors: torch.Tensor, order: np.ndarray) -> torch.Tensor:
        from kornia.enhance import adjust_brightness, adjust_contrast, adjust_hue, adjust_saturation

        steps = (lambda x, f: adjust_brightness(x, f - 1.0), adjust_contrast, adjust_saturation,
                 lambda x, f: adjust_hue(x, f * 2.0 * math.pi))
        images = images.clamp(0.0, 1.0)
        for step in order.tolist():
            images = steps[step](images, factors[:, step])
        return images.clamp(0.0, 1.0)




def model_images(images: torch.Tensor, device: torch.device, channels_last: bool = False) -> torch.Tensor:
    """A loader's images as the model's input on ``device``.

    Args:
        images: (B, S, S, 3) uint8 RGB (frame cache, moved to the device as bytes: a quarter of the
            float traffic) or (B, 3, S, S) float32 in [0, 1] (the reference reader).
        device: where the model runs.
        channels_last: return channels_last memory format.

    Returns:
        (B, 3, S, S) float32 in [0, 1] on ``device``.
    """
    images = images.to(device, non_blocking=True)
    if images.dtype == torch.uint8:
        images = images.permute(0, 3, 1, 2).float().div_(255.0)  # (B, S, S, 3) -> (B, 3, S, S)
    return images.contiguous(memory_format=torch.channels_last if channels_last else torch.contiguous_format)
