"""Training checkpoints: one file holds everything to rebuild the model and resume the run.

The file is ``torch.save`` of :meth:`Checkpoint.record`, loaded with ``weights_only=True`` (no pickled
code): ``format`` "hupbench-checkpoint", ``version`` 1 and the fields of :class:`Checkpoint`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import MISSING, dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from hupbench.core.errors import BadValueError, MissingFileError
from hupbench.core.input_checks import check_int
from hupbench.core.io import write_with
from hupbench.input_geometry import INPUT_SIZE_RANGE
from hupbench.models.build import build_model, load_checkpoint_state

FORMAT = "hupbench-checkpoint"
VERSION = 1
#: relative agreement of a model's intrinsics buffer with its checkpoint's K_input (float32 rounding)
INTRINSICS_REL_TOL = 1e-5

@dataclass(frozen=True)
class Checkpoint:
    """The record of one checkpoint: the model's saved config (:func:`hupbench.models.build.build_model`) and state dict,
    the model input's side (pixels) and (3, 3) intrinsics K_input (the camera the 3D output is trained for), the
    resolved training config, and for a resume the optimiser, scheduler and torch RNG states, the counters
    (train_seconds excludes validation) and validations (mm); ``path`` (not saved) names the file in errors."""

    model_config: dict
    model: dict
    step: int
    input_size: int
    K_input: list
    config: dict
    optimizer: dict | None = None
    scheduler: dict | None = None
    epoch: float = 0.0
    samples_seen: int = 0
    train_seconds: float = 0.0
    wall_seconds: float | None = None
    best_val_mpjpe_mm: float = math.inf
    val_mpjpe_mm: dict | None = None
    first_val_mpjpe_mm: dict | None = None
    dataset: dict | None = None
    rng: dict | None = None
    world_size: int = 1
    path: Path | None = field(default=None, compare=False)

    def record(self) -> dict[str, Any]:
        """What the file holds: ``format``, ``version`` and every field but ``path``."""
        return {"format": FORMAT, "version": VERSION,
                **{f.name: getattr(self, f.name) for f in fields(self) if f.name != "path"}}

    def save(self, path: str | Path) -> Path:
        """Write atomically (temporary name + rename: a killed run never leaves half a file)."""
        # torch.save reports a full disk as "[enforce fail at inline_container.cc] . unexpected pos": write_with
        # names the device and the file instead, and removes the temporary file of any failed write
        return write_with(path, lambda tmp: torch.save(self.record(), tmp))

    @classmethod
    def read(cls, path: str | Path) -> Checkpoint:
        """Load a checkpoint file (tensors on the CPU) and check the fields every consumer relies on."""
        path = Path(path)
        if not path.is_file():
            raise MissingFileError(f"checkpoint {path} does not exist")
        try:
            payload = torch.load(path, map_location="cpu", weights_only=True)
        except Exception as exc:  # torch raises several unrelated types for a corrupt or foreign file
            # the first sentence only: torch's unpickling errors go on for lines about weights_only=False,
            # which is not the cure for a damaged file
            first = next((line for line in str(exc).splitlines() if line.strip()), "").split(". ")[0][:200]
            reason = first or ("an empty file (0 bytes)" if path.stat().st_size == 0 else "no message")
            raise BadValueError(f"{path} is not a readable torch checkpoint (damaged, truncated or not written by "
                                f"torch.save): {type(exc).__name__}: {reason}") from exc
        header = (payload.get("format"), payload.get("version")) if isinstance(payload, dict) else (None, None)
        if header != (FORMAT, VERSION):
            said = ", ".join(f"{name} {value!r:.40}" if value is not None else f"no {name}"
                             for name, value in zip(("format", "version"), header))
            raise BadValueError(f"{path} is not a hupbench checkpoint of version {VERSION} (format={FORMAT!r}): it "
                                f"has {said}")
        missing = [f.name for f in fields(cls) if f.default is MISSING and f.default_factory is MISSING
                   and f.name not in payload]
        if missing:
            raise BadValueError(f"checkpoint {path} lacks {', '.join(missing)}")
        config, state = payload["model_config"], payload["model"]
        if not (isinstance(config, Mapping) and isinstance(config.get("name"), str) and isinstance(state, Mapping)):
            raise BadValueError(f"checkpoint {path}: model_config must be a mapping with a model 'name' and model a "
                                f"state dict (name -> tensor), got {type(config).__name__} and {type(state).__name__}")
        check_int(payload["input_size"], f"checkpoint {path}: input_size", *INPUT_SIZE_RANGE)
        check_int(payload["step"], f"checkpoint {path}: step", low=0)
        try:
            K = np.asarray(payload["K_input"], dtype=np.float64)
        except (TypeError, ValueError):  # ragged, or not numbers
            K = np.zeros(0)
        if K.shape != (3, 3) or not np.isfinite(K).all() or K[0, 0] <= 0 or K[1, 1] <= 0:
            raise BadValueError(f"checkpoint {path}: K_input must be a finite 3 x 3 matrix with positive focal "
                                f"lengths, got {payload['K_input']!r:.80}")
        return cls(**{f.name: payload[f.name] for f in fields(cls) if f.name in payload}, path=path)

    def build_model(self) -> nn.Module:
        """The model of this checkpoint, built from its model_config with its weights loaded strictly; a config
        that builds no model, weights that do not fit it, or an input camera that is not ``K_input``, are refused
        naming the file."""
        try:
            model = load_checkpoint_state(build_model(self.model_config), self.model)
        except (ValueError, TypeError) as exc:
            raise BadValueError(f"checkpoint {self.path}: its model_config (a {self.model_config['name']!r} model) "
                                f"and its weights build no model: {exc}") from exc
        self._check_camera(model)
        return model

    def _check_camera(self, model: nn.Module) -> None:
        """A model that unprojects through its input camera holds it as an ``intrinsics`` buffer (normalised
        (fx, fy, cx, cy), :func:`hupbench.models.hopenet.normalized_intrinsics`): it must be the camera of
        ``K_input``, which eval, export and the fits use for the same 3D points."""
        from hupbench.models.hopenet import normalized_intrinsics

        buffer = getattr(model, "intrinsics", None)
        if buffer is None:
            return
        expected = normalized_intrinsics(self.K_input, self.input_size)
        if not torch.allclose(buffer.detach().float().cpu(), expected, rtol=INTRINSICS_REL_TOL, atol=0.0):
            raise BadValueError(f"checkpoint {self.path}: the model's intrinsics buffer (normalised fx, fy, cx, cy) "
                                f"{[round(float(v), 6) for v in buffer]} is not the camera of its K_input "
                                f"{[round(float(v), 6) for v in expected]} at input_size {self.input_size}: the "
                                f"checkpoint was edited or mixes two runs")


def load_model(path: str | Path) -> tuple[nn.Module, dict[str, Any]]:
    """Rebuild the model of a checkpoint file and load its weights strictly.

    Returns:
        (model in eval mode on the CPU, the checkpoint's :meth:`Checkpoint.record`).
    """
    checkpoint = Checkpoint.read(path)
    return checkpoint.build_model().eval(), checkpoint.record()
