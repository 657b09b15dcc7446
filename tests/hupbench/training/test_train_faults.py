"""Faults of ``python train.py`` (docs/robustness.md, section train.py): a second run on the same folder, the
lock of a killed run, a full disk, SIGKILL at random points followed by the same command.

The default versions are small (the 64 px tiny dataset, 6 steps); the many-kill version is marked slow.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from helpers.cli import CliAnswer, assert_clean_error
from helpers.training import REPO, TRAIN_PREFIX, train_py
from helpers import THREADS
from helpers.faults import dead_pid, private_mount

STEPS = 6


def overrides(dataset, run_dir, cache, *extra) -> list[str]:
    """A 6-step run on the tiny dataset: validation and checkpoints every 2 steps, a loss line every step."""
    return ["model=hopenet_r10_128", f"data.root={dataset}", f"run_dir={run_dir}", f"data.cache_dir={cache}",
            "data.reader.input_size=64", "data.batch_size=4", "data.num_workers=0", "data.val_frames=8",
            f"train.max_steps={STEPS}", "train.val_every=2", "train.ckpt_every=2", "train.log_every=1",
            "train.progress=false", "train.tensorboard=false", f"threads={THREADS}", "precision=fp32", *extra]


def read_log(run_dir: Path) -> list[dict]:
    return [json.loads(line) for line in (run_dir / "metrics.jsonl").read_text().splitlines()]


def temporary_files(*folders: Path) -> list[Path]:
    return [p for folder in folders if folder.exists() for p in folder.rglob(".*.tmp*")]


def assert_whole_run(run_dir: Path, reference: dict[int, float], cache: Path) -> None:
    """The run finished; its log holds every step once, with the losses of an uninterrupted run; no
    temporary file and no lock is left."""
    from hupbench.checkpoint import Checkpoint

    assert (run_dir / "summary.json").is_file()
    log = read_log(run_dir)
    keys = [(r["event"], r["step"]) for r in log]
    assert len(keys) == len(set(keys)), f"steps logged twice: {sorted(k for k in keys if keys.count(k) > 1)}"
    losses = {r["step"]: r["loss"] for r in log if r["event"] == "train"}
    assert sorted(losses) == list(range(1, STEPS + 1))
    for step, loss in reference.items():
        assert losses[step] == pytest.approx(loss, rel=1e-6, abs=1e-9), step
    assert [r["step"] for r in log if r["event"] == "val"] == [0, 2, 4, 6]
    assert Checkpoint.read(run_dir / "checkpoints" / "last.pt").step == STEPS
    assert not temporary_files(run_dir, cache)
    assert not (run_dir / ".hupbench.lock").exists()


class Reference(dict):
    """Losses per step of one uninterrupted run; ``wall_s``: how long its loop took."""

    wall_s: float


@pytest.fixture(scope="module")
def reference(tiny_dataset, tmp_path_factory) -> Reference:
    """One uninterrupted run (in this process: the same code and thread count as train.py's)."""
    from hupbench.config import compose
    from hupbench.training.loop import run_train

    folder = tmp_path_factory.mktemp("reference")
    result = run_train(compose("train", overrides(tiny_dataset, folder / "run", folder / "cache")),
                       log=lambda *_: None)
    losses = Reference({r["step"]: r["loss"] for r in read_log(folder / "run") if r["event"] == "train"})
    losses.wall_s = float(result["wall_seconds"])
    return losses


def _hold_lock(run_dir: Path) -> subprocess.Popen:
    """Another live process holding the run folder's lock, as a running train.py does."""
    holder = subprocess.Popen(
        [sys.executable, "-c", "import sys, time\nfrom hupbench.core.io import OutputLock\n"
         "OutputLock(sys.argv[1], 'training').acquire()\nprint('held', flush=True)\ntime.sleep(600)\n", str(run_dir)],
        stdout=subprocess.PIPE, text=True, cwd=REPO, env={**os.environ, "PYTHONPATH": str(REPO)})
    assert holder.stdout.readline().strip() == "held"
    return holder


@pytest.mark.matrix
def test_fault_train_second_run_refused(tiny_dataset, tmp_path):
    """Measured before: two train.py runs with one run_name both exited 0 and metrics.jsonl held every step
    twice. Now the second is refused in one line naming the holder's pid and host, and writes nothing."""
    run_dir = tmp_path / "run"
    holder = _hold_lock(run_dir)
    try:
        answer = train_py(*overrides(tiny_dataset, run_dir, tmp_path / "cache"), cwd=tmp_path)
        assert_clean_error(answer, str(run_dir), f"pid {holder.pid}", socket.gethostname(), "in use",
                           prefix=TRAIN_PREFIX)
        assert answer.rc == 1
        assert sorted(p.name for p in run_dir.iterdir()) == [".hupbench.lock"]  # untouched
        assert json.loads((run_dir / ".hupbench.lock").read_text())["pid"] == holder.pid
    finally:
        holder.kill()
        holder.wait()


@pytest.mark.matrix
def test_fault_train_stale_lock_taken_over(tiny_dataset, tmp_path, reference, capsys):
    """The lock file of a run killed with SIGKILL stays behind; the next run takes it over, says so, and
    finishes as an uninterrupted run would."""
    from hupbench.verbs.train import task
    from hupbench.config import compose

    run_dir, cache = tmp_path / "run", tmp_path / "cache"
    holder = _hold_lock(run_dir)
    holder.send_signal(signal.SIGKILL)
    holder.wait()
    assert json.loads((run_dir / ".hupbench.lock").read_text())["pid"] == holder.pid
    task(compose("train", overrides(tiny_dataset, run_dir, cache)))
    out = capsys.readouterr().out
    assert f"took over {run_dir} from a run that is gone (pid {holder.pid} on {socket.gethostname()})" in out
    assert_whole_run(run_dir, reference, cache)


def _inspect(folder: str) -> str:
    """Shell lines that list, inside the private mount, what a failed command left: temporary files, files."""
    return (f'echo "RC=$rc"; find "{folder}" -name ".*.tmp*" -printf "TMP %p\\n"; '
            f'find "{folder}" -type f -printf "FILE %p %s\\n"')


def _parse(output: str) -> tuple[int, list[str], list[str], str]:
    rc = int(next(line for line in output.splitlines() if line.startswith("RC="))[3:])
    tmp = [line[4:] for line in output.splitlines() if line.startswith("TMP ")]
    files = [line[5:] for line in output.splitlines() if line.startswith("FILE ")]
    err = "\n".join(line for line in output.splitlines() if not line.startswith(("RC=", "TMP ", "FILE ")))
    return rc, tmp, files, err


@pytest.mark.matrix
@pytest.mark.parametrize("where", ["checkpoint", "frame-cache"])
def test_fault_train_disk_full(where, tiny_dataset, tmp_path):
    """A full disk, measured before: a checkpoint write failed with torch's "[enforce fail at
    inline_container.cc:672] . unexpected pos" and left .last.pt.tmpNNN files; a frame cache build was killed
    by SIGBUS (exit 135) leaving .train_64px.npy.tmpNNN. Now: one line naming the device and the file, exit 1,
    no temporary file, no summary.json. The run folder (or the cache) is on a 2 MB (100 kB) tmpfs."""
    disk = tmp_path / "disk"
    if where == "checkpoint":  # run.json and the log fit, the first checkpoint (best.pt, 60 MB) does not
        run_dir, cache, size, file = disk / "run", tmp_path / "cache", "2m", disk / "run" / "checkpoints" / "best.pt"
    else:  # the train split's frame cache (20 x 64 x 64 x 3 bytes) does not fit
        run_dir, cache, size, file = tmp_path / "run", disk / "cache", "100k", disk / "cache" / "train_64px.npy"
    args = " ".join(f"'{a}'" for a in overrides(tiny_dataset, run_dir, cache, "train.tensorboard=true"))
    rc, output = private_mount(f"size={size}", disk, f'"{sys.executable}" train.py {args}; rc=$?; {_inspect(disk)}')
    rc, tmp, files, err = _parse(output)
    assert_clean_error(CliAnswer(rc, "", err), f"no space left on {disk} writing {file}", prefix=TRAIN_PREFIX)
    assert rc == 1 and not tmp, tmp
    assert not [f for f in files if "summary.json" in f or f.endswith(".npy")], files
    assert not list(tmp_path.rglob("summary.json")) and not temporary_files(tmp_path)


def _log_lines(run_dir: Path) -> int:
    try:
        return (run_dir / "metrics.jsonl").read_text().count("\n")
    except OSError:
        return 0


def _kill_at_random_points(argv: list[str], cwd: Path, rng: np.random.Generator, kills: int, window_s: float,
                           run_dir: Path | None = None) -> list[float]:
    """Start ``argv`` ``kills`` times and SIGKILL it each time at a seeded random moment: within ``window_s``
    seconds of its start or, with ``run_dir``, within 0.2 s after its metrics.jsonl reached a seeded random
    number of lines (1 to 8 of the 10 a whole run writes: the kill lands in training whatever the machine's
    speed, in a step, a validation, a checkpoint or a log write).

    Returns:
        The delays used (s, from the start or from the line); negative when the run had finished first.
    """
    delays = []
    for _ in range(kills):
        proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=cwd,
                                env={**os.environ, "PYTHONPATH": str(REPO)})
        if run_dir is not None:
            lines, delay = int(rng.integers(1, 9)), float(rng.uniform(0.0, 0.2))
            while _log_lines(run_dir) < lines and proc.poll() is None:
                time.sleep(0.005)
        else:
            delay = float(rng.uniform(0.0, window_s))
        time.sleep(delay)
        if proc.poll() is None:
            proc.send_signal(signal.SIGKILL)
        else:
            delay = -delay
        proc.wait()
        delays.append(delay)
    return delays


def _sigkill_then_resume(tiny_dataset, tmp_path, reference, seed: int, kills: int, in_training: bool,
                         window_s: float = 0.0) -> tuple[list[float], bool]:
    run_dir, cache = tmp_path / "run", tmp_path / "cache"
    argv = [sys.executable, str(REPO / "train.py"), *overrides(tiny_dataset, run_dir, cache)]
    delays = _kill_at_random_points(argv, tmp_path, np.random.default_rng(seed), kills, window_s,
                                    run_dir if in_training else None)
    # the last kill caught the run while it held its folder: the lock file (and its pid) are left behind
    killed_holding = (run_dir / ".hupbench.lock").exists()
    done = subprocess.run(argv, capture_output=True, text=True, cwd=tmp_path, timeout=900,
                          env={**os.environ, "PYTHONPATH": str(REPO)})
    assert done.returncode == 0, f"kills after {delays} s; then {done.stderr[-3000:]}"
    assert "error" not in done.stderr.lower(), done.stderr
    assert ("took over" in done.stdout) == killed_holding, (delays, done.stdout)
    assert_whole_run(run_dir, reference, cache)
    return delays, killed_holding


@pytest.mark.matrix
def test_fault_train_sigkill_then_resume(tiny_dataset, tmp_path, reference):
    """SIGKILL at a seeded random point of training, then the same command: it resumes from the last
    checkpoint and ends with the losses of an uninterrupted run, each step logged once, no temporary file."""
    delays, killed_holding = _sigkill_then_resume(tiny_dataset, tmp_path, reference, seed=15, kills=1,
                                                  in_training=True)
    assert killed_holding, f"the run finished before its kill ({delays[0]:.2f} s after its log line)"


@pytest.mark.matrix
@pytest.mark.slow
@pytest.mark.parametrize("seed", [1, 2, 3])
def test_fault_train_sigkill_many_times(seed, tiny_dataset, tmp_path, reference):
    """Three SIGKILLs in a row at seeded random points from the start of the process (imports, the frame
    cache build, validation, steps, checkpoint and log writes: wherever they land), then the same command."""
    _sigkill_then_resume(tiny_dataset, tmp_path, reference, seed=seed, kills=3, in_training=False,
                         window_s=20.0 + reference.wall_s)




@pytest.mark.matrix
def test_fault_train_stale_tmp_removed(tiny_dataset, tmp_path, reference, capsys):
    """Temporary files that killed runs left (measured before: 23 MB of .last.pt.tmpNNN and .best.pt.tmpNNN
    that survived a later successful resume) are removed when training starts; a live writer's are kept."""
    from hupbench.verbs.train import task
    from hupbench.config import compose

    run_dir, cache = tmp_path / "run", tmp_path / "cache"
    pid = dead_pid()
    stale = [run_dir / "checkpoints" / f".last.pt.tmp{pid}", run_dir / "checkpoints" / f".best.pt.tmp{pid}",
             run_dir / f".metrics.jsonl.tmp{pid}", cache / f".train_64px.npy.tmp{pid}"]
    live = run_dir / f".notes.txt.tmp{os.getpid()}"  # this process is alive: a writer still at work
    for path in [*stale, live]:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(b"\0" * 1000)
    task(compose("train", overrides(tiny_dataset, run_dir, cache)))
    out = capsys.readouterr().out
    for path in stale[:3]:
        assert not path.exists() and f"removed {path}, a temporary file of a run that was killed" in out
    assert not stale[3].exists()  # the frame cache build cleans its own folder
    assert live.exists()
    live.unlink()
    assert_whole_run(run_dir, reference, cache)
