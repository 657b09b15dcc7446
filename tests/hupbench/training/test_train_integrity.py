"""A training run is complete only when what it wrote is whole (docs/robustness.md, train.py): weights that
became NaN, a resume on another dataset, optimiser values that fail only later, more threads than cores and
Ctrl-C each get one line and a non-zero exit; a bug in the training step keeps its traceback.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import signal
import subprocess
import sys
import time

import pytest

from helpers.cli import assert_clean_error, assert_nothing_complete
from hupbench.core.processes import usable_cores
from helpers.answers import record_answer
from helpers.faults import like_a_terminal, sigint_state
from helpers.training import REPO, TRAIN_PREFIX, tiny_cfg, tiny_overrides, train_answer


def strict_json(text: str):
    """json.loads that refuses NaN and Infinity, which are not JSON."""
    def refuse(name):
        raise ValueError(f"{name} is not JSON")

    return json.loads(text, parse_constant=refuse)


@pytest.mark.matrix
@pytest.mark.parametrize("steps, needles", [(1, ("weights became nan", "step 1")), (3, ("loss became nan", "step 2"))],
                         ids=["weights-nan", "loss-nan"])
def test_matrix_train_diverged(steps, needles, tiny_dataset, tmp_path, capsys):
    """With Adam's eps 0 the weights of unused parameters become 0/0 in the first step. Measured before: a 1-step
    run exited 0 and its summary.json held a bare NaN (not JSON) as its validation MPJPE; a run that logged the
    NaN loss ended in a FloatingPointError traceback. Now one line naming the step, exit 1, no summary.json, and
    every line written is JSON."""
    run_dir = tmp_path / "run"
    answer = train_answer(capsys, tiny_cfg(tiny_dataset, run_dir, tmp_path / "cache", f"train.max_steps={steps}",
                                           "train.val_every=100", "+optim.optimizer.eps=0"))
    assert_clean_error(answer, *needles, prefix=TRAIN_PREFIX)
    assert answer.rc == 1
    assert_nothing_complete(tmp_path, "summary.json")
    for line in (run_dir / "metrics.jsonl").read_text().splitlines():
        strict_json(line)


@pytest.mark.matrix
def test_matrix_train_resume_on_another_dataset(tiny_dataset, tmp_path, capsys):
    """train.resume=auto on a dataset regenerated in the same folder: measured before, the run continued on it.
    Now refused naming both manifests' sha256."""
    root = tmp_path / "dataset"
    shutil.copytree(tiny_dataset, root, ignore=shutil.ignore_patterns("cache"))
    run_dir, cache = tmp_path / "run", tmp_path / "cache"
    first = train_answer(capsys, tiny_cfg(root, run_dir, cache, "train.stop_after=1"))
    assert first.rc == 0, first
    manifest = root / "manifest.json"
    trained_on = hashlib.sha256(manifest.read_bytes()).hexdigest()
    manifest.write_text(json.dumps(json.loads(manifest.read_text()), indent=1))  # another file, as a new dataset's
    answer = train_answer(capsys, tiny_cfg(root, run_dir, cache))
    now = hashlib.sha256(manifest.read_bytes()).hexdigest()
    assert_clean_error(answer, "last.pt", "another dataset", trained_on, now, prefix=TRAIN_PREFIX)
    assert answer.rc == 1
    assert_nothing_complete(tmp_path, "summary.json")


# more threads than cores: one more is enough to show the bound (threads=4096 made a 1-step run take over 300 s
# and the machine's load some thousands: not a thing to run where it is accepted)
THREADS = usable_cores() + 1


@pytest.mark.matrix
@pytest.mark.parametrize("override, needles", [
    ("optim.optimizer.weight_decay=-1", ("optim.optimizer.weight_decay", ">= 0")),
    (f"threads={THREADS}", ("threads must be a whole number", f"got {THREADS}", "CPU core")),
], ids=["weight-decay-negative-cli", "threads-over-cores-cli"])
def test_matrix_train_refused_before_work(override, needles, tiny_dataset, tmp_path, capsys):
    """Measured before: weight_decay=-1 failed after the frame cache was built and the first validation ran, in
    Adam's words without the field; more threads than cores were accepted. Now both are refused before anything
    is read or written."""
    run_dir = tmp_path / "run"
    answer = train_answer(capsys, tiny_cfg(tiny_dataset, run_dir, tmp_path / "cache", override))
    assert_clean_error(answer, *needles, prefix=TRAIN_PREFIX)
    assert answer.rc == 1
    assert not run_dir.exists() and not (tmp_path / "cache").exists()


def _start_train_py(tiny_dataset, tmp_path, *extra: str) -> subprocess.Popen:
    argv = [sys.executable, str(REPO / "train.py"),
            *tiny_overrides(tiny_dataset, tmp_path / "run", tmp_path / "cache", *extra)]
    return subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tmp_path,
                            env={**os.environ, "PYTHONPATH": str(REPO), "PYTHONFAULTHANDLER": "1"},
                            start_new_session=True, preexec_fn=like_a_terminal)


@pytest.mark.matrix
def test_matrix_train_ctrl_c(tiny_dataset, tmp_path):
    """Ctrl-C (SIGINT to the terminal's process group: train.py and its two loader workers) while training.
    Measured before: a KeyboardInterrupt traceback. Now one line, exit code 130, the workers silent, the run
    folder's lock released."""
    proc = _start_train_py(tiny_dataset, tmp_path, "data.pipeline=jpeg", "data.num_workers=2", "train.max_steps=10000",
                           "train.val_every=10000", "train.ckpt_every=10000")
    log = tmp_path / "run" / "metrics.jsonl"
    deadline = time.monotonic() + 300
    while not (log.exists() and log.read_text().count("\n") >= 4) and proc.poll() is None:
        assert time.monotonic() < deadline, "training did not start"
        time.sleep(0.05)
    state = f"SIGINT of train.py: {sigint_state(proc.pid)}; of this test process: {sigint_state()}"
    os.killpg(proc.pid, signal.SIGINT)
    try:
        out, err = proc.communicate(timeout=120)
    except subprocess.TimeoutExpired:  # a hang: every thread's stack (faulthandler) and who is still alive
        alive = subprocess.run(["ps", "-o", "pid,stat,etime,cmd", "-g", str(proc.pid)], capture_output=True,
                               text=True).stdout
        os.kill(proc.pid, signal.SIGABRT)
        out, err = proc.communicate(timeout=60)
        os.killpg(proc.pid, signal.SIGKILL)
        raise AssertionError(f"train.py did not end within 120 s of Ctrl-C ({state}); alive:\n{alive}\n{err[-8000:]}")
    assert proc.returncode == 130, err
    assert err.strip().splitlines() == [err.strip()] and err.startswith("train.py: interrupted"), err
    record_answer(err.strip())
    assert "Traceback" not in err + out and "KeyboardInterrupt" not in err + out
    assert not (tmp_path / "run" / ".hupbench.lock").exists()


DROPPED_HANDOFF = """
import os, socket, sys, time
from multiprocessing import resource_sharer
if sys.argv[1] == "worker":
    from hupbench.data.loaders import _worker_setup
    _worker_setup(0)
read_end, _ = os.pipe()
address, _key = resource_sharer.DupFd(read_end)._id  # the fd offered as a loader worker offers a batch's memory
with socket.socket(socket.AF_UNIX) as taker:  # the main process connects and is stopped by Ctrl-C
    taker.connect(address)
    time.sleep(0.5)  # the sharer's challenge arrives unread: closing now resets the connection
time.sleep(0.5)
"""


@pytest.mark.parametrize("process", ["worker", "plain"])
def test_a_loader_worker_is_silent_on_a_handoff_its_main_process_dropped(process):
    """Ctrl-C in the middle of a batch's handoff resets the connection to the worker's resource-sharer thread
    (CI, test_matrix_train_ctrl_c: its ConnectionResetError traceback under the run's one line). A plain
    process prints it; a loader worker, set up by the loader, is silent."""
    answer = subprocess.run([sys.executable, "-c", DROPPED_HANDOFF, process], capture_output=True, text=True,
                            timeout=60, env={**os.environ, "PYTHONPATH": str(REPO)})
    assert answer.returncode == 0, answer.stderr
    if process == "worker":
        assert answer.stderr == ""
    else:
        assert "ConnectionResetError" in answer.stderr


BUGGY_STEP = """
import runpy, sys
import hupbench.training.loop as loop

def loss_terms(*args, **kwargs):
    raise {error}("a deliberate bug in the training step")

loop.loss_terms = loss_terms
sys.argv = sys.argv[1:]
runpy.run_path(sys.argv[0], run_name="__main__")
"""


@pytest.mark.parametrize("error", ["TypeError", "ValueError"])
def test_a_bug_in_the_training_step_keeps_its_traceback(error, tiny_dataset, tmp_path):
    """A bug is not a refusal: train.py shows its traceback instead of one error line (measured before: a
    ValueError from the step was printed as ``train.py: error: ...``)."""
    argv = [sys.executable, "-c", BUGGY_STEP.format(error=error), str(REPO / "train.py"),
            *tiny_overrides(tiny_dataset, tmp_path / "run", tmp_path / "cache")]
    done = subprocess.run(argv, capture_output=True, text=True, cwd=tmp_path, timeout=600,
                          env={**os.environ, "PYTHONPATH": str(REPO)})
    assert done.returncode == 1
    assert "Traceback (most recent call last)" in done.stderr
    assert f"{error}: a deliberate bug in the training step" in done.stderr
    assert TRAIN_PREFIX not in done.stderr
