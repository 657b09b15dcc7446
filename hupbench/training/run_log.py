"""A run's log: ``metrics.jsonl`` (train and val events, written atomically, resumable), TensorBoard
scalars and progress lines."""

from __future__ import annotations

import errno
import json
from pathlib import Path

from datagen.io import DiskFullError, write_bytes
from datagen.errors import BadValueError


class MetricsLog:
    """metrics.jsonl (append, flushed per line) + TensorBoard, on rank 0 only."""

    def __init__(self, run_dir: Path, enabled: bool, tensorboard: bool, resume_step: int | None) -> None:
        self.enabled = enabled
        self.path = run_dir / "metrics.jsonl"
        self.writer = None
        if not enabled:
            return
        if resume_step is None:
            write_bytes(self.path, b"")
        elif self.path.exists():
            # drop lines a killed run wrote after its last checkpoint: they are about to be redone
            kept = [line for line in self._records() if json.loads(line)["step"] <= resume_step]
            write_bytes(self.path, "".join(line + "\n" for line in kept).encode())
        if tensorboard:
            from torch.utils.tensorboard import SummaryWriter

            self.writer = SummaryWriter(str(run_dir / "tb"), purge_step=resume_step)

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
        try:
            with open(self.path, "a") as f:
                f.write(json.dumps(record, sort_keys=True, allow_nan=False) + "\n")  # NaN is not JSON
        except OSError as exc:
            raise (DiskFullError(self.path) if exc.errno == errno.ENOSPC else exc) from exc
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
