"""A training run's config, typed: frozen dataclasses whose ``__post_init__`` is the only check of their fields.

Each node of conf/train.yaml (which documents the fields) is built through its ``_target_``: the model's by
:mod:`hupbench.models.model_config`, the data node's by :class:`hupbench.data.DataConfig`; :func:`train_config`
builds the tree once, before anything is read or written. A bad value is refused naming the field as the user
writes it (``train.max_steps must be a whole number from 1 to 1000000000 or null, got 0``). Inside, the training
reads the typed values as they are.
"""

from __future__ import annotations

import functools
import inspect
from dataclasses import dataclass, field
from pathlib import Path

from omegaconf import DictConfig, OmegaConf

from hupbench.core import keypoints as kp
from hupbench.core.errors import BadValueError
from hupbench.core.input_checks import check_bool_fields, check_choice, check_int, check_number, is_number
from hupbench.core.io import check_writable
from hupbench.core.processes import usable_cores
from hupbench.config import build
from hupbench.data import DataConfig
from hupbench.fits import model_fit_settings
from hupbench.metrics import PROBE_SYMMETRIES
from hupbench.models.model_config import ModelConfig

#: the most steps or epochs a run may ask for: 10^9 steps take years at any speed measured here, so a larger
#: number is a typo (train.max_steps=1e12 would train until killed)
MAX_COUNT = 1_000_000_000
#: learning rates above this make every model here diverge within a few steps
MAX_LR = 1.0


@dataclass(frozen=True)
class Schedule:
    """The ``train`` node: how long a run is, when it logs, validates and saves (in steps), how it resumes."""

    epochs: int = 10
    max_steps: int | None = None
    stop_after: int | None = None
    log_every: int = 20
    val_every: int = 200
    ckpt_every: int = 200
    progress: bool = True
    resume: str | None = "auto"
    bn_recompute_frames: int = 512
    tensorboard: bool = True

    def __post_init__(self) -> None:
        for name in ("epochs", "max_steps", "stop_after", "log_every", "val_every", "ckpt_every"):
            check_int(getattr(self, name), f"train.{name}", 1, MAX_COUNT, optional=name in ("max_steps", "stop_after"))
        check_int(self.bn_recompute_frames, "train.bn_recompute_frames", 0)
        check_bool_fields(self, "train.")


@dataclass(frozen=True)
class LossConfig:
    """The ``loss`` node: the weights of HOPE-Net's MSE terms (:func:`hupbench.training.losses.loss_terms`)."""

    w2d_init: float = 1.25
    w2d: float = 1.25
    w3d: float = 1.0
    unit_3d_m: float = 0.01
    probe_symmetry: str = "none"
    w_seg: float = 1.0

    def __post_init__(self) -> None:
        for weight in ("w2d_init", "w2d", "w3d", "w_seg"):
            check_number(getattr(self, weight), f"loss.{weight}", 0.0)
        check_number(self.unit_3d_m, "loss.unit_3d_m", 0.0, low_open=True)
        check_choice(self.probe_symmetry, "loss.probe_symmetry", sorted(PROBE_SYMMETRIES))


@dataclass(frozen=True)
class OptimConfig:
    """The ``optim`` node: the optimiser and the learning-rate scheduler, Hydra partials given the parameters
    and the run's length when the run starts, and the batch the learning rate is for."""

    optimizer: functools.partial
    scheduler: functools.partial
    reference_batch: int | None = None

    def __post_init__(self) -> None:
        options, takes = self.optimizer.keywords, list(inspect.signature(self.optimizer.func).parameters)[1:]
        unknown = sorted(set(options) - set(takes))
        if unknown:
            raise BadValueError(f"optim.optimizer.{unknown[0]} is not an option of {self.optimizer.func.__name__} "
                                f"(it takes {', '.join(takes)})")
        check_number(options.get("lr"), "optim.optimizer.lr", 0.0, MAX_LR, low_open=True)
        for name in ("weight_decay", "eps"):
            check_number(options.get(name, 0.0), f"optim.optimizer.{name}", 0.0)
        betas = options.get("betas", (0.9, 0.999))
        if not (isinstance(betas, (list, tuple)) and len(betas) == 2
                and all(is_number(beta) and 0 <= beta < 1 for beta in betas)):
            raise BadValueError(f"optim.optimizer.betas must be two numbers in [0, 1), got {betas!r}")
        check_int(self.reference_batch, "optim.reference_batch", 1, optional=True)
        check_int(self.scheduler.keywords.get("warmup_steps", 0), "optim.scheduler.warmup_steps", 0)
        check_number(self.scheduler.keywords.get("final_lr_fraction", 0.0), "optim.scheduler.final_lr_fraction",
                     0.0, 1.0)


@dataclass(frozen=True)
class TrainRun:
    """A training run: what conf/train.yaml composes, every node typed; ``config`` is the composed config,
    resolved, as run.json and checkpoints record it."""

    model_id: str
    model: ModelConfig
    data: DataConfig
    optim: OptimConfig
    train: Schedule = Schedule()
    loss: LossConfig = LossConfig()
    run_name: str = "run"
    label: str | None = None
    out_root: str = "hupbench_out/runs"
    run_dir: str | None = None
    seed: int = 0
    device: str = "cpu"
    precision: str = "auto"
    channels_last: bool = True
    threads: int | None = None
    compile: bool = False
    config: dict = field(default_factory=dict, compare=False, repr=False)

    def __post_init__(self) -> None:
        # more threads than cores only contend for them: a run slows to a crawl
        check_int(self.threads, "threads", 1, usable_cores(), optional=True,
                  hint=" (the CPU cores this process may use)")
        check_int(self.seed, "seed", 0, 2**31 - 1)
        check_choice(self.device, "device", ("cpu", "cuda"))
        check_choice(self.precision, "precision", ("auto", "fp32", "bf16"))
        check_bool_fields(self)
        check_writable(self.folder, "run_dir" if self.run_dir else "out_root/run_name")
        if self.model.n_keypoints != kp.NUM_KEYPOINTS:
            raise BadValueError(f"model.n_keypoints must be {kp.NUM_KEYPOINTS} (21 hand joints + 8 probe corners, "
                                f"as every dataset has), got {self.model.n_keypoints}")
        model_fit_settings(self.model.saved())   # the fit settings the model changes: names and values

    @property
    def folder(self) -> Path:
        """The run folder: run_dir, else out_root/run_name."""
        return Path(self.run_dir) if self.run_dir else Path(self.out_root) / self.run_name


def train_config(cfg: DictConfig) -> TrainRun:
    """The typed run of a composed conf/train.yaml: every node built, and so checked, once."""
    resolved = OmegaConf.to_container(cfg, resolve=True, throw_on_missing=True)
    return TrainRun(**build(cfg), config=resolved)
