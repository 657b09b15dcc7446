"""What the training tests share: a few-step config on the tiny dataset and the answer of train.py to a call."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import traceback
from pathlib import Path

from helpers.cli import CliAnswer

from helpers import REPO, THREADS  # noqa: F401  (REPO re-exported for the training tests)
TRAIN_PREFIX = "train.py: error:"


def tiny_overrides(dataset, run_dir, cache_dir, *extra: str) -> list[str]:
    """The real train config shrunk to 2 steps on the 64 px tiny dataset (validation and a checkpoint at
    step 2, a loss line every step), its frame cache in ``cache_dir``; ``extra`` overrides come last."""
    return ["model=hopenet_r10_128", f"data.root={dataset}", f"run_dir={run_dir}", f"data.cache_dir={cache_dir}",
            "data.reader.input_size=64", "data.batch_size=4", "data.num_workers=0", "data.val_frames=8",
            "train.max_steps=2", "train.val_every=2", "train.ckpt_every=2", "train.log_every=1", "train.progress=false",
            "train.tensorboard=false", f"threads={THREADS}", "precision=fp32", *extra]


def tiny_cfg(dataset, run_dir, cache_dir, *extra: str):
    """:func:`tiny_overrides` composed."""
    from hupbench.config import compose

    return compose("train", tiny_overrides(dataset, run_dir, cache_dir, *extra))


class _RanOn(BaseException):
    """Raised by the alarm in :func:`answer_of`; a BaseException so that no entry point answers it."""


def answer_of(capsys, call, limit_s: int = 300) -> CliAnswer:
    """What a command line would have shown for ``call()``: its exit code and output; an exception that the
    entry point does not answer becomes the traceback the user would see, and a call still running after
    ``limit_s`` (bad input accepted: e.g. 10^12 training steps) is stopped and counted as exit code 0."""

    def ran_on(*_):
        raise _RanOn()

    capsys.readouterr()
    previous = signal.signal(signal.SIGALRM, ran_on)
    signal.alarm(limit_s)
    try:
        call()
        rc = 0
    except SystemExit as exc:
        rc = exc.code if isinstance(exc.code, int) else 1
    except _RanOn:
        captured = capsys.readouterr()
        return CliAnswer(0, captured.out, captured.err + f"\n(still running after {limit_s} s: the input was accepted)")
    except Exception:  # noqa: BLE001  (the point: anything that escapes is a traceback to the user)
        captured = capsys.readouterr()
        return CliAnswer(1, captured.out, captured.err + traceback.format_exc())
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)
    captured = capsys.readouterr()
    return CliAnswer(rc, captured.out, captured.err)


def train_answer(capsys, cfg, limit_s: int = 120) -> CliAnswer:
    """train.py's answer to a composed config: its Hydra job (:func:`hupbench.verbs.train.task`) in this
    process, its end answered as train.py answers it (:func:`hupbench.error_lines.answered`)."""
    from hupbench.error_lines import answered
    from hupbench.verbs.train import task

    def job() -> int:
        task(cfg)
        return 0

    return answer_of(capsys, lambda: sys.exit(answered("train.py", job)), limit_s=limit_s)


def train_py(*argv: str, cwd: Path, timeout: float = 600) -> CliAnswer:
    """``python train.py ARGV`` in a fresh process."""
    done = subprocess.run([sys.executable, str(REPO / "train.py"), *argv], capture_output=True, text=True,
                          cwd=cwd, timeout=timeout, env={**os.environ, "PYTHONPATH": str(REPO)})
    return CliAnswer(done.returncode, done.stdout, done.stderr)
