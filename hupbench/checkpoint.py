"""Training checkpoints: one file holds everything to rebuild the model and resume the run.

Format (``torch.save`` of a dict, loaded with ``weights_only=True``: no pickled code):

    format          "hupbench-checkpoint"
    version         1
    model_config    dict for :func:`models.build.build_model`
    model           the model's state dict
    optimizer       optimiser state dict (None in an exported "weights only" file)
    scheduler       learning-rate scheduler state dict (or None)
    step            optimiser steps taken
    epoch           epochs completed
    samples_seen    training images consumed
    train_seconds   wall time spent training (excluding validation), s
    input_size      side of the square model input, pixels
    K_input         (3, 3) intrinsics of the model input image (list of lists), the camera
                    the 3D output is trained for
    config          the resolved training config
    dataset         {"path", "manifest_sha256"}
    rng             {"torch": ByteTensor state}, for an exact resume
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import torch
from torch import nn

from datagen.io import write_with
from datagen.input_checks import check_int
from hupbench.inference.model_file import INPUT_SIZE_RANGE
from models.build import build_model, load_checkpoint_state
from datagen.errors import BadValueError, MissingFileError

FORMAT = "hupbench-checkpoint"
VERSION = 1
REQUIRED_KEYS = ("format", "version", "model_config", "model", "step", "input_size", "K_input", "config")


def save_checkpoint(path: str | Path, payload: dict[str, Any]) -> Path:
    """Write a checkpoint atomically (temporary name + rename: a killed run never leaves half a file).

    Args:
        path: destination ``.pt`` file.
        payload: the fields listed in the module docstring; ``format`` and ``version`` are added.
    """
    missing = [k for k in REQUIRED_KEYS if k not in payload and k not in ("format", "version")]
    if missing:
        raise BadValueError(f"checkpoint payload lacks {', '.join(missing)}")
    payload = {"format": FORMAT, "version": VERSION, **payload}
    # torch.save reports a full disk as "[enforce fail at inline_container.cc] . unexpected pos": write_with
    # names the device and the file instead, and removes the temporary file of any failed write
    return write_with(path, lambda tmp: torch.save(payload, tmp))


def read_checkpoint(path: str | Path) -> dict[str, Any]:
    """Load and check a checkpoint dict (tensors on the CPU)."""
    path = Path(path)
    if not path.is_file():
        raise MissingFileError(f"checkpoint {path} does not exist")
    if path.stat().st_size == 0:
        raise BadValueError(f"{path} is empty (0 bytes): not a readable torch checkpoint")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises several unrelated types for a corrupt or foreign file
        # the first sentence only: torch's unpickling errors go on for lines about weights_only=False,
        # which is not the cure for a damaged file
        first = next((line for line in str(exc).splitlines() if line.strip()), "").split(". ")[0][:200]
        raise BadValueError(f"{path} is not a readable torch checkpoint (damaged, truncated or not written by "
                         f"torch.save): {type(exc).__name__}: {first}") from exc
    if not isinstance(payload, dict) or payload.get("format") != FORMAT:
        raise BadValueError(f"{path} is not a hupbench checkpoint (no format={FORMAT!r} field)")
    if payload.get("version") != VERSION:
        raise BadValueError(f"{path} has checkpoint version {payload.get('version')!r}; this hupbench reads {VERSION}")
    missing = [k for k in REQUIRED_KEYS if k not in payload]
    if missing:
        raise BadValueError(f"checkpoint {path} lacks {', '.join(missing)}")
    _check_fields(payload, path)
    return payload


def _check_fields(payload: dict, path: Path) -> None:
    """The fields every consumer relies on, checked before anything is built from them."""
    if not isinstance(payload["model_config"], Mapping) or not isinstance(payload["model_config"].get("name"), str):
        raise BadValueError(f"checkpoint {path}: model_config must be a mapping with a model 'name', "
                         f"got {type(payload['model_config']).__name__}")
    if not isinstance(payload["model"], Mapping):
        raise BadValueError(f"checkpoint {path}: model must be a state dict (name -> tensor), "
                         f"got {type(payload['model']).__name__}")
    size = payload["input_size"]
    check_int(size, f"checkpoint {path}: input_size", *INPUT_SIZE_RANGE)
    K = payload["K_input"]
    try:
        values = [float(v) for row in K for v in row] if len(K) == 3 and all(len(row) == 3 for row in K) else None
    except (TypeError, ValueError):
        values = None
    if values is None or not all(math.isfinite(v) for v in values) or values[0] <= 0 or values[4] <= 0:
        raise BadValueError(f"checkpoint {path}: K_input must be a finite 3 x 3 matrix with positive focal lengths, "
                         f"got {K!r:.80}")
    step = payload["step"]
    check_int(step, f"checkpoint {path}: step", low=0)


def load_model(path: str | Path) -> tuple[nn.Module, dict[str, Any]]:
    """Rebuild the model of a checkpoint and load its weights strictly.

    Returns:
        (model in eval mode on the CPU, the checkpoint dict).
    """
    payload = read_checkpoint(path)
    return load_checkpoint_model(payload, path).eval(), payload


def load_checkpoint_model(payload: dict[str, Any], path: str | Path) -> nn.Module:
    """The model of a checked checkpoint dict, built from its model_config with its weights loaded strictly;
    a config that builds no model, or weights that do not fit it, raise ValueError naming ``path``."""
    name = payload["model_config"].get("name")
    try:
        model = build_model(payload["model_config"])
    except (ValueError, TypeError) as exc:
        raise BadValueError(f"checkpoint {path}: its model_config builds no model: {exc}") from exc
    try:
        return load_checkpoint_state(model, payload["model"])
    except (ValueError, TypeError) as exc:
        raise BadValueError(f"checkpoint {path}: its weights do not fit its model_config (a {name!r} model): "
                         f"{exc}") from exc


def file_sha256(path: str | Path) -> str:
    """Hex SHA-256 of a file's bytes (the dataset manifest hash in results)."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()
