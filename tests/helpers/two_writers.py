"""Two runs writing one output at once: the first, a real process, is caught while it writes."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

from helpers import REPO


def start_writing(argv: list[str], folder: Path, timeout_s: float = 300.0) -> subprocess.Popen:
    """Start ``python -m hupbench.cli ARGV`` and return it once something appears in ``folder`` (its lock,
    a temporary file or a first output: the run is writing there).

    Raises:
        AssertionError: the run ended, or wrote nothing there within ``timeout_s``.
    """
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    proc = subprocess.Popen([sys.executable, "-m", "hupbench.cli", *map(str, argv)], cwd=REPO, env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + timeout_s
    while not (folder.is_dir() and any(folder.iterdir())):
        if proc.poll() is not None or time.monotonic() > deadline:
            proc.kill()
            raise AssertionError(f"the first run wrote nothing into {folder} (exit {proc.wait()}): "
                                 f"{proc.stderr.read()[-2000:]}")
        time.sleep(0.005)
    return proc


def finish(proc: subprocess.Popen, timeout_s: float = 600.0) -> None:
    """Wait for the first run; it must have succeeded."""
    _, err = proc.communicate(timeout=timeout_s)
    assert proc.returncode == 0, f"the first run failed (exit {proc.returncode}): {err[-3000:]}"
