"""A run's log: ``metrics.jsonl`` (train and val events, written atomically, resumable), TensorBoard
scalars, and what the user sees: lines (also kept in the run folder's ``train.log``) and the progress bar."""

from __future__ import annotations

import json
import time
from pathlib import Path

import torch

from hupbench.core.errors import BadValueError
from hupbench.core.io import write_bytes, writing


class MetricsLog:
    """metrics.jsonl (append, flushed per line) + TensorBoard, on rank 0 only."""

    def __init__(self, run_dir: Path, enabled: bool, tensorboard: bool, resume_step: int | None) -> None:
        self.enabled = enabled
        self.path = run_dir / "metrics.jsonl"
        self.writer = None
        if not enabled:
            return
        with writing(self.path):
            if resume_step is None:
                write_bytes(self.path, b"")
            elif self.path.exists():
                # drop lines a killed run wrote after its last checkpoint: they are about to be redone
                kept = [line for line in self._records() if json.loads(line)["step"] <= resume_step]
                write_bytes(self.path, "".join(line + "\n" for line in kept).encode())
        if tensorboard:
            from torch.utils.tensorboard import SummaryWriter

            with writing(run_dir / "tb") as tb:
                self.writer = SummaryWriter(str(tb), purge_step=resume_step)

    def _records(self) -> list[str]:
        """The file's JSON lines; a last line cut short (a run killed while writing it, a full disk) is dropped."""
        lines = [line for line in self.path.read_text().splitlines() if line.strip()]
        for i, line in enumerate(lines):
            try:
                record = json.loads(line)
            except json.JSONDecodeError:
                record = None
            if not isinstance(record, dict) or not isinstance(record.get("step"), int):
                if i == len(lines) - 1:
                    return lines[:-1]
                raise BadValueError(f"{self.path}: line {i + 1} is not a metrics record (JSON with a 'step'); "
                                 "the log was edited or damaged: move it away to start the log afresh")
        return lines

    def __call__(self, record: dict) -> None:
        if not self.enabled:
            return
        with writing(self.path), open(self.path, "a") as f:
            f.write(json.dumps(record, sort_keys=True, allow_nan=False) + "\n")  # NaN is not JSON
        if self.writer is not None:
            step = record["step"]
            for key, value in record.items():
                if isinstance(value, dict):
                    for sub, v in value.items():
                        if isinstance(v, float):
                            self.writer.add_scalar(f"{record['event']}/{key}_{sub}", v, step)
                elif isinstance(value, float) and key not in ("wall_s", "train_wall_s", "epoch"):
                    self.writer.add_scalar(f"{record['event']}/{key}", value, step)

    def close(self) -> None:
        if self.writer is not None:
            self.writer.close()


#: the run folder's copy of what a run printed, time-stamped, appended to by every invocation
TEXT_LOG = "train.log"


def loss_window(mean: float, first: int, last: int) -> str:
    """The bar's and train.log's loss: the mean over steps ``first`` to ``last``, labelled with them."""
    return f"loss {mean:.4g} ({f'step {last}' if first == last else f'avg of steps {first}-{last}'})"


class LossWindow:
    """The training loss summed on the device over the steps since the last log step (adding waits for
    nothing); :meth:`read` takes its mean where the loop reads numbers anyway.

    Attributes:
        shown: the last mean read, as :func:`loss_window` words it (None before the first read).
    """

    def __init__(self, step: int, device: torch.device) -> None:
        self.total, self.first, self.shown = torch.zeros((), device=device), step + 1, None

    def add(self, loss: torch.Tensor) -> None:
        self.total += loss

    def read(self, step: int) -> None:
        """The mean over the steps from the window's first to ``step`` into :attr:`shown` (waits for the device)."""
        self.shown = loss_window(float(self.total) / (step + 1 - self.first), self.first, step)

    def restart(self, step: int) -> None:
        """An empty window starting after ``step``."""
        self.total.zero_()
        self.first = step + 1


def bar_postfix(epoch: int, epochs: int, lr: float, loss: str | None, val_mm: float | None) -> str:
    """What the progress bar shows after its counts: epoch (1-based), learning rate, the loss window
    (:func:`loss_window`) and the last validation MPJPE (all keypoints, mm)."""
    parts = [f"epoch {epoch}/{epochs}", f"lr {lr:.2e}", loss or "loss -"]
    if val_mm is not None:
        parts.append(f"val {val_mm:.1f} mm")
    return ", ".join(parts)


class RunConsole:
    """What a run tells its user, on rank 0 only: lines through ``log`` (drawn above the progress bar) and,
    time-stamped, in the run folder's train.log (lines said before :meth:`open_file` are kept until it); the
    progress bar, labelled with the run's name, whose description names the phase (validating, saving) while
    one runs."""

    def __init__(self, log, enabled: bool) -> None:
        self.log, self.enabled = log, enabled
        self.path: Path | None = None
        self.pending: list[str] = []
        self.bar = None
        self.name = ""

    def open_file(self, folder: Path) -> None:
        """Append from now on to ``folder/train.log`` (the folder exists and this run holds it)."""
        if not self.enabled:
            return
        self.path = folder / TEXT_LOG
        self._append(self.pending)
        self.pending = []

    def _append(self, lines: list[str]) -> None:
        if not lines:
            return
        with writing(self.path), open(self.path, "a") as f:
            f.write("".join(line + "\n" for line in lines))

    def line(self, text: str, console: bool = True) -> None:
        """``text`` in train.log and, with ``console``, to the user (above the bar while one is drawn)."""
        if not self.enabled:
            return
        stamped = f"{time.strftime('%Y-%m-%d %H:%M:%S')} {text}"
        if self.path is None:
            self.pending.append(stamped)
        else:
            self._append([stamped])
        if console:
            if self.bar is not None:
                from tqdm import tqdm

                with tqdm.external_write_mode():
                    self.log(text)
            else:
                self.log(text)

    def progress_line(self, text: str) -> None:
        """A log step's or validation's line: always in train.log; to the user only without a bar (which
        shows the same numbers)."""
        self.line(text, console=self.bar is None)

    def start_bar(self, name: str, total: int, initial: int) -> None:
        if not self.enabled:
            return
        from tqdm import tqdm

        self.name = name
        self.bar = tqdm(total=total, initial=initial, unit="step", dynamic_ncols=True, desc=name)

    def step(self, postfix: str) -> None:
        """One step done; the bar shows ``postfix`` (:func:`bar_postfix`)."""
        if self.bar is not None:
            self.bar.set_postfix_str(postfix, refresh=False)
            self.bar.update(1)

    def show(self, postfix: str) -> None:
        """The bar shows ``postfix`` now, without a step (a validation's new figure)."""
        if self.bar is not None:
            self.bar.set_postfix_str(postfix)

    def phase(self, what: str | None) -> None:
        """The work after a step that can take a while (``None``: back to training): the bar's description
        while there is a bar, else a line."""
        if not self.enabled:
            return
        if self.bar is not None:
            self.bar.set_description_str(f"{self.name}: {what} ..." if what else self.name)  # redraws the bar
        elif what:
            self.line(f"{what} ...")

    def close_bar(self) -> None:
        if self.bar is not None:
            self.bar.set_description_str(self.name, refresh=False)
            self.bar.close()
            self.bar = None
