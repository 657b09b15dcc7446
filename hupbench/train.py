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

import json
import math
import os
import platform
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import torch
from omegaconf import DictConfig, OmegaConf

from datagen import keypoints as kp
from datagen.io import write_bytes, write_json
from hupbench.checkpoint import file_sha256, read_checkpoint, save_checkpoint
from hupbench.config import build
from hupbench.provenance import run_info

# config keys that may differ between a run and the run it resumes
RESUME_FREE_KEYS = ("train.resume", "train.progress", "train.stop_after", "run_dir", "threads", "data.num_workers",
                    "label")


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


def hopenet_loss(output, batch: dict, weights: DictConfig | dict) -> tuple[torch.Tensor, dict[str, float]]:
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
        (total loss, {term name: value}) with the unweighted terms for logging; with half_turn also
        "probe_half_turned", the fraction of samples whose corners were relabelled.
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
    logged = {name: float(value.detach()) for name, value in terms.items()}
    if choice is not None:
        logged["probe_half_turned"] = float((choice != 0).float().mean())
    return total, logged


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
        raise FileNotFoundError(f"train.resume={mode}: no such checkpoint")
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
            model(batch["image"].to(device, non_blocking=True))
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
        images = batch["image"].to(device, non_blocking=True)
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
            self.path.write_text("")
        elif self.path.exists():
            # drop lines a killed run wrote after its last checkpoint: they are about to be redone
            kept = [line for line in self.path.read_text().splitlines()
                    if line.strip() and json.loads(line)["step"] <= resume_step]
            write_bytes(self.path, "".join(line + "\n" for line in kept).encode())
        if tensorboard:
            from torch.utils.tensorboard import SummaryWriter

            self.writer = SummaryWriter(str(run_dir / "tb"), purge_step=resume_step)

    def __call__(self, record: dict) -> None:
        if not self.enabled:
            return
        with open(self.path, "a") as f:
            f.write(json.dumps(record, sort_keys=True) + "\n")
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


def run_train(cfg: DictConfig, log=print) -> dict:
    """Train a model on a hupbench dataset.

    Args:
        cfg: the composed ``train`` config (conf/train.yaml).

    Returns:
        dict with "run_dir", "checkpoint" (last.pt), "best_checkpoint", "steps", "samples_seen",
        "train_seconds", "wall_seconds", "val_mpjpe_mm" (last validation) and "first_val_mpjpe_mm".
    """
    from hupbench.data import HUPDataset, read_manifest, resize_intrinsics

    world, rank, local_rank = _dist_env()
    device = _device(cfg, local_rank)
    if cfg.precision not in ("fp32", "bf16"):
        raise ValueError(f"precision must be 'fp32' or 'bf16', got {cfg.precision!r}")
    if cfg.threads is not None:
        torch.set_num_threads(int(cfg.threads))
    run_dir = Path(cfg.run_dir) if cfg.run_dir else Path(cfg.out_root) / cfg.run_name
    root = Path(cfg.data.root)

    # -- everything that can be wrong is checked before the first step
    manifest = read_manifest(root, needs="the models are built for")
    reader = build(cfg.data.reader)
    train_set = HUPDataset(root, cfg.data.train_split, reader)
    val_reader = type(reader)(input_size=reader.input_size, rotate_deg=0.0, photometric=0.0, seed=reader.seed)
    val_set = HUPDataset(root, cfg.data.val_split, val_reader)
    resume_path = _resume_path(cfg, run_dir)
    resolved = OmegaConf.to_container(cfg, resolve=True)
    checkpoint = None
    if resume_path is not None:
        checkpoint = read_checkpoint(resume_path)
        diff = _config_diff(checkpoint["config"], resolved)
        if diff:
            raise ValueError(f"checkpoint {resume_path} was trained with another config; differences: "
                             + "; ".join(diff))
        mean_layout = checkpoint["model_config"].get("points3d_mean")
    else:
        # the prior: the training split's mean camera-frame layout, (29, 3) metres
        mean_layout = train_set.ann["keypoints_3d_cam"].astype(np.float64).mean(axis=0).tolist()
    torch.manual_seed(int(cfg.seed))  # the initial weights are a function of the seed
    model = build(OmegaConf.create({**OmegaConf.to_container(cfg.model, resolve=True), "points3d_mean": mean_layout}))
    if model.config["n_keypoints"] != kp.NUM_KEYPOINTS:
        raise ValueError(f"model.n_keypoints={model.config['n_keypoints']} but the dataset has {kp.NUM_KEYPOINTS} "
                         "keypoints")
    if checkpoint is not None:
        from models.build import load_checkpoint_state

        if checkpoint["model_config"].get("name") != model.config["name"]:
            raise ValueError(f"checkpoint {resume_path} holds a {checkpoint['model_config'].get('name')!r} model, "
                             f"this run builds {model.config['name']!r}")
        load_checkpoint_state(model, checkpoint["model"])

    batch_size = int(cfg.data.batch_size)
    sampler = EpochSampler(len(train_set), batch_size, int(cfg.seed), world, rank)
    steps_per_epoch = sampler.batches_per_epoch
    total_steps = int(cfg.train.max_steps) if cfg.train.max_steps else int(cfg.train.epochs) * steps_per_epoch
    if total_steps < 1:
        raise ValueError(f"the run has no steps (train.max_steps={cfg.train.max_steps}, epochs={cfg.train.epochs})")
    optimizer = build(cfg.optim.optimizer)(model.parameters())
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

    step, samples_seen, train_seconds, wall_offset = 0, 0, 0.0, 0.0
    best = math.inf
    if checkpoint is not None:
        optimizer.load_state_dict(checkpoint["optimizer"])
        scheduler.load_state_dict(checkpoint["scheduler"])
        step, samples_seen = int(checkpoint["step"]), int(checkpoint["samples_seen"])
        train_seconds, wall_offset = float(checkpoint["train_seconds"]), float(checkpoint["wall_seconds"])
        best = float(checkpoint.get("best_val_mpjpe_mm", math.inf))
        torch.set_rng_state(checkpoint["rng"]["torch"])

    is_main = rank == 0
    if is_main:
        run_dir.mkdir(parents=True, exist_ok=True)
        write_json(run_dir / "run.json", run_info(cfg, verb="train", world_size=world,
                                                  hardware=hardware_description(device), resumed_from=(
                                                      str(resume_path) if resume_path else None)))
    logger = _Log(run_dir, is_main, bool(cfg.train.tensorboard), step if checkpoint is not None else None)
    loader_args = {"batch_size": batch_size, "num_workers": int(cfg.data.num_workers),
                   "pin_memory": device.type == "cuda"}
    val_indices = np.arange(len(val_set))
    if cfg.data.val_frames is not None and cfg.data.val_frames < len(val_set):
        val_indices = np.linspace(0, len(val_set) - 1, int(cfg.data.val_frames)).round().astype(int)
    val_loader = torch.utils.data.DataLoader(
        torch.utils.data.Subset(val_set, val_indices[rank::world].tolist()), shuffle=False, **loader_args)
    bn_loader = None
    if cfg.train.bn_recompute_frames:
        # un-augmented training frames, a fixed draw: the statistics the model meets at test time
        plain_train = HUPDataset(root, cfg.data.train_split, val_reader)
        n_bn = min(int(cfg.train.bn_recompute_frames), len(plain_train))
        bn_indices = np.random.default_rng(int(cfg.seed)).choice(len(plain_train), n_bn, replace=False)
        bn_loader = torch.utils.data.DataLoader(torch.utils.data.Subset(plain_train, sorted(bn_indices.tolist())),
                                                shuffle=False, **loader_args)

    K_input = resize_intrinsics(train_set.ann["K"][0], reader.input_size / int(manifest["image_size"][0]))
    base = {"K_input": K_input.tolist(), "input_size": reader.input_size, "config": resolved,
            "dataset": {"path": str(root.resolve()), "manifest_sha256": file_sha256(root / "manifest.json")}}

    def save(name: str, val: dict | None) -> None:
        save_checkpoint(run_dir / "checkpoints" / name, {
            **base, "model_config": model.config, "model": model.state_dict(),
            "optimizer": optimizer.state_dict(), "scheduler": scheduler.state_dict(), "step": step,
            "epoch": step / steps_per_epoch, "samples_seen": samples_seen, "train_seconds": train_seconds,
            "wall_seconds": wall_offset + time.perf_counter() - start, "best_val_mpjpe_mm": best,
            "val_mpjpe_mm": val, "rng": {"torch": torch.get_rng_state()}, "world_size": world})

    def run_validation() -> dict:
        nonlocal best
        if bn_loader is not None and step > 0:
            recompute_bn_statistics(model, bn_loader, device, autocast)
        val = validate(model, val_loader, device, autocast, world)
        record = {"event": "val", "step": step, "epoch": step / steps_per_epoch, "samples_seen": samples_seen,
                  "wall_s": wall_offset + time.perf_counter() - start, "train_wall_s": train_seconds,
                  "val_mpjpe_mm": {k: val[k] for k in ("all", "hand", "probe")}, "val_frames": val["frames"]}
        logger(record)
        if is_main and val["all"] < best:
            best = val["all"]
            save("best.pt", val)
        return val

    start = time.perf_counter()
    if is_main:
        log(f"training {model.config['name']} ({model.config['backbone']}, {reader.input_size} px) on {root}: "
            f"{len(train_set)} train frames, {len(val_indices)} val frames, {total_steps} steps of "
            f"{batch_size * world} on {device}{f' x {world} processes' if world > 1 else ''}; run folder {run_dir}")
    first_val = run_validation() if checkpoint is None else checkpoint.get("first_val_mpjpe_mm")
    base["first_val_mpjpe_mm"] = first_val
    last_val = checkpoint.get("val_mpjpe_mm") if checkpoint is not None else first_val
    progress = None
    if is_main and cfg.train.progress:
        from tqdm import tqdm

        progress = tqdm(total=total_steps, initial=step, unit="step", dynamic_ncols=True)
    model.train()
    while step < total_steps:
        epoch, start_batch = divmod(step, steps_per_epoch)
        train_set.set_epoch(epoch)
        sampler.set_position(epoch, start_batch)
        loader = torch.utils.data.DataLoader(train_set, sampler=sampler, drop_last=True, **loader_args)
        for batch in loader:
            t0 = time.perf_counter()
            images = batch["image"].to(device, non_blocking=True)
            if cfg.channels_last:
                images = images.contiguous(memory_format=torch.channels_last)
            targets = {k: batch[k].to(device, non_blocking=True) for k in ("keypoints_2d", "keypoints_3d")}
            with torch.autocast(**autocast):
                output = train_model(images)
            loss, terms = hopenet_loss(output, targets, cfg.loss)
            if not torch.isfinite(loss):
                raise FloatingPointError(f"loss became {float(loss)} at step {step}; terms {terms}")
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
            scheduler.step()
            step += 1
            samples_seen += batch_size * world
            if device.type == "cuda":
                torch.cuda.synchronize(device)
            train_seconds += time.perf_counter() - t0
            if progress is not None:
                progress.update(1)
                progress.set_postfix(loss=f"{float(loss.detach()):.4f}", val_mm=f"{last_val['all']:.1f}" if last_val else "-")
            if step % cfg.train.log_every == 0 or step == 1:
                logger({"event": "train", "step": step, "samples_seen": samples_seen,
                        "wall_s": wall_offset + time.perf_counter() - start, "train_wall_s": train_seconds,
                        "loss": float(loss.detach()), **terms, "lr": scheduler.get_last_lr()[0]})
            validated = step % cfg.train.val_every == 0 or step == total_steps
            if validated:
                last_val = run_validation()
            stopping = cfg.train.stop_after is not None and step >= int(cfg.train.stop_after)
            if step % cfg.train.ckpt_every == 0 or step == total_steps or stopping:
                if bn_loader is not None and not validated:
                    recompute_bn_statistics(model, bn_loader, device, autocast)  # eval-ready weights
                if is_main:
                    save("last.pt", last_val)
            if step >= total_steps or stopping:
                break
        if cfg.train.stop_after is not None and step >= int(cfg.train.stop_after):
            break
    if progress is not None:
        progress.close()
    logger.close()
    wall = wall_offset + time.perf_counter() - start
    result = {"run_dir": str(run_dir), "checkpoint": str(run_dir / "checkpoints" / "last.pt"),
              "best_checkpoint": str(run_dir / "checkpoints" / "best.pt"), "steps": step,
              "samples_seen": samples_seen, "epochs": step / steps_per_epoch, "train_seconds": train_seconds,
              "wall_seconds": wall, "val_mpjpe_mm": last_val, "first_val_mpjpe_mm": first_val,
              "best_val_mpjpe_mm": best, "world_size": world, "complete": True}
    if step < total_steps:
        if is_main:
            log(f"stopped at step {step} of {total_steps} (train.stop_after); rerun with train.resume=auto to continue")
        return result | {"complete": False}
    if is_main:
        write_json(run_dir / "summary.json", result)
        log(f"finished {step} steps in {wall / 60:.1f} min ({samples_seen / max(train_seconds, 1e-9):.1f} img/s "
            f"training); val MPJPE {first_val['all']:.1f} -> {last_val['all']:.1f} mm "
            f"(hand {last_val['hand']:.1f}, probe {last_val['probe']:.1f})")
    return result
