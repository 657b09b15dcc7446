"""Training: :func:`train` runs one typed run (:class:`hupbench.training.run_config.TrainRun`) in its run folder,
one loop for every model (bf16 autocast, channels_last and DDP under ``torchrun`` optional); ``python train.py``
and ``hupbench train`` run it through :func:`run_train`.

Run folder:
    run.json             resolved config, git commit, package versions, hardware
    metrics.jsonl        one JSON object per line: "train" and "val" events (the leaderboard reads it)
    train.log            what the run printed, time-stamped, with a line per log step and validation
    checkpoints/last.pt  the latest state (:class:`hupbench.checkpoint.Checkpoint`); best.pt: lowest val MPJPE
    tb/                  TensorBoard scalars
    summary.json         written last, only when the run finished with finite weights: final metrics, timings
"""

from __future__ import annotations

import math
import os
import time
from contextlib import contextmanager
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch
from omegaconf import DictConfig

from hupbench.checkpoint import Checkpoint
from hupbench.core import keypoints as kp
from hupbench.core.camera import resize_intrinsics
from hupbench.core.contract import MANIFEST, read_annotations
from hupbench.core.errors import BadValueError, RunFailedError
from hupbench.core.io import OutputLock, clean_stale_tmp, file_sha256, write_json, writing
from hupbench.data import Placement, TrainData, model_images, read_manifest, setup_data
from hupbench.fits.hand_fit import training_hands
from hupbench.input_geometry import INPUT_MODALITIES
from hupbench.models.build import build_model, load_checkpoint_state
from hupbench.provenance import hardware_description, run_info
from hupbench.training.losses import loss_terms
from hupbench.training.resume import finished_run, new_run_override, resume_checkpoint
from hupbench.training.run_config import TrainRun, train_config
from hupbench.training.run_log import LossWindow, MetricsLog, RunConsole, bar_postfix
from hupbench.training.schedule import learning_rate
from hupbench.training.validation import recompute_bn_statistics, validate


def run_train(cfg: DictConfig, log=print) -> dict:
    """:func:`train` on the typed run of a composed conf/train.yaml, in its run folder."""
    return train(train_config(cfg), log)


def train(run: TrainRun, log=print) -> dict:
    """Train ``run`` in its run folder (``run.folder``, held by this run alone): set up, loop (log, validate,
    save), summarise. Weights or metrics that are not finite fail the run before a checkpoint or summary.json
    is written: a run is complete only when what it wrote is whole.

    Returns:
        summary.json's dict: the checkpoints, counters, timings and validations (mm), and "complete" (False
        when train.stop_after stopped the run early).
    """
    place = placement(run.device)
    if run.threads is not None:
        torch.set_num_threads(run.threads)
    folder, console = run.folder, RunConsole(log, place.is_main)
    manifest = read_manifest(Path(run.data.root), needs="the models are built for")
    with _run_folder(folder, place.is_main, console.line):
        resumed = resume_checkpoint(run)
        finished = finished_run(folder, resumed)
        if finished is not None:
            console.open_file(folder)
            console.line(f"already complete: nothing to do (checkpoint {finished['checkpoint']}: step "
                         f"{finished['steps']}, val MPJPE {finished['val_mpjpe_mm']['all']:.1f} mm; use "
                         f"{new_run_override(run)} for a new run)")
            return finished
        s = Session.start(run, manifest, resumed, place, console)  # everything that can be wrong is checked here
        state, schedule, steps_per_epoch, total = s.state, run.train, s.data.sampler.batches_per_epoch, s.total_steps
        stop = min(total, schedule.stop_after or total)
        epochs = -(-total // steps_per_epoch)
        if schedule.progress:
            console.start_bar(run.run_name, total, state.step)
        # the device is waited for only when a number is read (log, validation and checkpoint steps; on a CPU
        # every step: no queue to wait for); train_seconds counts the time between them, validation excluded
        window = LossWindow(state.step, place.device)
        s.model.train()
        segment = time.perf_counter()
        while state.step < stop:
            epoch, start_batch = divmod(state.step, steps_per_epoch)
            s.data.sampler.set_position(epoch, start_batch)
            for batch in s.data.train_loader:
                loss, terms = train_step(s.train_model, s.optimizer, batch, epoch, s.data, run, place.device,
                                         s.autocast)
                s.scheduler.step()
                state.step += 1
                state.samples_seen += s.batch_size
                window.add(loss)
                validating = state.step % schedule.val_every == 0 or state.step == total
                saving = state.step % schedule.ckpt_every == 0 or state.step == stop
                logging = state.step % schedule.log_every == 0 or state.step in (1, stop)
                reading = logging or validating or saving
                if reading:
                    _check_finite(state.step, "loss", {"loss": loss, **terms})
                    state.train_seconds += time.perf_counter() - segment  # float(loss) waited for the device
                if reading or place.device.type == "cpu":
                    window.read(state.step)
                lr = s.scheduler.get_last_lr()[0]
                console.step(bar_postfix(epoch + 1, epochs, lr, window.shown, s.last_val_mm))
                if logging:
                    s.log_train(loss, terms, lr, f"step {state.step}/{total} (epoch {epoch + 1}/{epochs}): "
                                                 f"{window.shown}")
                    window.restart(state.step)
                if validating:
                    s.validation()
                if saving:
                    s.save_last(validated=validating)
                if validating or saving:
                    console.phase(None)
                if validating:  # the bar ends on the figure the summary reports
                    console.show(bar_postfix(epoch + 1, epochs, lr, window.shown, s.last_val_mm))
                if reading:
                    segment = time.perf_counter()
                if state.step >= stop:
                    break
        return s.finish()


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


@dataclass
class Session:
    """What a run trains with, built by :meth:`start`: its data, model (and the module the steps run, DDP or
    compiled), optimiser and scheduler, counters, logs; the validation, checkpoints and summary of the loop."""

    run: TrainRun
    place: Placement
    console: RunConsole
    logger: MetricsLog
    data: TrainData
    model: torch.nn.Module
    train_model: torch.nn.Module
    optimizer: torch.optim.Optimizer
    scheduler: object
    state: RunState
    autocast: dict
    K_input: np.ndarray
    dataset: dict
    total_steps: int
    batch_size: int
    started: float

    @classmethod
    def start(cls, run: TrainRun, manifest: dict, resumed: Checkpoint | None, place: Placement,
              console: RunConsole) -> Session:
        """Build the run's pieces (or restore them from ``resumed``), write run.json, open the logs, say what
        is trained, and validate the model as it starts (a resumed run keeps its first validation)."""
        folder, device, root = run.folder, place.device, Path(run.data.root)
        data = setup_data(run.data, run.seed, run.train.bn_recompute_frames, place, run.train.progress, console.line,
                          with_seg=getattr(run.model, "segmentation", False))
        # the stored images' K at the model's input size: the camera the 3D output is trained for
        K_input = resize_intrinsics(data.train_set.ann["K"][0], run.data.reader.input_size / manifest["image_size"][0])
        model = build_run_model(run, data, K_input, resumed)
        total_steps = run.train.max_steps or run.train.epochs * data.sampler.batches_per_epoch
        batch_size = run.data.batch_size * place.world
        optimizer = run.optim.optimizer(model.parameters(), lr=learning_rate(run.optim, batch_size))
        scheduler = run.optim.scheduler(optimizer, total_steps=total_steps)
        model.to(device, memory_format=torch.channels_last if run.channels_last else torch.preserve_format)
        precision = resolve_precision(run.precision, device)
        train_model = model
        if place.world > 1:
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
        if place.is_main:
            with writing(folder / "checkpoints") as checkpoints:  # a file of that name fails here, not after a step
                checkpoints.mkdir(parents=True, exist_ok=True)
            write_json(folder / "run.json", run_info(run.config, verb="train", world_size=place.world,
                                                     hardware=hardware_description(device), precision=precision,
                                                     resumed_from=str(resumed.path) if resumed else None))
            console.open_file(folder)
        logger = MetricsLog(folder, place.is_main, run.train.tensorboard, state.step if resumed else None)
        session = cls(run, place, console, logger, data, model, train_model, optimizer, scheduler, state,
                      autocast_args(precision, device), K_input,
                      {"path": str(root.resolve()), "manifest_sha256": file_sha256(root / MANIFEST)}, total_steps,
                      batch_size, time.perf_counter())
        console.line(f"training {model.config.name} ({model.config.backbone}, {run.data.reader.input_size} px "
                     f"{run.data.reader.input_modalities}) on {root}: {len(data.train_set)} train frames, "
                     f"{len(data.val_loader.dataset)} val frames, {total_steps} steps of {batch_size} on {device}"
                     f"{f' x {place.world} processes' if place.world > 1 else ''} in {precision}"
                     f"{' (precision=auto)' if run.precision == 'auto' else ''}; run folder {folder}")
        console.line(config_summary(run, type(optimizer).__name__, learning_rate(run.optim, batch_size),
                                    data.sampler.batches_per_epoch, total_steps), console=False)
        if resumed is not None:
            console.line(f"resuming from {resumed.path} at step {resumed.step} of {total_steps}")
        state.first_val = session.validation() if resumed is None else resumed.first_val_mpjpe_mm
        return session

    @property
    def last_val_mm(self) -> float | None:
        """The last validation's MPJPE over all keypoints (mm), None before the first."""
        return self.state.last_val["all"] if self.state.last_val else None

    def wall(self) -> float:
        """Seconds of the run so far, its runs before a resume included."""
        return self.state.wall_offset + time.perf_counter() - self.started

    def save(self, name: str) -> None:
        """checkpoints/``name``: the model, optimiser, scheduler, counters and RNG of this step."""
        state, run = self.state, self.run
        _check_finite(state.step, "weights", self.model.state_dict())
        Checkpoint(model_config=self.model.config.saved(), model=self.model.state_dict(), step=state.step,
                   input_size=run.data.reader.input_size, K_input=self.K_input.tolist(), config=run.config,
                   optimizer=self.optimizer.state_dict(), scheduler=self.scheduler.state_dict(),
                   epoch=state.step / self.data.sampler.batches_per_epoch, samples_seen=state.samples_seen,
                   train_seconds=state.train_seconds, wall_seconds=self.wall(), best_val_mpjpe_mm=state.best,
                   val_mpjpe_mm=state.last_val, first_val_mpjpe_mm=state.first_val, dataset=self.dataset,
                   rng={"torch": torch.get_rng_state()}, world_size=self.place.world,
                   ).save(run.folder / "checkpoints" / name)

    def validation(self) -> dict:
        """Validate (batch-norm statistics re-estimated first, after step 0), log it, and save best.pt when it
        is the lowest MPJPE so far. Returns the validation's MPJPE (mm: "all", "hand", "probe") and "frames"."""
        state, console, device = self.state, self.console, self.place.device
        if self.data.bn_loader is not None and state.step > 0:
            console.phase("recomputing batch-norm statistics")
            recompute_bn_statistics(self.model, self.data.bn_loader, device, self.autocast)
        console.phase("validating")
        val = validate(self.model, self.data.val_loader, device, self.autocast, self.place.world)
        _check_finite(state.step, "weights", self.model.state_dict())
        _check_finite(state.step, "validation MPJPE", val)
        self.logger({"event": "val", "step": state.step, "epoch": state.step / self.data.sampler.batches_per_epoch,
                     "samples_seen": state.samples_seen, "wall_s": self.wall(), "train_wall_s": state.train_seconds,
                     "val_mpjpe_mm": {k: val[k] for k in ("all", "hand", "probe")}, "val_frames": val["frames"]})
        state.last_val = val
        best = val["all"] < state.best
        console.progress_line(f"step {state.step}: val MPJPE {val['all']:.1f} mm (hand {val['hand']:.1f}, probe "
                              f"{val['probe']:.1f}) on {val['frames']} frames"
                              f"{', the best so far' if best and state.step > 0 else ''}")
        if self.place.is_main and best:
            state.best = val["all"]
            console.phase("saving checkpoint best.pt")
            self.save("best.pt")
        return val

    def save_last(self, validated: bool) -> None:
        """checkpoints/last.pt, with batch-norm statistics re-estimated unless a validation just did."""
        if self.data.bn_loader is not None and not validated:
            self.console.phase("recomputing batch-norm statistics")
            recompute_bn_statistics(self.model, self.data.bn_loader, self.place.device, self.autocast)
        if self.place.is_main:
            self.console.phase("saving checkpoint last.pt")
            self.save("last.pt")

    def log_train(self, loss: torch.Tensor, terms: dict[str, torch.Tensor], lr: float, line: str) -> None:
        """A log step: the loss and its terms in metrics.jsonl, ``line`` and the learning rate in train.log."""
        state = self.state
        self.logger({"event": "train", "step": state.step, "samples_seen": state.samples_seen, "wall_s": self.wall(),
                     "train_wall_s": state.train_seconds, "loss": float(loss),
                     **{k: float(v) for k, v in terms.items()}, "lr": lr})
        self.console.progress_line(f"{line}, lr {lr:.2e}")

    def finish(self) -> dict:
        """Close the bar and the logs; summary.json when the run reached its last step. Returns the summary."""
        self.console.close_bar()
        self.logger.close()
        state, folder, console = self.state, self.run.folder, self.console
        first, last = state.first_val, state.last_val
        result = {"run_dir": str(folder), "checkpoint": str(folder / "checkpoints" / "last.pt"),
                  "best_checkpoint": str(folder / "checkpoints" / "best.pt"), "steps": state.step,
                  "samples_seen": state.samples_seen, "epochs": state.step / self.data.sampler.batches_per_epoch,
                  "train_seconds": state.train_seconds, "wall_seconds": self.wall(), "val_mpjpe_mm": last,
                  "first_val_mpjpe_mm": first, "best_val_mpjpe_mm": state.best, "world_size": self.place.world,
                  "complete": state.step >= self.total_steps}
        if not result["complete"]:
            console.line(f"stopped at step {state.step} of {self.total_steps} (train.stop_after), checkpoint "
                         f"{result['checkpoint']}; the same command with train.stop_after=null"
                         f"{'' if self.run.train.resume == 'auto' else ' train.resume=auto'} continues it")
            return result
        if self.place.is_main:
            write_json(folder / "summary.json", result)
        speed = state.samples_seen / max(state.train_seconds, 1e-9)
        console.line(f"finished {state.step} steps in {self.wall() / 60:.1f} min ({speed:.1f} img/s training); val "
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
    targets = {k: batch[k].to(device, non_blocking=True) for k in ("keypoints_2d", "keypoints_3d", "seg") if k in batch}
    with torch.autocast(**autocast):
        output = model(images)
    loss, terms = loss_terms(output, targets, run.loss)
    optimizer.zero_grad(set_to_none=True)
    loss.backward()
    optimizer.step()
    return loss.detach(), terms


def placement(device: str) -> Placement:
    """This process among the run's: torchrun's WORLD_SIZE, RANK and LOCAL_RANK (one process without torchrun),
    on ``device`` ("cpu", or "cuda": the GPU of its local rank, refused where CUDA is not there)."""
    world, rank, local_rank = (int(os.environ.get(k, d)) for k, d in
                               (("WORLD_SIZE", "1"), ("RANK", "0"), ("LOCAL_RANK", "0")))
    if device == "cuda" and not torch.cuda.is_available():
        raise RunFailedError(f"device=cuda was asked for but CUDA is not available here (torch {torch.__version__}); "
                             "use device=cpu")
    return Placement(world, rank, torch.device("cuda", local_rank) if device == "cuda" else torch.device("cpu"))


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
        hands = resumed.model_config.get("hand_templates")
    else:
        # the prior: the training split's mean camera-frame layout, (29, 3) metres
        mean = data.train_set.ann["keypoints_3d_cam"].astype(np.float64).mean(axis=0).tolist()
        extents = None  # the box of a model that poses the probe rigidly (hupbench.models.heatmap, probe_head)
        if getattr(config, "probe_head", None) == "rigid":
            extents = probe_half_extents(data.train_set.ann["keypoints_3d_cam"][:, kp.CORNER_SLICE]).tolist()
        hands = None  # a model that fits the hand: one training hand per grasp, its fit's starts
        if config.hand_fit == "depth":
            train = data.train_set.dataset
            grasps = read_annotations(train.root, "train", ("grasp_id",), train.manifest)["grasp_id"]
            hands = training_hands(data.train_set.ann["keypoints_3d_cam"], grasps).tolist()
    camera = {"K_input": K_input.tolist(), "input_size": run.data.reader.input_size, "probe_half_extents": extents}
    channels = INPUT_MODALITIES[run.data.reader.input_modalities]
    config = replace(config, points3d_mean=mean, input_channels=channels, hand_templates=hands,
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
