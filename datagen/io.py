"""Atomic file writes: a temporary name in the same folder, then one rename.

A killed process leaves either the old file or the new one, never half of
one under the final name.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np


def _tmp_path(path: Path) -> Path:
    return path.with_name(f".{path.name}.tmp{os.getpid()}")


def write_bytes(path: str | Path, data: bytes) -> Path:
    """Write bytes atomically, creating parent folders."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = _tmp_path(path)
    tmp.write_bytes(data)
    os.replace(tmp, path)
    return path


def write_json(path: str | Path, data: dict) -> Path:
    """Write indented JSON atomically (numpy scalars and paths become plain values)."""
    return write_bytes(path, (json.dumps(data, indent=2, sort_keys=True, default=_plain) + "\n").encode())


def save_npz(path: str | Path, arrays: dict) -> Path:
    """``np.savez`` atomically."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.stem}.tmp{os.getpid()}.npz")  # savez appends .npz to other names
    np.savez(tmp, **arrays)
    os.replace(tmp, path)
    return path


def _plain(value):
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    return str(value)
