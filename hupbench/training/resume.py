"""Which checkpoint a training run continues (``train.resume``), checked to be of the run's config and dataset,
and what a finished run answers when it is started again.

``train.resume``: ``auto`` continues ``RUN/checkpoints/last.pt`` when it exists, ``never`` refuses a run folder
that holds one, a path continues that checkpoint. A checkpoint of another config (but the keys of
:data:`RESUME_FREE_KEYS`) or of another dataset (its manifest's sha256) is refused, the refusal naming the
differences and the override that starts a new run beside this one instead.
"""

from __future__ import annotations

import json
import shlex
from pathlib import Path

from hupbench.checkpoint import Checkpoint
from hupbench.core.contract import MANIFEST
from hupbench.core.errors import BadValueError, MissingFileError
from hupbench.core.io import file_sha256
from hupbench.training.run_config import TrainRun

#: config differences a refused resume lists (a checkpoint of another project differs everywhere)
MAX_DIFFS_SHOWN = 8
#: config keys that may differ between a run and the run it resumes
RESUME_FREE_KEYS = ("train.resume", "train.progress", "train.stop_after", "run_dir", "threads", "data.num_workers",
                    "data.cache_dir", "label")
#: config keys added after checkpoints were written, with the value that does what a run did before the key existed:
#: a checkpoint without the key is of the same config as a run with that value (the depth camera issue's reader keys:
#: the depth the dataset stores, no fresh noise; the segmentation loss's weight, which a model without the head ignores)
ADDED_KEYS = {"data.reader.depth_sensor": "dataset", "data.reader.fresh_sensor_noise": False, "loss.w_seg": 1.0}


def resume_checkpoint(run: TrainRun) -> Checkpoint | None:
    """The checkpoint ``run`` continues in its run folder (None: a new run), checked to be of its config and
    dataset."""
    folder = run.folder
    mode, last = run.train.resume, folder / "checkpoints" / "last.pt"
    if mode in (None, "never") and last.exists():
        raise BadValueError(f"{folder} already holds a checkpoint ({last}); use train.resume=auto to continue it, "
                            f"or {new_run_override(run)} for a new run")
    if mode in (None, "never") or (mode == "auto" and not last.exists()):
        return None
    path = last if mode == "auto" else Path(mode)
    if not path.is_file():
        raise MissingFileError(f"train.resume={mode}: checkpoint {path} does not exist")
    checkpoint = Checkpoint.read(path)
    diff = _config_diff(checkpoint.config, run.config)
    if diff:
        shown = "; ".join(diff[:MAX_DIFFS_SHOWN]) + (f"; and {len(diff) - MAX_DIFFS_SHOWN} more"
                                                     if len(diff) > MAX_DIFFS_SHOWN else "")
        fix = (f"to train with the new values start a new run, {new_run_override(run)}; to continue this run, "
               "give it the values it was trained with" if mode == "auto" else
               "resume it with the values it was trained with, or leave train.resume out to start afresh")
        raise BadValueError(f"checkpoint {path} was trained with another config; differences: {shown}; {fix}")
    manifest = Path(run.data.root) / MANIFEST
    trained_on, now = (checkpoint.dataset or {}).get("manifest_sha256"), file_sha256(manifest)
    if trained_on != now:
        raise BadValueError(f"checkpoint {path} was trained on another dataset: manifest sha256 {trained_on} "
                            f"({(checkpoint.dataset or {}).get('path')}), but {manifest} has {now}; "
                            f"resume on the dataset it was trained on, or start a new run: {new_run_override(run)}")
    return checkpoint


def finished_run(folder: Path, resumed: Checkpoint | None) -> dict | None:
    """The summary of the run in ``folder`` when it already finished at ``resumed``, its last checkpoint (whose
    config and dataset are this run's), with the paths of where it is now and "already_complete"; else None."""
    path = folder / "summary.json"
    if resumed is None or resumed.path != folder / "checkpoints" / "last.pt" or not path.is_file():
        return None
    try:
        summary = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise BadValueError(f"{path} is not JSON ({exc.msg}, line {exc.lineno}): the run's summary was damaged; "
                            "move it away and the same command writes it again") from exc
    if not summary.get("complete") or summary.get("steps") != resumed.step:
        return None
    return {**summary, "run_dir": str(folder), "checkpoint": str(folder / "checkpoints" / "last.pt"),
            "best_checkpoint": str(folder / "checkpoints" / "best.pt"), "already_complete": True}


def new_run_override(run: TrainRun) -> str:
    """The override that starts a new run beside this one: ``run_name=NAME_K`` with the first K >= 2 whose folder
    does not exist, or ``run_dir=FOLDER_K`` when run_dir names a folder outside the run name's."""
    if run.run_dir is None or run.run_name in Path(run.run_dir).parts:
        key, base = "run_name", Path(run.out_root) / run.run_name
    else:
        key, base = "run_dir", Path(run.run_dir)
    k = 2
    while Path(f"{base}_{k}").exists():
        k += 1
    return f"{key}={shlex.quote((run.run_name if key == 'run_name' else str(base)) + f'_{k}')}"


def _config_diff(a: dict, b: dict, prefix: str = "") -> list[str]:
    """``key: checkpoint A, now B`` for every dotted key whose value differs, but :data:`RESUME_FREE_KEYS` and a key
    of :data:`ADDED_KEYS` absent from the checkpoint's config and at its value now."""
    out = []
    for key in sorted(set(a) | set(b)):
        path = f"{prefix}{key}"
        if path in RESUME_FREE_KEYS:
            continue
        va, vb = a.get(key, "<absent>"), b.get(key, "<absent>")
        if key not in a and path in ADDED_KEYS and vb == ADDED_KEYS[path]:
            continue
        if isinstance(va, dict) and isinstance(vb, dict):
            out += _config_diff(va, vb, path + ".")
        elif va != vb:
            out.append(f"{path}: checkpoint {va!r}, now {vb!r}")
    return out
