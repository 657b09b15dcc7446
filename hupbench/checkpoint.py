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
import os
from pathlib import Path
from typing import Any

import torch
from torch import nn

from models.build import build_model, load_checkpoint_state

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
        raise ValueError(f"checkpoint payload lacks {', '.join(missing)}")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    torch.save({"format": FORMAT, "version": VERSION, **payload}, tmp)
    os.replace(tmp, path)
    return path


def read_checkpoint(path: str | Path) -> dict[str, Any]:
    """Load and check a checkpoint dict (tensors on the CPU)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"checkpoint {path} does not exist")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises several unrelated types for a corrupt or foreign file
        raise ValueError(f"{path} is not a readable torch checkpoint: {type(exc).__name__}: {exc}") from exc
    if not isinstance(payload, dict) or payload.get("format") != FORMAT:
        raise ValueError(f"{path} is not a hupbench checkpoint (no format={FORMAT!r} field)")
    if payload.get("version") != VERSION:
        raise ValueError(f"{path} has checkpoint version {payload.get('version')!r}; this hupbench reads {VERSION}")
    missing = [k for k in REQUIRED_KEYS if k not in payload]
    if missing:
        raise ValueError(f"checkpoint {path} lacks {', '.join(missing)}")
    return payload


def load_model(path: str | Path) -> tuple[nn.Module, dict[str, Any]]:
    """Rebuild the model of a checkpoint and load its weights strictly.

    Returns:
        (model in eval mode on the CPU, the checkpoint dict).
    """
    payload = read_checkpoint(path)
    model = load_checkpoint_state(build_model(payload["model_config"]), payload["model"])
    return model.eval(), payload


def file_sha256(path: str | Path) -> str:
    """Hex SHA-256 of a file's bytes (the dataset manifest hash in results)."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()
