"""What a training config may hold, checked before anything is read (``train.py: error: FIELD ...``)."""

from __future__ import annotations

from omegaconf import DictConfig, OmegaConf

from datagen.input_checks import check_int, check_number
from datagen.errors import BadValueError


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
    check_int(value, field, low, optional=optional)
    if value > high:
        raise BadValueError(f"{field} must be at most {high:,}, got {value:,}")


def _number(cfg: DictConfig, field: str, low: float, high: float | None = None, low_open: bool = False) -> None:
    check_number(OmegaConf.select(cfg, field), field, low, high, low_open=low_open)


def _choice(cfg: DictConfig, field: str, choices, default=None) -> None:
    value = OmegaConf.select(cfg, field, default=default)
    if value not in choices:
        raise BadValueError(f"{field} must be {' or '.join(repr(c) for c in choices)}, got {value!r}")


def check_schedule(cfg: DictConfig) -> None:
    """Refuse a batch size or step count that is not a whole number from 1 to :data:`MAX_COUNT` (0 used to
    divide by zero or, for max_steps, to train the epochs default without a word), naming the field."""
    for field, optional in SCHEDULE_FIELDS.items():
        _whole(cfg, field, 1, optional)


def check_config(cfg: DictConfig) -> None:
    """Every number and choice of a training config that the run uses, checked before anything is read or
    written; the error names the field and what it must be (Hydra passes ``data.batch_size=abc`` on as a
    string, ``optim.optimizer.lr=nan`` as a float)."""
    from hupbench.config import build
    from hupbench.metrics import PROBE_SYMMETRIES

    check_schedule(cfg)
    _whole(cfg, "data.num_workers", 0, high=1024)
    _whole(cfg, "threads", 1, optional=True, high=4096)
    _whole(cfg, "seed", 0, high=2**31 - 1)
    _whole(cfg, "data.val_frames", 1, optional=True)
    _whole(cfg, "train.bn_recompute_frames", 0)
    build(cfg.data.reader)  # ReaderConfig checks its fields
    _number(cfg, "optim.optimizer.lr", 0.0, MAX_LR, low_open=True)
    for weight in ("w2d_init", "w2d", "w3d"):
        _number(cfg, f"loss.{weight}", 0.0)
    _number(cfg, "loss.unit_3d_m", 0.0, low_open=True)
    _choice(cfg, "loss.probe_symmetry", sorted(PROBE_SYMMETRIES), default="none")
    _choice(cfg, "device", ("cpu", "cuda"))
    _choice(cfg, "precision", ("fp32", "bf16"))
    _choice(cfg, "data.pipeline", ("cache", "jpeg"), default="cache")
