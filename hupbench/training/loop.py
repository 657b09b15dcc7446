"""Training: :func:`train` runs one typed run (:class:`hupbench.training.run_config.TrainRun`) in its run folder,
one loop for every model (bf16 autocast, channels_last and DDP under ``torchrun`` optional); ``python train.py``
calls :func:`main`.

Run folder:
    run.json             resolved config, git commit, package versions, hardware
    metrics.jsonl        one JSON object per line: "train" and "val" events (the leaderboard reads it)
    train.log            what the run printed, time-stamped, with a line per log step and validation
    checkpoints/last.pt  the latest state (:class:`hupbench.checkpoint.Checkpoint`); best.pt: lowest val MPJPE
    tb/                  TensorBoard scalars
    summary.json         written last, only when the run finished with finite weights: final metrics, timings
"""

from __future__ import annotations

import json
import math
import os
import shlex
import sys
import time
from contextlib import contextmanager
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch
from omegaconf import DictConfig, OmegaConf

from hupbench.core import keypoints as kp
from hupbench.core.camera import resize_intrinsics
from hupbench.core.errors import BadValueError, MissingFileError, RunFailedError
from hupbench.core.io import OutputLock, clean_stale_tmp, file_sha256, write_json
from hupbench.checkpoint import Checkpoint
from hupbench.data import TrainData, model_images, setup_data
from hupbench.error_lines import USER_ERRORS, error_line
from hupbench.input_geometry import INPUT_MODALITIES
from hupbench.provenance import hardware_description, run_info
from hupbench.training.losses import loss_terms
from hupbench.training.run_config import TrainRun, train_config
from hupbench.training.run_log import MetricsLog, RunConsole, bar_postfix, loss_window
from hupbench.training.schedule import learning_rate
from hupbench.training.validation import recompute_bn_statistics, validate
from hupbench.models.build import build_model, load_checkpoint_state

#: config differences a refused resume lists (a checkpoint of another project differs everywhere)
MAX_DIFFS_SHOWN = 8
#: config keys that may differ between a run and the run it resumes
RESUME_FREE_KEYS = ("train.resume", "train.progress", "train.stop_after", "run_dir", "threads", "data.num_workers",
                    "data.cache_dir", "label")


def main(cfg: DictConfig, log=print, debug: bool = False) -> float:
    """The body of ``python train.py``: :func:`run_train`, a deliberate refusal answered as one line on stderr,
    ``train.py: error: ...``, and exit code 1 (``debug``, HYDRA_FULL_ERROR=1: its traceback). Returns the last
    validation MPJPE (all keypoints, mm): what a Hydra sweeper minimises."""
    from hydra.errors import HydraException
    from omegaconf.errors import OmegaConfBaseException

    try:
        result = run_train(cfg, log)
    except (*USER_ERRORS, HydraException, OmegaConfBaseException) as exc:
        if debug:
            raise
        print(f"train.py: error: {error_line(exc)}", file=sys.stderr)
        raise SystemExit(1) from None
    if result["complete"] and int(os.environ.get("RANK", "0")) == 0:
        for line in next_commands(result["checkpoint"], cfg.data.root):
            log(line)
    return result["val_mpjpe_mm"]["all"]


def next_commands(checkpoint: str, dataset: str) -> list[str]:
    """The lines that end a finished run: what to run on its checkpoint next."""
    ckpt, data = shlex.quote(str(checkpoint)), shlex.quote(str(dataset))
    return [f"next: hupbench eval {ckpt} {data}    # MPJPE and the other metrics on the test split",
            f"      hupbench export {ckpt}    # ONNX model, checked against PyTorch"]


def run_train(cfg: DictConfig, log=print) -> dict:
    """:func:`train` on the typed run of a composed conf/train.yaml, in its run folder."""
    run = train_config(cfg)
    return train(run, run.folder, log)


def train(run: TrainRun, folder: Path, log=print) -> dict:  # layout: long because the run reads in one sitting
    """Train ``run`` in ``folder`` (held by this run alone, :func:`_run_folder`): set up, loop (log, validate,
    save), summarise. Weights or metrics that are not finite fail the run before a checkpoint or summary.json
    is written: a run is complete only when what it wrote is whole.

    Returns:
        summary.json's dict: the checkpoints, counters, timings and validations (mm), and "complete" (False
        when train.stop_after stopped the run early).
    """
    from hupbench.data import read_manifest

    folder = Path(folder)
    world, rank, local_rank = (int(os.environ.get(k, d)) for k, d in
                               (("WORLD_SIZE", "1"), ("RANK", "0"), ("LOCAL_RANK", "0")))  # set by torchrun
    is_main = rank == 0
    device = torch.device("cuda", local_rank) if run.device == "cuda" else torch.device("cpu")
    if device.type == "cuda" and not torch.cuda.is_available():
        raise RunFailedError(f"device=cuda was asked for but CUDA is not available here (torch {torch.__version__}); "
                             "use device=cpu")
    if run.threads is not None:
        torch.set_num_threads(run.threads)
    root = Path(run.data.root)
    manifest = read_manifest(root, needs="the models are built for")
    if folder.exists() and not folder.is_dir():
        raise BadValueError(f"run_dir {folder} is a file; expected a folder for the run (or a path to make one)")

    console = RunConsole(log, is_main)
    with _run_folder(folder, is_main, console.line):
        # -- setup: everything that can be wrong is checked before the first step
        resumed = _resume_checkpoint(run, folder, root)
        finished = _finished_run(folder, resumed)
        if finished is not None:
            console.open_file(folder)
            console.line(f"already complete: nothing to do (checkpoint {finished['checkpoint']}: step "
                         f"{finished['steps']}, val MPJPE {finished['val_mpjpe_mm']['all']:.1f} mm; use "
                         f"{new_run_override(run)} for a new run)")
            return finished
        data = setup_data(OmegaConf.create(run.config), world, rank, device, log)
        input_size = run.data.reader.input_size
        K_input = resize_intrinsics(data.train_set.ann["K"][0], input_size / int(manifest["image_size"][0]))
        model = build_run_model(run, data, K_input, resumed)
        steps_per_epoch = data.sampler.batches_per_epoch
        total_steps = run.train.max_steps or run.train.epochs * steps_per_epoch
        batch_size = run.data.batch_size * world
        optimizer = run.optim.optimizer(model.parameters(), lr=learning_rate(run.optim, batch_size))
        scheduler = run.optim.scheduler(optimizer, total_steps=total_steps)
        model.to(device)
        if run.channels_last:
            model.to(memory_format=torch.channels_last)
        precision = resolve_precision(run.precision, device)
        autocast = autocast_args(precision, device)
        train_model = model
        if world > 1:
            if not torch.distributed.is_initialized():
                torch.distributed.init_process_group(backend="nccl" if device.type == "cuda" else "gloo")
            train_model = torch.nn.parallel.DistributedDataParallel(
                model, device_ids=[device.index] if device.type == "cuda" else None)
        if run.compile:
            train_model = torch.compile(train_model)
        state = RunState()
        if resumed is not None:
            optimizer.load_state_dict(resumed.optimizer)
            scheduler.load_state_dict(resumed.scheduler)
            state = RunState(resumed.step, resumed.samples_seen, resumed.train_seconds, resumed.wall_seconds,
                             resumed.best_val_mpjpe_mm, resumed.first_val_mpjpe_mm, resumed.val_mpjpe_mm)
            torch.set_rng_state(resumed.rng["torch"])
        if is_main:
            folder.mkdir(parents=True, exist_ok=True)
            write_json(folder / "run.json", run_info(run.config, verb="train", world_size=world,
                                                     hardware=hardware_description(device), precision=precision,
                                                     resumed_from=str(resumed.path) if resumed else None))
            console.open_file(folder)
        logger = MetricsLog(folder, is_main, run.train.tensorboard, state.step if resumed else None)
        dataset = {"path": str(root.resolve()), "manifest_sha256": file_sha256(root / "manifest.json")}
        start = time.perf_counter()

        def wall() -> float:
            return state.wall_offset + time.perf_counter() - start

        def save(name: str) -> None:
            _check_finite(state.step, "weights", model.state_dict())
            Checkpoint(model_config=model.config.saved(), model=model.state_dict(), step=state.step,
                       input_size=input_size, K_input=K_input.tolist(), config=run.config,
                       optimizer=optimizer.state_dict(), scheduler=scheduler.state_dict(),
                       epoch=state.step / steps_per_epoch, samples_seen=state.samples_seen,
                       train_seconds=state.train_seconds, wall_seconds=wall(), best_val_mpjpe_mm=state.best,
                       val_mpjpe_mm=state.last_val, first_val_mpjpe_mm=state.first_val, dataset=dataset,
                       rng={"torch": torch.get_rng_state()}, world_size=world).save(folder / "checkpoints" / name)

        def validation() -> dict:
            if data.bn_loader is not None and state.step > 0:
                console.phase("recomputing batch-norm statistics")
                recompute_bn_statistics(model, data.bn_loader, device, autocast)
            console.phase("validating")
            val = validate(model, data.val_loader, device, autocast, world)
            _check_finite(state.step, "weights", model.state_dict())
            _check_finite(state.step, "validation MPJPE", val)
            logger({"event": "val", "step": state.step, "epoch": state.step / steps_per_epoch,
                    "samples_seen": state.samples_seen, "wall_s": wall(), "train_wall_s": state.train_seconds,
                    "val_mpjpe_mm": {k: val[k] for k in ("all", "hand", "probe")}, "val_frames": val["frames"]})
            state.last_val = val
            best = val["all"] < state.best
            console.progress_line(f"step {state.step}: val MPJPE {val['all']:.1f} mm (hand {val['hand']:.1f}, probe "
                                  f"{val['probe']:.1f}) on {val['frames']} frames"
                                  f"{', the best so far' if best and state.step > 0 else ''}")
            if is_main and best:
                state.best = val["all"]
                console.phase("saving checkpoint best.pt")
                save("best.pt")
            return val

        console.line(f"training {model.config.name} ({model.config.backbone}, {input_size} px "
                     f"{run.data.reader.input_modalities}) on {root}: "
                     f"{len(data.train_set)} train frames, {len(data.val_loader.dataset)} val frames, {total_steps} "
                     f"steps of {batch_size} on {device}{f' x {world} processes' if world > 1 else ''} in {precision}"
                     f"{' (precision=auto)' if run.precision == 'auto' else ''}; run folder {folder}")
        console.line(config_summary(run, type(optimizer).__name__, learning_rate(run.optim, batch_size),
                                    steps_per_epoch, total_steps), console=False)
        if resumed is not None:
            console.line(f"resuming from {resumed.path} at step {resumed.step} of {total_steps}")
        state.first_val = validation() if resumed is None else resumed.first_val_mpjpe_mm

        # -- the loop: the device is waited for only when a number is read (log, validation and checkpoint
        # steps); train_seconds counts the time between them, data loading included, validation excluded
        schedule = run.train
        stop = min(total_steps, schedule.stop_after or total_steps)
        epochs = -(-total_steps // steps_per_epoch)
        if schedule.progress:
            console.start_bar(run.run_name, total_steps, state.step)
        # the loss summed on the device over the steps since the last log step: its mean is read where the
        # loop reads numbers anyway, and on a CPU every step (no queue to wait for: float() costs 0.15 us)
        window, window_first, shown = torch.zeros((), device=device), state.step + 1, None
        model.train()
        segment = time.perf_counter()
        while state.step < stop:
            epoch, start_batch = divmod(state.step, steps_per_epoch)
            data.sampler.set_position(epoch, start_batch)
            for batch in data.train_loader:
                loss, terms = train_step(train_model, optimizer, batch, epoch, data, run, device, autocast)
                scheduler.step()
                state.step += 1
                state.samples_seen += batch_size
                window += loss
                validating = state.step % schedule.val_every == 0 or state.step == total_steps
                saving = state.step % schedule.ckpt_every == 0 or state.step == stop
                logging = state.step % schedule.log_every == 0 or state.step in (1, stop)
                if logging or validating or saving:
                    _check_finite(state.step, "loss", {"loss": loss, **terms})
                    state.train_seconds += time.perf_counter() - segment  # float(loss) waited for the device
                if logging or validating or saving or device.type == "cpu":
                    shown = loss_window(float(window) / (state.step + 1 - window_first), window_first, state.step)
                lr = scheduler.get_last_lr()[0]
                console.step(bar_postfix(epoch + 1, epochs, lr, shown,
                                         state.last_val["all"] if state.last_val else None))
                if logging:
                    logger({"event": "train", "step": state.step, "samples_seen": state.samples_seen, "wall_s": wall(),
                            "train_wall_s": state.train_seconds, "loss": float(loss),
                            **{k: float(v) for k, v in terms.items()}, "lr": lr})
                    console.progress_line(f"step {state.step}/{total_steps} (epoch {epoch + 1}/{epochs}): {shown}, "
                                          f"lr {lr:.2e}")
                    window.zero_()
                    window_first = state.step + 1
                if validating:
                    validation()
                if saving:
                    if data.bn_loader is not None and not validating:
                        console.phase("recomputing batch-norm statistics")
                        recompute_bn_statistics(model, data.bn_loader, device, autocast)
                    if is_main:
                        console.phase("saving checkpoint last.pt")
                        save("last.pt")
                if validating or saving:
                    console.phase(None)
                if validating:  # the bar ends on the figure the summary reports
                    console.show(bar_postfix(epoch + 1, epochs, lr, shown, state.last_val["all"]))
                if logging or validating or saving:
                    segment = time.perf_counter()
                if state.step >= stop:
                    break
        console.close_bar()
        logger.close()

        # -- summary
        first, last = state.first_val, state.last_val
        result = {"run_dir": str(folder), "checkpoint": str(folder / "checkpoints" / "last.pt"),
                  "best_checkpoint": str(folder / "checkpoints" / "best.pt"), "steps": state.step,
                  "samples_seen": state.samples_seen, "epochs": state.step / steps_per_epoch,
                  "train_seconds": state.train_seconds, "wall_seconds": wall(), "val_mpjpe_mm": last,
                  "first_val_mpjpe_mm": first, "best_val_mpjpe_mm": state.best, "world_size": world,
                  "complete": state.step >= total_steps}
        if not result["complete"]:
            console.line(f"stopped at step {state.step} of {total_steps} (train.stop_after), checkpoint "
                         f"{result['checkpoint']}; the same command with train.stop_after=null"
                         f"{'' if schedule.resume == 'auto' else ' train.resume=auto'} continues it")
        else:
            if is_main:
                write_json(folder / "summary.json", result)
            speed = state.samples_seen / max(state.train_seconds, 1e-9)
            console.line(f"finished {state.step} steps in {wall() / 60:.1f} min ({speed:.1f} img/s training); val "
                         f"MPJPE {first['all']:.1f} -> {last['all']:.1f} mm (hand {last['hand']:.1f}, probe "
                         f"{last['probe']:.1f})")
            console.line(f"checkpoint {result['checkpoint']} (lowest validation MPJPE, {state.best:.1f} mm: "
                         f"{result['best_checkpoint']})")
        return result


def train_step(model, optimizer, batch: dict, epoch: int, data: TrainData, run: TrainRun,
               device: torch.device, autocast: dict) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """One optimiser step on one batch (the scheduler steps after it); returns the detached loss and its
    terms (no device sync)."""
    batch = data.augment({name: value.to(device, non_blocking=True) for name, value in batch.items()}, epoch)
    images = model_images(batch["image"], device, run.channels_last)
    targets = {k: batch[k].to(device, non_blocking=True) for k in ("keypoints_2d", "keypoints_3d")}
    with torch.autocast(**autocast):
        output = model(images)
    loss, terms = loss_terms(output, targets, run.loss)
    optimizer.zero_grad(set_to_none=True)
    loss.backward()
    optimizer.step()
    return loss.detach(), terms


def native_bf16(device: torch.device) -> bool:
    """Whether ``device`` computes in bf16 natively: a GPU that supports it, a CPU with AVX512-BF16 or AMX.
    Elsewhere bf16 autocast is emulated (12x slower than fp32 on an AVX2-only CPU)."""
    if device.type == "cuda":
        return torch.cuda.is_bf16_supported()
    return bool(torch.cpu._is_avx512_bf16_supported() or torch.cpu._is_amx_tile_supported())


def resolve_precision(precision: str, device: torch.device) -> str:
    """The precision a run computes in: ``auto`` is bf16 where ``device`` runs it natively, else fp32."""
    if precision != "auto":
        return precision
    return "bf16" if native_bf16(device) else "fp32"


def autocast_args(precision: str, device: torch.device) -> dict:
    """torch.autocast's arguments for a resolved precision."""
    return {"device_type": device.type, "dtype": torch.bfloat16, "enabled": precision == "bf16"}


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


@contextmanager
def _run_folder(folder: Path, is_main: bool, log):
    """Hold the run folder while the run writes it: one run per folder (a second would append every step to
    metrics.jsonl a second time and overwrite the first's checkpoints); rank 0 writes every file, so it
    alone holds the lock. A run refused before it wrote anything leaves no folder."""
    made = not folder.exists()
    lock = OutputLock(folder, "training").acquire() if is_main else None
    try:
        if lock is not None:
            for stale in clean_stale_tmp(folder):
                log(f"removed {stale}, a temporary file of a run that was killed")
            if lock.taken_over:
                log(f"took over {folder} from a run that is gone (pid {lock.taken_over.get('pid')} on "
                    f"{lock.taken_over.get('host')})")
        yield
    finally:
        if lock is not None:
            lock.release()
            if made and folder.is_dir() and not any(folder.iterdir()):
                folder.rmdir()


def _resume_checkpoint(run: TrainRun, folder: Path, root: Path) -> Checkpoint | None:
    """The checkpoint this run continues (``train.resume``), checked to be of this run's config and dataset."""
    mode, last = run.train.resume, folder / "checkpoints" / "last.pt"
    if mode in (None, "never") and last.exists():
        raise BadValueError(f"{folder} already holds a checkpoint ({last}); use train.resume=auto to continue it, "
                            f"or {new_run_override(run)} for a new run")
    if mode in (None, "never") or (mode == "auto" and not last.exists()):
        return None
    path = last if mode == "auto" else Path(mode)
    if not path.is_file():
        raise MissingFileError(f"train.resume={mode}: checkpoint {path} does not exist")
    checkpoint = Checkpoint.read(path)
    diff = _config_diff(checkpoint.config, run.config)
    if diff:
        shown = "; ".join(diff[:MAX_DIFFS_SHOWN]) + (f"; and {len(diff) - MAX_DIFFS_SHOWN} more"
                                                     if len(diff) > MAX_DIFFS_SHOWN else "")
        fix = (f"to train with the new values start a new run, {new_run_override(run)}; to continue this run, "
               "give it the values it was trained with" if mode == "auto" else
               "resume it with the values it was trained with, or leave train.resume out to start afresh")
        raise BadValueError(f"checkpoint {path} was trained with another config; differences: {shown}; {fix}")
    trained_on = (checkpoint.dataset or {}).get("manifest_sha256")
    now = file_sha256(root / "manifest.json")
    if trained_on != now:
        raise BadValueError(f"checkpoint {path} was trained on another dataset: manifest sha256 {trained_on} "
                            f"({(checkpoint.dataset or {}).get('path')}), but {root / 'manifest.json'} has {now}; "
                            f"resume on the dataset it was trained on, or start a new run: {new_run_override(run)}")
    return checkpoint


def _finished_run(folder: Path, resumed: Checkpoint | None) -> dict | None:
    """The summary of the run in ``folder`` when it already finished at ``resumed``, its last checkpoint (whose
    config and dataset are this run's), with the paths of where it is now and "already_complete"; else None."""
    path = folder / "summary.json"
    if resumed is None or resumed.path != folder / "checkpoints" / "last.pt" or not path.is_file():
        return None
    try:
        summary = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise BadValueError(f"{path} is not JSON ({exc.msg}, line {exc.lineno}): the run's summary was damaged; "
                            "move it away and the same command writes it again") from exc
    if not summary.get("complete") or summary.get("steps") != resumed.step:
        return None
    return {**summary, "run_dir": str(folder), "checkpoint": str(folder / "checkpoints" / "last.pt"),
            "best_checkpoint": str(folder / "checkpoints" / "best.pt"), "already_complete": True}


def new_run_override(run: TrainRun) -> str:
    """The override that starts a new run beside this one: ``run_name=NAME_K`` with the first K >= 2 whose folder
    does not exist, or ``run_dir=FOLDER_K`` when run_dir names a folder outside the run name's."""
    if run.run_dir is None or run.run_name in Path(run.run_dir).parts:
        key, base = "run_name", Path(run.out_root) / run.run_name
    else:
        key, base = "run_dir", Path(run.run_dir)
    k = 2
    while Path(f"{base}_{k}").exists():
        k += 1
    return f"{key}={shlex.quote((run.run_name if key == 'run_name' else str(base)) + f'_{k}')}"


def config_summary(run: TrainRun, optimizer: str, lr: float, steps_per_epoch: int, total_steps: int) -> str:
    """train.log's line of the run's main settings (run.json holds the whole resolved config); ``lr``: the
    optimiser's base learning rate (:func:`learning_rate`)."""
    schedule = run.train
    return (f"config: model={run.model_id} seed={run.seed} data.root={run.data.root} "
            f"data.batch_size={run.data.batch_size} data.reader.input_size={run.data.reader.input_size} "
            f"{total_steps} steps ({steps_per_epoch} per epoch) {optimizer} lr {lr:.2e} "
            f"weight_decay {run.optim.optimizer.keywords.get('weight_decay', 0.0):g} "
            f"scheduler {run.optim.scheduler.func.__name__} "
            f"train.log_every={schedule.log_every} train.val_every={schedule.val_every} "
            f"train.ckpt_every={schedule.ckpt_every} precision={run.precision} device={run.device}; "
            "the whole config: run.json")


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


def build_run_model(run: TrainRun, data: TrainData, K_input: np.ndarray,
                    resumed: Checkpoint | None = None) -> torch.nn.Module:
    """The run's model: its config with the training split's mean layout as its 3D prior, the input channels of
    ``data.reader.input_modalities`` (and the input camera for models that unproject through it, where the
    config leaves them null), or the checkpoint's model when resuming."""
    config = run.model
    if resumed is not None:
        name = resumed.model_config.get("name")
        if name != config.name:
            raise BadValueError(f"checkpoint {resumed.path} holds a {name!r} model, this run builds {config.name!r}")
        mean = resumed.model_config.get("points3d_mean")
        extents = resumed.model_config.get("probe_half_extents")
    else:
        # the prior: the training split's mean camera-frame layout, (29, 3) metres
        mean = data.train_set.ann["keypoints_3d_cam"].astype(np.float64).mean(axis=0).tolist()
        extents = None  # the box of a model that poses the probe rigidly (hupbench.models.heatmap, probe_head)
        if getattr(config, "probe_head", None) == "rigid":
            extents = probe_half_extents(data.train_set.ann["keypoints_3d_cam"][:, kp.CORNER_SLICE]).tolist()
    camera = {"K_input": K_input.tolist(), "input_size": run.data.reader.input_size, "probe_half_extents": extents}
    channels = INPUT_MODALITIES[run.data.reader.input_modalities]
    config = replace(config, points3d_mean=mean, input_channels=channels,
                     **{k: v for k, v in camera.items() if hasattr(config, k) and getattr(config, k) is None})
    torch.manual_seed(run.seed)  # the initial weights are a function of the seed
    try:
        model = build_model(config.saved())
    except ValueError as exc:  # the model's layers refusing a combination of the config's values
        raise BadValueError(f"model: {exc}") from exc
    if resumed is not None:
        try:
            load_checkpoint_state(model, resumed.model)
        except (ValueError, TypeError) as exc:
            raise BadValueError(f"checkpoint {resumed.path}: {exc}") from exc
    return model


def probe_half_extents(corners: np.ndarray) -> np.ndarray:
    """(3,) float64 half the probe box's sides along its own x, y, z (metres): the mean over frames of its 4
    edges along each axis, from (N, 8, 3) corners in the order of ``hupbench.core.keypoints.CORNER_BITS``."""
    corners = np.asarray(corners, dtype=np.float64)
    halves = []
    for axis in range(3):
        low = [k for k, bits in enumerate(kp.CORNER_BITS) if bits[axis] == 0]
        high = [next(j for j, other in enumerate(kp.CORNER_BITS) if other[axis] == 1
                     and all(other[a] == kp.CORNER_BITS[k][a] for a in range(3) if a != axis)) for k in low]
        halves.append(np.linalg.norm(corners[:, high] - corners[:, low], axis=-1).mean() / 2.0)
    return np.array(halves)


def _check_finite(step: int, what: str, values: dict) -> None:
    """Refuse ``what`` (the weights, the loss and its terms, a validation) when a value is NaN or inf: a
    checkpoint or summary of it would call a diverged run usable."""
    bad = [name for name, value in values.items() if not torch.isfinite(torch.as_tensor(value)).all()]
    if bad:
        raise RunFailedError(f"the {what} became NaN or inf at step {step} ({', '.join(bad[:3])}"
                             f"{f' and {len(bad) - 3} more' if len(bad) > 3 else ''}): the run diverged, and nothing "
                             "after its last checkpoint was saved; lower optim.optimizer.lr or raise optim.optimizer.eps")
