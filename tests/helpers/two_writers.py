"""Two runs writing one output at once: the first, a real process, is caught while it writes."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

from helpers import REPO


def start_writing(argv: list[str], folder: Path, timeout_s: float = 300.0) -> subprocess.Popen:
    """Start ``python -m hupbench.cli ARGV`` and return it once it holds a lock in ``folder`` (a ``*.lock``
    file there records its pid): the lock file exists before it is locked and written, and a second run
    started in that gap could take the lock first.

    Raises:
        AssertionError: the run ended, or took no lock there within ``timeout_s``.
    """
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    proc = subprocess.Popen([sys.executable, "-m", "hupbench.cli", *map(str, argv)], cwd=REPO, env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + timeout_s
    while not _holds_lock(folder, proc.pid):
        if proc.poll() is not None or time.monotonic() > deadline:
            proc.kill()
            raise AssertionError(f"the first run took no lock in {folder} (exit {proc.wait()}): "
                                 f"{proc.stderr.read()[-2000:]}")
        time.sleep(0.005)
    return proc


def _holds_lock(folder: Path, pid: int) -> bool:
    """Whether a lock file in ``folder`` records ``pid`` as its holder (written once the lock is taken)."""
    for path in folder.glob("*.lock") if folder.is_dir() else ():
        try:
            if json.loads(path.read_text()).get("pid") == pid:
                return True
        except (OSError, ValueError):  # gone, or not yet written
            continue
    return False


def finish(proc: subprocess.Popen, timeout_s: float = 600.0) -> None:
    """Wait for the first run; it must have succeeded."""
    _, err = proc.communicate(timeout=timeout_s)
    assert proc.returncode == 0, f"the first run failed (exit {proc.returncode}): {err[-3000:]}"
