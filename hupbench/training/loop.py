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

import math
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from omegaconf import DictConfig, OmegaConf

import numpy as np
import torch

from datagen import keypoints as kp
from datagen.io import OutputLock, clean_stale_tmp, write_json
from hupbench.error_lines import USER_ERRORS, error_line
from hupbench.checkpoint import file_sha256, read_checkpoint, save_checkpoint
from hupbench.config import build
from hupbench.data import model_images
from hupbench.provenance import hardware_description, run_info
from hupbench.training.checks import check_config
from hupbench.training.losses import loss_terms
from hupbench.training.schedule import learning_rate
from hupbench.training.validation import recompute_bn_statistics, validate
from hupbench.training.run_log import MetricsLog
from hupbench.data import TrainData, setup_data
from datagen.errors import BadValueError, MissingFileError, RunFailedError


# config keys that may differ between a run and the run it resumes
#: config differences a refused resume lists (a checkpoint of another project differs everywhere)
MAX_DIFFS_SHOWN = 8
RESUME_FREE_KEYS = ("train.resume", "train.progress", "train.stop_after", "run_dir", "threads", "data.num_workers",
                    "data.cache_dir", "label")


# schedule and loss


# distributed helpers (torchrun sets WORLD_SIZE, RANK, LOCAL_RANK)


def _dist_env() -> tuple[int, int, int]:
    world = int(os.environ.get("WORLD_SIZE", "1"))
    return world, int(os.environ.get("RANK", "0")), int(os.environ.get("LOCAL_RANK", "0"))


def _device(cfg: DictConfig, local_rank: int) -> torch.device:
    if cfg.device == "cpu":
        return torch.device("cpu")
    if cfg.device == "cuda":
        if not torch.cuda.is_available():
            raise RunFailedError("device=cuda was asked for but CUDA is not available here "
                               f"(torch {torch.__version__}); use device=cpu")
        return torch.device("cuda", local_rank)
    raise BadValueError(f"device must be 'cpu' or 'cuda', got {cfg.device!r}")


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
            raise BadValueError(f"{run_dir} already holds a checkpoint ({last}); use train.resume=auto to continue it "
                             "or another run_name")
        return None
    if mode == "auto":
        return last if last.exists() else None
    path = Path(mode)
    if not path.is_file():
        raise MissingFileError(f"train.resume={mode}: checkpoint {path} does not exist")
    return path


# validation


# the run


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
        raise BadValueError(f"run_dir {run_dir} is a file; expected a folder for the run (or a path to make one)")
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
    from datagen.camera import resize_intrinsics

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
            raise BadValueError(f"checkpoint {resume_path} was trained with another config; differences: {shown}")
    input_size = int(cfg.data.reader.input_size)
    K_input = resize_intrinsics(train_ann["K"][0], input_size / int(manifest["image_size"][0]))
    model = build_run_model(cfg, train_ann, K_input, checkpoint, resume_path)

    steps_per_epoch = data.sampler.batches_per_epoch
    total_steps = int(cfg.train.max_steps) if cfg.train.max_steps is not None else int(cfg.train.epochs) * steps_per_epoch
    if total_steps < 1:
        raise BadValueError(f"the run has no steps (train.max_steps={cfg.train.max_steps}, epochs={cfg.train.epochs})")
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
    logger = MetricsLog(run_dir, is_main, bool(cfg.train.tensorboard), state.step if checkpoint is not None else None)
    checkpoint_fields = {"K_input": K_input.tolist(), "input_size": input_size, "config": resolved,
            "dataset": {"path": str(root.resolve()), "manifest_sha256": file_sha256(root / "manifest.json")}}
    run = _Run(cfg, model, optimizer, scheduler, data, state, logger, run_dir, checkpoint_fields, device, autocast,
               world, is_main, steps_per_epoch)

    if is_main:
        log(f"training {model.config['name']} ({model.config['backbone']}, {input_size} px) on {root}: "
            f"{len(data.train_set)} train frames, {len(data.val_loader.dataset)} val frames, {total_steps} steps of "
            f"{int(cfg.data.batch_size) * world} on {device}{f' x {world} processes' if world > 1 else ''}; "
            f"run folder {run_dir}")
    state.first_val = run.validation() if checkpoint is None else checkpoint.get("first_val_mpjpe_mm")
    checkpoint_fields["first_val_mpjpe_mm"] = state.first_val
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
        raise BadValueError(f"model.n_keypoints={model.config['n_keypoints']} but the dataset has {kp.NUM_KEYPOINTS} "
                         "keypoints")
    if checkpoint is not None:
        from models.build import load_checkpoint_state

        if checkpoint["model_config"].get("name") != model.config["name"]:
            raise BadValueError(f"checkpoint {resume_path} holds a {checkpoint['model_config'].get('name')!r} model, "
                             f"this run builds {model.config['name']!r}")
        try:
            load_checkpoint_state(model, checkpoint["model"])
        except (ValueError, TypeError) as exc:
            raise BadValueError(f"checkpoint {resume_path}: {exc}") from exc
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
                 checkpoint_fields: dict, device, autocast, world: int, is_main: bool, steps_per_epoch: int) -> None:
        self.cfg, self.model, self.optimizer, self.scheduler, self.data = cfg, model, optimizer, scheduler, data
        self.state, self.logger, self.run_dir, self.checkpoint_fields = state, logger, run_dir, checkpoint_fields
        self.device, self.autocast, self.world, self.is_main = device, autocast, world, is_main
        self.steps_per_epoch = steps_per_epoch
        self.start = time.perf_counter()

    def wall(self) -> float:
        return self.state.wall_offset + time.perf_counter() - self.start

    def save(self, name: str) -> None:
        s = self.state
        save_checkpoint(self.run_dir / "checkpoints" / name, {
            **self.checkpoint_fields, "model_config": self.model.config, "model": self.model.state_dict(),
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
