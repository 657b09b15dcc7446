"""Faults a test inflicts on a run: a private tmpfs (a full disk, a read-only folder), a SIGKILL while
writing, a dead writer's pid."""

from __future__ import annotations

import os
import shlex
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from helpers import REPO
from helpers.cli import CliAnswer


def private_mount(options: str, folder: Path, script: str, env: dict | None = None,
                  timeout: float = 600) -> tuple[int, str]:
    """Run the shell ``script`` with a fresh tmpfs (``mount -o OPTIONS``) on ``folder``, in a private mount
    namespace (the mount vanishes with the script). ``$D`` is the mount point. Skips the test where a mount
    namespace cannot be made (no unshare, not root).

    Returns:
        (exit code of the script, its stdout + stderr).
    """
    if shutil.which("unshare") is None:
        pytest.skip("unshare(1) is not installed: no private tmpfs for this fault")
    folder.mkdir(parents=True, exist_ok=True)
    wrapped = f'mount -t tmpfs -o {options} tmpfs "$D" || exit 97\n{script}'
    done = subprocess.run(["unshare", "-m", "--propagation", "private", "sh", "-c", wrapped],
                          capture_output=True, text=True, timeout=timeout, cwd=REPO,
                          env={**os.environ, "PYTHONPATH": str(REPO), "D": str(folder), **(env or {})})
    if done.returncode == 97 or "unshare failed" in done.stderr:
        pytest.skip(f"cannot mount a tmpfs in a private namespace here (not root?): {done.stderr.strip()[-300:]}")
    return done.returncode, done.stdout + done.stderr


def run_in_namespace(argv: list[str], *, read_only: tuple[Path, ...] = (), tmpfs: tuple[Path, int] | None = None,
                     setup: str = "", listing: Path | None = None, after: str = "", timeout: int = 300) -> CliAnswer:
    """Run ``python3 -m hupbench.cli ARGV`` in a private mount namespace (needs root; skips otherwise).

    Args:
        argv: the hupbench arguments.
        read_only: folders bind-mounted read-only on themselves.
        tmpfs: ``(folder, size_kb)``: a small tmpfs mounted on the folder (a disk that fills up).
        setup: shell commands run after mounting, before hupbench (e.g. copy an old file in).
        listing: a file outside the mounts that receives ``find``'s list of the tmpfs folder
            (relative path and size per line) after the run, since the tmpfs dies with the namespace.
        after: shell commands run after hupbench, still in the namespace (the exit code stays hupbench's).
    """
    q = shlex.quote
    lines = []
    if tmpfs is not None:
        tmpfs[0].mkdir(parents=True, exist_ok=True)
        lines.append(f"mount -t tmpfs -o size={tmpfs[1]}k tmpfs {q(str(tmpfs[0]))} || exit 97")
    for folder in read_only:
        lines.append(f"mount --bind -o ro {q(str(folder))} {q(str(folder))} || exit 97")
    lines.append(setup)
    lines.append(" ".join(q(a) for a in [sys.executable, "-m", "hupbench.cli", *map(str, argv)]))
    lines.append("rc=$?")
    if listing is not None and tmpfs is not None:
        lines.append(f"find {q(str(tmpfs[0]))} -mindepth 1 -printf '%P %s\\n' > {q(str(listing))}")
    lines.append(after)
    lines.append("exit $rc")
    try:
        proc = subprocess.run(["unshare", "-m", "--propagation", "private", "sh", "-c", "\n".join(lines)],
                              capture_output=True, text=True, timeout=timeout, cwd=REPO,
                              env=os.environ | {"PYTHONPATH": str(REPO)})
    except FileNotFoundError:
        pytest.skip("unshare is not installed: no private mount namespace for a read-only folder or a full disk")
    if proc.returncode == 97 or "unshare failed" in proc.stderr or "unshare:" in proc.stderr:
        pytest.skip(f"cannot mount in a private namespace here (needs root): {proc.stderr.strip()[:200]}")
    return CliAnswer(proc.returncode, proc.stdout, proc.stderr)


def full_disk_script(command: str, disk: Path) -> str:
    """Fill the tmpfs on ``disk`` (8 kB) to the last byte, run ``command``, list what it left there."""
    return (f'head -c 8192 /dev/zero > "{disk}/filler"; {command}; rc=$?; echo "RC=$rc"; '
            f'find "{disk}" -name ".*.tmp*" -printf "TMP %p\\n"; find "{disk}" -type f -printf "FILE %p\\n"')


def parse_full_disk(output: str) -> tuple[CliAnswer, list[str], list[str]]:
    lines = output.splitlines()
    rc = int(next(line for line in lines if line.startswith("RC="))[3:])
    tmp = [line[4:] for line in lines if line.startswith("TMP ")]
    files = [line[5:] for line in lines if line.startswith("FILE ")]
    err = "\n".join(line for line in lines if not line.startswith(("RC=", "TMP ", "FILE ")))
    return CliAnswer(rc, "", err), tmp, files


def run_killed_then_again(argv: list[str], cwd: Path, seed: int, folder: Path, pattern: str,
                          window_s: float, attempts: int = 5) -> list[str]:
    """Run ``argv``; once a file matching ``pattern`` appears in ``folder`` (a temporary file: the run is
    writing), SIGKILL it at a seeded random moment within ``window_s`` s; then run it again to the end.

    A fast machine can finish writing inside the window (the kill then lands after the rename and tests
    nothing): such an attempt is thrown away, ``folder`` emptied, and the kill tried again with half the
    window, up to ``attempts`` times.

    Returns:
        The names in ``folder`` right after the kill (what the killed run left, a temporary file among them).
    """
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    rng = np.random.default_rng(seed)
    for _ in range(attempts):
        proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=cwd, env=env)
        while not list(folder.glob(pattern)) and proc.poll() is None:
            time.sleep(0.005)
        time.sleep(float(rng.uniform(0.0, window_s)))
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        left = sorted(p.name for p in folder.iterdir())
        if list(folder.glob(pattern)):
            break
        for path in folder.iterdir():  # the run outran its kill: start over with a shorter window
            shutil.rmtree(path) if path.is_dir() else path.unlink()
        window_s /= 2
    else:
        raise AssertionError(f"{attempts} runs each finished writing before their kill: {argv}")
    done = subprocess.run(argv, capture_output=True, text=True, cwd=cwd, env=env, timeout=900)
    assert done.returncode == 0, f"killed leaving {left}, then: {done.stderr[-3000:]}"
    return left


def dead_pid() -> int:
    """The pid of a process that has exited (what a killed writer's temporary name carries)."""
    proc = subprocess.Popen(["true"])
    proc.wait()
    return proc.pid


def like_a_terminal() -> None:
    """``preexec_fn`` of a process that Ctrl-C must reach: SIGINT handled by default and not blocked, as a
    shell starts a program. The test process itself may have inherited an ignored or blocked SIGINT (a full
    suite run left the Ctrl-C tests' children deaf to it: they trained on for the whole 120 s)."""
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def sigint_state(pid: int | str = "self") -> str:
    """How process ``pid`` treats SIGINT, from /proc: ignored, blocked (a diagnosis when Ctrl-C went unheard)."""
    bit = 1 << (signal.SIGINT - 1)
    try:
        fields = dict(line.split(":", 1) for line in Path(f"/proc/{pid}/status").read_text().splitlines() if ":" in line)
    except OSError:
        return "unknown"
    return ", ".join(f"{name} {'yes' if int(fields[key], 16) & bit else 'no'}"
                     for name, key in (("ignored", "SigIgn"), ("blocked", "SigBlk")) if key in fields)
