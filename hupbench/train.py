"""Training: ``python train.py model=hopenet`` (thin Hydra entry) over :func:`run_train`.

One loop for every model: HOPE-Net's weighted MSE (2D init + 2D + 3D; the
baseline has only the 3D term unless built with a 2D head), Adam with warm-up
and cosine decay, optional bf16 autocast and channels_last, validation MPJPE
(hand / probe / all, mm, absolute camera frame) logged against wall time and
samples seen, atomic checkpoints that resume to the same next loss, and
multi-process training under ``torchrun`` (DDP; gloo on CPU, nccl on CUDA).

Run folder (``run_dir``):
    run.json             resolved config, git commit, package versions, hardware
    metrics.jsonl        one JSON object per line: "train" and "val" events (the leaderboard reads it)
    checkpoints/last.pt  the latest state (hupbench.checkpoint format); best.pt: lowest val MPJPE
    tb/                  TensorBoard scalars
    summary.json         written last, only when the run finished: final metrics and timings
"""

from __future__ import annotations

import errno
import json
import math
import os
import platform
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import torch
from omegaconf import DictConfig, OmegaConf

from datagen import keypoints as kp
from datagen.io import DiskFullError, OutputLock, clean_stale_tmp, write_bytes, write_json
from hupbench.errors import USER_ERRORS, error_line
from hupbench.checkpoint import file_sha256, read_checkpoint, save_checkpoint
from hupbench.config import build
from hupbench.frames import model_images
from hupbench.provenance import run_info

# config keys that may differ between a run and the run it resumes
#: config differences a refused resume lists (a checkpoint of another project differs everywhere)
MAX_DIFFS_SHOWN = 8
RESUME_FREE_KEYS = ("train.resume", "train.progress", "train.stop_after", "run_dir", "threads", "data.num_workers",
                    "data.cache_dir", "label")


# ----------------------------------------------------------------------------------------------
# schedule and loss


def warmup_cosine(optimizer: torch.optim.Optimizer, total_steps: int, warmup_steps: int = 100,
                  final_lr_fraction: float = 0.02) -> torch.optim.lr_scheduler.LambdaLR:
    """Linear warm-up to the base learning rate, then cosine decay to ``final_lr_fraction`` of it.

    Args:
        optimizer: the optimiser whose learning rates are scaled.
        total_steps: optimiser steps in the whole run.
        warmup_steps: steps of linear warm-up (shortened to a tenth of the run for short runs).
        final_lr_fraction: learning rate at the last step, as a fraction of the base rate.
    """
    if total_steps < 1:
        raise ValueError(f"total_steps must be >= 1, got {total_steps}")
    if not 0.0 <= final_lr_fraction <= 1.0:
        raise ValueError(f"final_lr_fraction must be in [0, 1], got {final_lr_fraction}")
    warmup = max(0, min(int(warmup_steps), total_steps // 10))

    def factor(step: int) -> float:
        if step < warmup:
            return (step + 1) / warmup
        progress = min(1.0, (step - warmup) / max(1, total_steps - warmup))
        return final_lr_fraction + (1.0 - final_lr_fraction) * 0.5 * (1.0 + math.cos(math.pi * progress))

    return torch.optim.lr_scheduler.LambdaLR(optimizer, factor)


def loss_terms(output, batch: dict, weights: DictConfig | dict) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """HOPE-Net's weighted MSE over whichever outputs the model has.

    With ``probe_symmetry: half_turn`` the probe corners' labels are taken up to the half turn about
    the probe's long axis: per sample, the true corners are relabelled by the element of
    ``hupbench.metrics.PROBE_SYMMETRIES`` (identity or half turn) whose 3D corner MSE against the
    prediction is smaller, and the same relabelling is applied to the 2D targets, so all terms agree
    on which corner is which (PoseCNN's ShapeMatch idea for a discrete group). The 3D term is then the
    minimum over the group of the corner MSE plus the unchanged hand MSE; the choice itself carries
    no gradient.

    Args:
        output: HOPENetOutput (points2d_init, points2d, points3d) or RegressorOutput (points2d or
            None, points3d); 2D (B, 29, 2) normalised image units, 3D (B, 29, 3) metres.
        batch: "keypoints_2d" (B, 29, 2) normalised, "keypoints_3d" (B, 29, 3) metres, camera frame.
        weights: w2d_init, w2d, w3d, unit_3d_m (the 3D loss is measured in that many metres) and
            optionally probe_symmetry ("none", the default, or "half_turn").

    Returns:
        (total loss, {term name: 0-dim detached tensor on the loss's device}) with the unweighted
        terms for logging (tensors, so that the training loop reads them without waiting for the
        device at every step); with half_turn also "probe_half_turned", the fraction of samples
        whose corners were relabelled.
    """
    from hupbench.metrics import PROBE_SYMMETRIES, permute_keypoints, symmetry_costs

    target_2d = batch["keypoints_2d"]
    target_3d = batch["keypoints_3d"] / weights["unit_3d_m"]
    symmetry = weights.get("probe_symmetry", "none")
    if symmetry not in PROBE_SYMMETRIES:
        raise ValueError(f"loss.probe_symmetry must be one of {sorted(PROBE_SYMMETRIES)}, got {symmetry!r}")
    choice = None
    if symmetry != "none":
        group = PROBE_SYMMETRIES[symmetry]
        with torch.no_grad():
            costs = symmetry_costs(output.points3d.float() / weights["unit_3d_m"], target_3d, group, squared=True)
            choice = costs.argmin(dim=1)                                            # (B,) group element
        target_3d = permute_keypoints(target_3d, group, choice)
        target_2d = permute_keypoints(target_2d, group, choice)
    terms = {"loss_3d": torch.nn.functional.mse_loss(output.points3d.float() / weights["unit_3d_m"], target_3d)}
    total = weights["w3d"] * terms["loss_3d"]
    if getattr(output, "points2d_init", None) is not None:
        terms["loss_2d_init"] = torch.nn.functional.mse_loss(output.points2d_init.float(), target_2d)
        total = total + weights["w2d_init"] * terms["loss_2d_init"]
    if output.points2d is not None:
        terms["loss_2d"] = torch.nn.functional.mse_loss(output.points2d.float(), target_2d)
        total = total + weights["w2d"] * terms["loss_2d"]
    logged = {name: value.detach() for name, value in terms.items()}
    if choice is not None:
        logged["probe_half_turned"] = (choice != 0).float().mean()
    return total, logged


def hopenet_loss(output, batch: dict, weights: DictConfig | dict) -> tuple[torch.Tensor, dict[str, float]]:
    """:func:`loss_terms` with the logged terms as Python floats."""
    total, terms = loss_terms(output, batch, weights)
    return total, {name: float(value) for name, value in terms.items()}


# ----------------------------------------------------------------------------------------------
# distributed helpers (torchrun sets WORLD_SIZE, RANK, LOCAL_RANK)


def _dist_env() -> tuple[int, int, int]:
    world = int(os.environ.get("WORLD_SIZE", "1"))
    return world, int(os.environ.get("RANK", "0")), int(os.environ.get("LOCAL_RANK", "0"))


def _device(cfg: DictConfig, local_rank: int) -> torch.device:
    if cfg.device == "cpu":
        return torch.device("cpu")
    if cfg.device == "cuda":
        if not torch.cuda.is_available():
            raise RuntimeError("device=cuda was asked for but CUDA is not available here "
                               f"(torch {torch.__version__}); use device=cpu")
        return torch.device("cuda", local_rank)
    raise ValueError(f"device must be 'cpu' or 'cuda', got {cfg.device!r}")


class EpochSampler(torch.utils.data.Sampler):
    """A seeded permutation per epoch, sliced for this rank, starting at a batch offset (for resume).

    Every rank draws the same permutation from (seed, epoch) and takes every world-th index, so
    the ranks see disjoint frames; the tail that does not fill a whole global batch is dropped.
    """

    def __init__(self, n: int, batch_size: int, seed: int, world: int = 1, rank: int = 0) -> None:
        self.n, self.batch_size, self.seed, self.world, self.rank = n, batch_size, seed, world, rank
        self.epoch, self.start_batch = 0, 0
        self.batches_per_epoch = n // (batch_size * world)
        if self.batches_per_epoch < 1:
            raise ValueError(f"the training split has {n} frames, fewer than one batch of {batch_size} x {world} "
                             "processes; lower data.batch_size")

    def set_position(self, epoch: int, start_batch: int) -> None:
        self.epoch, self.start_batch = epoch, start_batch

    def __iter__(self) -> Iterator[int]:
        order = torch.randperm(self.n, generator=torch.Generator().manual_seed(self.seed * 100_003 + self.epoch))
        used = order[: self.batches_per_epoch * self.batch_size * self.world]
        mine = used[self.rank:: self.world]
        return iter(mine[self.start_batch * self.batch_size:].tolist())

    def __len__(self) -> int:
        return (self.batches_per_epoch - self.start_batch) * self.batch_size


# ----------------------------------------------------------------------------------------------
# set-up checks (all before the first step)


def _config_diff(a: dict, b: dict, prefix: str = "") -> list[str]:
    out = []
    for key in sorted(set(a) | set(b)):
        path = f"{prefix}{key}"
        if path in RESUME_FREE_KEYS:
            continue
        va, vb = a.get(key, "<absent>"), b.get(key, "<absent>")
        if isinstance(va, dict) and isinstance(vb, dict):
            out += _config_diff(va, vb, path + ".")
        elif va != vb:
            out.append(f"{path}: checkpoint {va!r}, now {vb!r}")
    return out


def _resume_path(cfg: DictConfig, run_dir: Path) -> Path | None:
    last = run_dir / "checkpoints" / "last.pt"
    mode = cfg.train.resume
    if mode in (None, "never"):
        if last.exists():
            raise ValueError(f"{run_dir} already holds a checkpoint ({last}); use train.resume=auto to continue it "
                             "or another run_name")
        return None
    if mode == "auto":
        return last if last.exists() else None
    path = Path(mode)
    if not path.is_file():
        raise FileNotFoundError(f"train.resume={mode}: checkpoint {path} does not exist")
    return path


# ----------------------------------------------------------------------------------------------
# validation


@torch.no_grad()
def recompute_bn_statistics(model: torch.nn.Module, loader, device: torch.device, autocast: dict) -> int:
    """Replace every batch norm's running statistics by exact averages over ``loader`` (precise BN).

    Running statistics are an exponential average over past batches, taken while the weights
    moved; at Adam's early learning rates they lag the weights so far that eval-mode errors
    came out worse than the untrained prior's while batch statistics gave a good fit.
    Recomputing them from un-augmented training frames before each validation and checkpoint
    makes eval-mode outputs (validation, ``hupbench eval``, ONNX) those of the current weights.
    Training is unaffected: in train mode batch norm normalises with the batch's own statistics.

    Returns:
        the number of frames averaged.
    """
    norms = [m for m in model.modules() if isinstance(m, torch.nn.modules.batchnorm._BatchNorm)]
    if not norms:
        return 0
    was_training = model.training
    momenta = [m.momentum for m in norms]
    for m in norms:
        m.reset_running_stats()
        m.momentum = None  # cumulative average over the batches below
    model.train()
    frames = 0
    for batch in loader:
        with torch.autocast(**autocast):
            model(model_images(batch["image"], device))
        frames += len(batch["image"])
    for m, momentum in zip(norms, momenta):
        m.momentum = momentum
    model.train(was_training)
    return frames


@torch.no_grad()
def validate(model: torch.nn.Module, loader, device: torch.device, autocast: dict, world: int = 1) -> dict:
    """Absolute camera-frame MPJPE over a validation loader, reduced across ranks.

    Returns:
        {"all": mm (mean over all 29 keypoints and frames), "hand": mm (21 joints),
        "probe": mm (8 corners), "frames": int}.
    """
    from hupbench.metrics import keypoint_errors_mm

    was_training = model.training
    model.eval()
    sums = torch.zeros(kp.NUM_KEYPOINTS, dtype=torch.float64)
    count = torch.zeros((), dtype=torch.float64)
    for batch in loader:
        images = model_images(batch["image"], device)
        with torch.autocast(**autocast):
            points3d = model(images).points3d.float()
        errors = keypoint_errors_mm(points3d.cpu().double(), batch["keypoints_3d"].double())  # (B, 29)
        sums += errors.sum(dim=0)
        count += errors.shape[0]
    if world > 1:
        reduce_device = device if device.type == "cuda" else torch.device("cpu")
        packed = torch.cat([sums, count[None]]).to(reduce_device)
        torch.distributed.all_reduce(packed)
        sums, count = packed[:-1].cpu(), packed[-1].cpu()
    model.train(was_training)
    per_keypoint = sums / count.clamp(min=1)
    return {"all": float(per_keypoint.mean()), "hand": float(per_keypoint[: kp.NUM_HAND].mean()),
            "probe": float(per_keypoint[kp.NUM_HAND:].mean()), "frames": int(count)}


# ----------------------------------------------------------------------------------------------
# the run


class _Log:
    """metrics.jsonl (append, flushed per line) + TensorBoard, on rank 0 only."""

    def __init__(self, run_dir: Path, enabled: bool, tensorboard: bool, resume_step: int | None) -> None:
        self.enabled = enabled
        self.path = run_dir / "metrics.jsonl"
        self.writer = None
        if not enabled:
            return
        if resume_step is None:
            write_bytes(self.path, b"")
        elif self.path.exists():
            # drop lines a killed run wrote after its last checkpoint: they are about to be redone
            kept = [line for line in self._records() if json.loads(line)["step"] <= resume_step]
            write_bytes(self.path, "".join(line + "\n" for line in kept).encode())
        if tensorboard:
            from torch.utils.tensorboard import SummaryWriter

            self.writer = SummaryWriter(str(run_dir / "tb"), purge_step=resume_step)

    def _records(self) -> list[str]:
        """The file's JSON lines; a last line cut short (a run killed while writing it, a full disk) is dropped."""
        lines = [line for line in self.path.read_text().splitlines() if line.strip()]
        for i, line in enumerate(lines):
            try:
                record = json.loads(line)
            except json.JSONDecodeError:
                record = None
            if not isinstance(record, dict) or not isinstance(record.get("step"), int):
                if i == len(lines) - 1:
                    return lines[:-1]
                raise ValueError(f"{self.path}: line {i + 1} is not a metrics record (JSON with a 'step'); "
                                 "the log was edited or damaged: move it away to start the log afresh")
        return lines

    def __call__(self, record: dict) -> None:
        if not self.enabled:
            return
        try:
            with open(self.path, "a") as f:
                f.write(json.dumps(record, sort_keys=True) + "\n")
        except OSError as exc:
            raise (DiskFullError(self.path) if exc.errno == errno.ENOSPC else exc) from exc
        if self.writer is not None:
            step = record["step"]
            for key, value in record.items():
                if isinstance(value, dict):
                    for sub, v in value.items():
                        if isinstance(v, float):
                            self.writer.add_scalar(f"{record['event']}/{key}_{sub}", v, step)
                elif isinstance(value, float) and key not in ("wall_s", "train_wall_s", "epoch"):
                    self.writer.add_scalar(f"{record['event']}/{key}", value, step)

    def close(self) -> None:
        if self.writer is not None:
            self.writer.close()


def hardware_description(device: torch.device) -> str:
    """One line naming the machine a run used (the leaderboard's hardware column)."""
    if device.type == "cuda":
        return f"{torch.cuda.get_device_name(device)} (CUDA {torch.version.cuda})"
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"CPU: {cpu}, {torch.get_num_threads()} threads"


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
    (:mod:`hupbench.frames`), batches gathered in one call, augmentation per batch on ``device``.
    jpeg: the reference reader, a JPEG decoded and augmented per item in the loader workers.
    """
    from hupbench.data import HUPDataset
    from hupbench.frames import BatchAugment, CachedFrames, collate_batch

    root = Path(cfg.data.root)
    reader = build(cfg.data.reader)
    pipeline = cfg.data.get("pipeline", "cache")
    if pipeline not in ("cache", "jpeg"):
        raise ValueError(f"data.pipeline must be 'cache' or 'jpeg', got {pipeline!r}")
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


def learning_rate(cfg: DictConfig, world: int) -> float:
    """The optimiser's learning rate for this run's global batch.

    ``optim.reference_batch`` null: ``optim.optimizer.lr`` as given. A number N: linear scaling
    (Goyal et al. 2017, "Accurate, large minibatch SGD"), lr x global batch / N, which the
    scheduler's linear warm-up makes safe in the first steps.
    """
    lr = float(cfg.optim.optimizer.lr)
    reference = cfg.optim.get("reference_batch")
    if reference is None:
        return lr
    if isinstance(reference, bool) or not isinstance(reference, int) or reference < 1:
        raise ValueError(f"optim.reference_batch must be null or a positive int, got {reference!r}")
    return lr * int(cfg.data.batch_size) * world / reference


def train_step(model, optimizer, scheduler, batch: dict, epoch: int, data: TrainData, cfg: DictConfig,
               device: torch.device, autocast: dict) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """One optimiser step on one batch; returns the detached loss and its terms (no device sync)."""
    if data.augment is not None:
        batch = {name: value.to(device, non_blocking=True) for name, value in batch.items()}
        batch = data.augment(batch, epoch)
    images = model_images(batch["image"], device, bool(cfg.channels_last))
    targets = {k: batch[k].to(device, non_blocking=True) for k in ("keypoints_2d", "keypoints_3d")}
    with torch.autocast(**autocast):
        output = model(images)
    loss, terms = loss_terms(output, targets, cfg.loss)
    optimizer.zero_grad(set_to_none=True)
    loss.backward()
    optimizer.step()
    scheduler.step()
    return loss.detach(), terms


#: config fields that count steps or frames: each a whole number >= 1 (None allowed where listed)
SCHEDULE_FIELDS = {"data.batch_size": False, "train.epochs": False, "train.max_steps": True,
                   "train.stop_after": True, "train.log_every": False, "train.val_every": False,
                   "train.ckpt_every": False}
#: the most steps, epochs or frames per batch a run may ask for: 10^9 steps take years at any speed
#: measured here, so a larger number is a typo (train.max_steps=1e12 would train until killed)
MAX_COUNT = 1_000_000_000
#: learning rates above this make every model here diverge within a few steps
MAX_LR = 1.0


def _whole(cfg: DictConfig, field: str, low: int, optional: bool = False, high: int = MAX_COUNT) -> None:
    value = OmegaConf.select(cfg, field)
    if value is None and optional:
        return
    if isinstance(value, bool) or not isinstance(value, int) or value < low:
        raise ValueError(f"{field} must be a whole number >= {low}{' or null' if optional else ''}, got {value!r}")
    if value > high:
        raise ValueError(f"{field} must be at most {high:,}, got {value:,}")


def _number(cfg: DictConfig, field: str, low: float, high: float | None = None, low_open: bool = False) -> None:
    value = OmegaConf.select(cfg, field)
    ok = (not isinstance(value, bool) and isinstance(value, (int, float)) and math.isfinite(value)
          and (value > low if low_open else value >= low) and (high is None or value <= high))
    if not ok:
        interval = (f"in {'(' if low_open else '['}{low:g}, {high:g}]" if high is not None
                    else f"{'>' if low_open else '>='} {low:g}")
        raise ValueError(f"{field} must be a finite number {interval}, got {value!r}")


def _choice(cfg: DictConfig, field: str, choices, default=None) -> None:
    value = OmegaConf.select(cfg, field, default=default)
    if value not in choices:
        raise ValueError(f"{field} must be {' or '.join(repr(c) for c in choices)}, got {value!r}")


def check_schedule(cfg: DictConfig) -> None:
    """Refuse a batch size or step count that is not a whole number from 1 to :data:`MAX_COUNT` (0 used to
    divide by zero or, for max_steps, to train the epochs default without a word), naming the field."""
    for field, optional in SCHEDULE_FIELDS.items():
        _whole(cfg, field, 1, optional)


def check_config(cfg: DictConfig) -> None:
    """Every number and choice of a training config that the run uses, checked before anything is read or
    written; the error names the field and what it must be (Hydra passes ``data.batch_size=abc`` on as a
    string, ``optim.optimizer.lr=nan`` as a float)."""
    from hupbench.data import MAX_INPUT_SIZE, MIN_INPUT_SIZE
    from hupbench.metrics import PROBE_SYMMETRIES

    check_schedule(cfg)
    _whole(cfg, "data.num_workers", 0, high=1024)
    _whole(cfg, "threads", 1, optional=True, high=4096)
    _whole(cfg, "seed", 0, high=2**31 - 1)
    _whole(cfg, "data.val_frames", 1, optional=True)
    _whole(cfg, "train.bn_recompute_frames", 0)
    _whole(cfg, "data.reader.input_size", MIN_INPUT_SIZE, high=MAX_INPUT_SIZE)
    _number(cfg, "data.reader.rotate_deg", 0.0, 180.0)
    _number(cfg, "data.reader.photometric", 0.0, 1.0)
    _number(cfg, "optim.optimizer.lr", 0.0, MAX_LR, low_open=True)
    for weight in ("w2d_init", "w2d", "w3d"):
        _number(cfg, f"loss.{weight}", 0.0)
    _number(cfg, "loss.unit_3d_m", 0.0, low_open=True)
    _choice(cfg, "loss.probe_symmetry", sorted(PROBE_SYMMETRIES), default="none")
    _choice(cfg, "device", ("cpu", "cuda"))
    _choice(cfg, "precision", ("fp32", "bf16"))
    _choice(cfg, "data.pipeline", ("cache", "jpeg"), default="cache")


def run_train(cfg: DictConfig, log=print) -> dict:
    """Train a model on a hupbench dataset.

    Args:
        cfg: the composed ``train`` config (conf/train.yaml).

    The run folder is held by one run at a time (``datagen.io.OutputLock``, rank 0 only: a second run
    on it is refused naming the holder's pid and host; the lock of a killed run is taken over), and the
    temporary files that killed runs left in it are removed first.

    Returns:
        dict with "run_dir", "checkpoint" (last.pt), "best_checkpoint", "steps", "samples_seen",
        "train_seconds", "wall_seconds", "val_mpjpe_mm" (last validation) and "first_val_mpjpe_mm".

    Raises:
        ValueError: a config value, the dataset or a checkpoint to resume is wrong (the message names
        the field or file). OSError: a file is missing or cannot be written (a full disk names the
        device). datagen.io.LockedError: another run holds the run folder.
    """
    from hupbench.data import read_manifest

    check_config(cfg)
    world, rank, local_rank = _dist_env()
    device = _device(cfg, local_rank)
    if cfg.threads is not None:
        torch.set_num_threads(int(cfg.threads))
    run_dir = Path(cfg.run_dir) if cfg.run_dir else Path(cfg.out_root) / cfg.run_name
    root = Path(cfg.data.root)

    # -- everything that can be wrong is checked before the first step
    manifest = read_manifest(root, needs="the models are built for")
    if run_dir.exists() and not run_dir.is_dir():
        raise ValueError(f"run_dir {run_dir} is a file; expected a folder for the run (or a path to make one)")
    # one run per folder: a second run would append every step to metrics.jsonl a second time and
    # overwrite the first's checkpoints. Rank 0 writes every file of a run, so it alone holds the lock
    made = not run_dir.exists()
    lock = OutputLock(run_dir, "training").acquire() if rank == 0 else None
    try:
        if lock is not None:
            for stale in clean_stale_tmp(run_dir):
                log(f"removed {stale}, a temporary file of a run that was killed")
            if lock.taken_over:
                log(f"took over {run_dir} from a run that is gone (pid {lock.taken_over.get('pid')} on "
                    f"{lock.taken_over.get('host')})")
        return _run_locked(cfg, log, world, rank, device, run_dir, root, manifest)
    finally:
        if lock is not None:
            lock.release()
            if made and run_dir.is_dir() and not any(run_dir.iterdir()):
                run_dir.rmdir()  # a run refused before it wrote anything leaves no folder


def _run_locked(cfg: DictConfig, log, world: int, rank: int, device: torch.device, run_dir: Path, root: Path,
                manifest: dict) -> dict:
    """:func:`run_train` once the run folder is this run's."""
    from hupbench.data import resize_intrinsics

    data = setup_data(cfg, world, rank, device, log)
    train_ann = data.train_set.ann
    resume_path = _resume_path(cfg, run_dir)
    resolved = OmegaConf.to_container(cfg, resolve=True)
    checkpoint = None
    if resume_path is not None:
        checkpoint = read_checkpoint(resume_path)
        diff = _config_diff(checkpoint["config"], resolved)
        if diff:
            shown = "; ".join(diff[:MAX_DIFFS_SHOWN]) + (f"; and {len(diff) - MAX_DIFFS_SHOWN} more"
                                                         if len(diff) > MAX_DIFFS_SHOWN else "")
            raise ValueError(f"checkpoint {resume_path} was trained with another config; differences: {shown}")
    input_size = int(cfg.data.reader.input_size)
    K_input = resize_intrinsics(train_ann["K"][0], input_size / int(manifest["image_size"][0]))
    model = build_run_model(cfg, train_ann, K_input, checkpoint, resume_path)

    steps_per_epoch = data.sampler.batches_per_epoch
    total_steps = int(cfg.train.max_steps) if cfg.train.max_steps is not None else int(cfg.train.epochs) * steps_per_epoch
    if total_steps < 1:
        raise ValueError(f"the run has no steps (train.max_steps={cfg.train.max_steps}, epochs={cfg.train.epochs})")
    optimizer = build(cfg.optim.optimizer)(model.parameters(), lr=learning_rate(cfg, world))
    scheduler = build(cfg.optim.scheduler)(optimizer, total_steps=total_steps)

    model.to(device)
    if cfg.channels_last:
        model.to(memory_format=torch.channels_last)
    autocast = {"device_type": device.type, "dtype": torch.bfloat16, "enabled": cfg.precision == "bf16"}
    train_model = model
    if world > 1:
        if not torch.distributed.is_initialized():
            torch.distributed.init_process_group(backend="nccl" if device.type == "cuda" else "gloo")
        train_model = torch.nn.parallel.DistributedDataParallel(
            model, device_ids=[device.index] if device.type == "cuda" else None)
    if cfg.get("compile", False):
        train_model = torch.compile(train_model)

    state = RunState()
    if checkpoint is not None:
        optimizer.load_state_dict(checkpoint["optimizer"])
        scheduler.load_state_dict(checkpoint["scheduler"])
        state = RunState.from_checkpoint(checkpoint)
        torch.set_rng_state(checkpoint["rng"]["torch"])

    is_main = rank == 0
    if is_main:
        run_dir.mkdir(parents=True, exist_ok=True)
        write_json(run_dir / "run.json", run_info(cfg, verb="train", world_size=world,
                                                  hardware=hardware_description(device), resumed_from=(
                                                      str(resume_path) if resume_path else None)))
    logger = _Log(run_dir, is_main, bool(cfg.train.tensorboard), state.step if checkpoint is not None else None)
    base = {"K_input": K_input.tolist(), "input_size": input_size, "config": resolved,
            "dataset": {"path": str(root.resolve()), "manifest_sha256": file_sha256(root / "manifest.json")}}
    run = _Run(cfg, model, optimizer, scheduler, data, state, logger, run_dir, base, device, autocast, world,
               is_main, steps_per_epoch)

    if is_main:
        log(f"training {model.config['name']} ({model.config['backbone']}, {input_size} px) on {root}: "
            f"{len(data.train_set)} train frames, {len(data.val_loader.dataset)} val frames, {total_steps} steps of "
            f"{int(cfg.data.batch_size) * world} on {device}{f' x {world} processes' if world > 1 else ''}; "
            f"run folder {run_dir}")
    state.first_val = run.validation() if checkpoint is None else checkpoint.get("first_val_mpjpe_mm")
    base["first_val_mpjpe_mm"] = state.first_val
    run.loop(train_model, total_steps)
    logger.close()
    wall = state.wall_offset + time.perf_counter() - run.start
    result = {"run_dir": str(run_dir), "checkpoint": str(run_dir / "checkpoints" / "last.pt"),
              "best_checkpoint": str(run_dir / "checkpoints" / "best.pt"), "steps": state.step,
              "samples_seen": state.samples_seen, "epochs": state.step / steps_per_epoch,
              "train_seconds": state.train_seconds, "wall_seconds": wall, "val_mpjpe_mm": state.last_val,
              "first_val_mpjpe_mm": state.first_val, "best_val_mpjpe_mm": state.best, "world_size": world,
              "complete": True}
    if state.step < total_steps:
        if is_main:
            log(f"stopped at step {state.step} of {total_steps} (train.stop_after); rerun with train.resume=auto "
                "to continue")
        return result | {"complete": False}
    if is_main:
        write_json(run_dir / "summary.json", result)
        first, last = state.first_val, state.last_val
        log(f"finished {state.step} steps in {wall / 60:.1f} min ({state.samples_seen / max(state.train_seconds, 1e-9):.1f} "
            f"img/s training); val MPJPE {first['all']:.1f} -> {last['all']:.1f} mm "
            f"(hand {last['hand']:.1f}, probe {last['probe']:.1f})")
    return result


def main(cfg: DictConfig, log=print, debug: bool = False) -> float:
    """The body of ``python train.py``: :func:`run_train`, with a bad input or a failure answered as one
    line on stderr, ``train.py: error: ...``, and exit code 1 (SystemExit); ``debug`` (train.py passes
    Hydra's HYDRA_FULL_ERROR=1) lets the traceback through instead.

    Returns:
        The last validation MPJPE (all keypoints, mm): what a Hydra sweeper minimises.
    """
    from hydra.errors import HydraException
    from omegaconf.errors import OmegaConfBaseException

    try:
        result = run_train(cfg, log)
    except (*USER_ERRORS, HydraException, OmegaConfBaseException) as exc:
        if debug:
            raise
        print(f"train.py: error: {error_line(exc)}", file=sys.stderr)
        raise SystemExit(1) from None
    return result["val_mpjpe_mm"]["all"]


def build_run_model(cfg: DictConfig, train_ann: dict, K_input: np.ndarray, checkpoint: dict | None,
                    resume_path: Path | None) -> torch.nn.Module:
    """The run's model: built from its config with the training split's mean layout as its 3D prior
    (and the input camera for models that unproject through it), or the checkpoint's when resuming."""
    if checkpoint is not None:
        mean_layout = checkpoint["model_config"].get("points3d_mean")
    else:
        # the prior: the training split's mean camera-frame layout, (29, 3) metres
        mean_layout = train_ann["keypoints_3d_cam"].astype(np.float64).mean(axis=0).tolist()
    model_cfg = {**OmegaConf.to_container(cfg.model, resolve=True), "points3d_mean": mean_layout}
    # models that unproject through the input camera get it from the data (config value null)
    if "K_input" in model_cfg and model_cfg["K_input"] is None:
        model_cfg["K_input"] = np.asarray(K_input, dtype=np.float64).tolist()
    if "input_size" in model_cfg and model_cfg["input_size"] is None:
        model_cfg["input_size"] = int(cfg.data.reader.input_size)
    torch.manual_seed(int(cfg.seed))  # the initial weights are a function of the seed
    model = build(OmegaConf.create(model_cfg))
    if model.config["n_keypoints"] != kp.NUM_KEYPOINTS:
        raise ValueError(f"model.n_keypoints={model.config['n_keypoints']} but the dataset has {kp.NUM_KEYPOINTS} "
                         "keypoints")
    if checkpoint is not None:
        from models.build import load_checkpoint_state

        if checkpoint["model_config"].get("name") != model.config["name"]:
            raise ValueError(f"checkpoint {resume_path} holds a {checkpoint['model_config'].get('name')!r} model, "
                             f"this run builds {model.config['name']!r}")
        try:
            load_checkpoint_state(model, checkpoint["model"])
        except (ValueError, TypeError) as exc:
            raise ValueError(f"checkpoint {resume_path}: {exc}") from exc
    return model


@dataclass
class RunState:
    """Counters of a run that a checkpoint carries across a resume."""

    step: int = 0
    samples_seen: int = 0
    train_seconds: float = 0.0
    wall_offset: float = 0.0
    best: float = math.inf
    first_val: dict | None = None
    last_val: dict | None = None

    @classmethod
    def from_checkpoint(cls, checkpoint: dict) -> "RunState":
        return cls(int(checkpoint["step"]), int(checkpoint["samples_seen"]), float(checkpoint["train_seconds"]),
                   float(checkpoint["wall_seconds"]), float(checkpoint.get("best_val_mpjpe_mm", math.inf)),
                   checkpoint.get("first_val_mpjpe_mm"), checkpoint.get("val_mpjpe_mm"))


class _Run:
    """The loop of one run: steps, logging, validation and checkpoints (state in :class:`RunState`)."""

    def __init__(self, cfg, model, optimizer, scheduler, data: TrainData, state: RunState, logger, run_dir: Path,
                 base: dict, device, autocast, world: int, is_main: bool, steps_per_epoch: int) -> None:
        self.cfg, self.model, self.optimizer, self.scheduler, self.data = cfg, model, optimizer, scheduler, data
        self.state, self.logger, self.run_dir, self.base = state, logger, run_dir, base
        self.device, self.autocast, self.world, self.is_main = device, autocast, world, is_main
        self.steps_per_epoch = steps_per_epoch
        self.start = time.perf_counter()

    def wall(self) -> float:
        return self.state.wall_offset + time.perf_counter() - self.start

    def save(self, name: str) -> None:
        s = self.state
        save_checkpoint(self.run_dir / "checkpoints" / name, {
            **self.base, "model_config": self.model.config, "model": self.model.state_dict(),
            "optimizer": self.optimizer.state_dict(), "scheduler": self.scheduler.state_dict(), "step": s.step,
            "epoch": s.step / self.steps_per_epoch, "samples_seen": s.samples_seen, "train_seconds": s.train_seconds,
            "wall_seconds": self.wall(), "best_val_mpjpe_mm": s.best, "val_mpjpe_mm": s.last_val,
            "rng": {"torch": torch.get_rng_state()}, "world_size": self.world})

    def validation(self) -> dict:
        s = self.state
        if self.data.bn_loader is not None and s.step > 0:
            recompute_bn_statistics(self.model, self.data.bn_loader, self.device, self.autocast)
        val = validate(self.model, self.data.val_loader, self.device, self.autocast, self.world)
        self.logger({"event": "val", "step": s.step, "epoch": s.step / self.steps_per_epoch,
                     "samples_seen": s.samples_seen, "wall_s": self.wall(), "train_wall_s": s.train_seconds,
                     "val_mpjpe_mm": {k: val[k] for k in ("all", "hand", "probe")}, "val_frames": val["frames"]})
        s.last_val = val
        if self.is_main and val["all"] < s.best:
            s.best = val["all"]
            self.save("best.pt")
        return val

    def loop(self, train_model, total_steps: int) -> None:
        """Train until ``total_steps`` (or ``train.stop_after``). The device is waited for only when a
        number is read: at log, validation and checkpoint steps (``train_seconds`` counts the time
        between them, data loading included, validation and checkpoints excluded)."""
        cfg, s, train = self.cfg, self.state, self.cfg.train
        stop_after = None if train.stop_after is None else int(train.stop_after)
        progress = None
        if self.is_main and train.progress:
            from tqdm import tqdm

            progress = tqdm(total=total_steps, initial=s.step, unit="step", dynamic_ncols=True)
        batch_size = int(cfg.data.batch_size) * self.world
        self.model.train()
        segment = time.perf_counter()
        while s.step < total_steps and (stop_after is None or s.step < stop_after):
            epoch, start_batch = divmod(s.step, self.steps_per_epoch)
            if hasattr(self.data.train_set, "set_epoch"):
                self.data.train_set.set_epoch(epoch)
            self.data.sampler.set_position(epoch, start_batch)
            for batch in self.data.train_loader:
                loss, terms = train_step(train_model, self.optimizer, self.scheduler, batch, epoch, self.data, cfg,
                                         self.device, self.autocast)
                s.step += 1
                s.samples_seen += batch_size
                if progress is not None:
                    progress.update(1)
                validating = s.step % train.val_every == 0 or s.step == total_steps
                stopping = stop_after is not None and s.step >= stop_after
                saving = s.step % train.ckpt_every == 0 or s.step == total_steps or stopping
                logging = s.step % train.log_every == 0 or s.step == 1
                if logging or validating or saving:
                    if not torch.isfinite(loss):
                        raise FloatingPointError(f"loss became {float(loss)} at step {s.step}; terms "
                                                 f"{ {k: float(v) for k, v in terms.items()} }")
                    s.train_seconds += time.perf_counter() - segment   # float(loss) above waited for the device
                if logging:
                    self.logger({"event": "train", "step": s.step, "samples_seen": s.samples_seen,
                                 "wall_s": self.wall(), "train_wall_s": s.train_seconds, "loss": float(loss),
                                 **{k: float(v) for k, v in terms.items()}, "lr": self.scheduler.get_last_lr()[0]})
                    if progress is not None:
                        progress.set_postfix(loss=f"{float(loss):.4f}",
                                             val_mm=f"{s.last_val['all']:.1f}" if s.last_val else "-")
                if validating:
                    self.validation()
                if saving:
                    if self.data.bn_loader is not None and not validating:
                        recompute_bn_statistics(self.model, self.data.bn_loader, self.device, self.autocast)
                    if self.is_main:
                        self.save("last.pt")
                if logging or validating or saving:
                    segment = time.perf_counter()
                if s.step >= total_steps or stopping:
                    break
        if progress is not None:
            progress.close()
