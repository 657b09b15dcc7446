"""``hupbench leaderboard``: ``README.md`` (:mod:`~hupbench.evaluation.leaderboard_readme`) and two plots
(:mod:`~hupbench.evaluation.leaderboard_plots`), rebuilt from ``leaderboard/results/*.json``, the depth sensor
table's ``leaderboard/robustness/*.json`` (:mod:`~hupbench.evaluation.leaderboard_robustness`) and the
training logs under ``logs/``.

A broken input is an error naming the file, and nothing is rewritten: a row that silently dropped out of
the table would be a wrong leaderboard nobody notices. The three outputs are renamed into place together,
so a full disk or a kill leaves the old set or the new one. The same files give the same bytes: rows are
sorted, numbers formatted explicitly, nothing reads the clock.
"""

from __future__ import annotations

import contextlib
from pathlib import Path

from hupbench.core.errors import BadValueError, MissingFileError
from hupbench.core.input_checks import check_int, is_number
from hupbench.core.io import atomic_output, check_writable, clean_stale_tmp, parse_json, read_bytes
from hupbench.evaluation.leaderboard_plots import plot_latency, plot_training
from hupbench.evaluation.leaderboard_readme import LATENCY_PLOT, TRAINING_PLOT, render_readme
from hupbench.evaluation.leaderboard_robustness import ROBUSTNESS, check_robustness
from hupbench.evaluation.leaderboard_table import sort_key, with_intervals
from hupbench.evaluation.results import LIMITS, load_results

README = "README.md"
#: the largest training time a log may state, seconds (about three years)
MAX_TRAIN_WALL_S = 1e8


def load_rows(results_dir: Path) -> list[dict]:
    """Every ``<run_name>.json`` of a folder (at least one), validated, sorted by
    :func:`~hupbench.evaluation.leaderboard_table.sort_key`: each must be a test-split result named by its run
    name, and a measured row must name its command. Each row carries its intervals
    (:func:`~hupbench.evaluation.leaderboard_table.with_intervals`: recorded, or recomputed from its grasp
    breakdown)."""
    assert results_dir.is_dir(), results_dir
    paths = sorted(results_dir.glob("*.json"))
    if not paths:
        raise BadValueError(f"no results files (*.json) in {results_dir}")
    by_folded_name: dict[str, Path] = {}
    for path in paths:
        twin = by_folded_name.setdefault(path.stem.casefold(), path)
        if twin != path:
            raise BadValueError(f"{twin} and {path}: run names must differ in more than letter case (the two files "
                                "collide on case-insensitive file systems such as macOS's and Windows')")
    rows = []
    for path in paths:
        row = load_results(path)
        if row["run_name"] != path.stem:
            raise BadValueError(f"{path}: results['run_name'] must equal the file stem {path.stem!r}, "
                                f"got {row['run_name']!r} (rename the file to {row['run_name']}.json, or rerun "
                                f"hupbench eval with --out {path})")
        if row["dataset"]["split"] != "test":
            raise BadValueError(f"{path}: the leaderboard compares test-split results, "
                                f"got results['dataset']['split'] = {row['dataset']['split']!r} (rerun hupbench "
                                f"eval with --split test --out {path}, or move the file out of {results_dir})")
        if row["kind"] == "measured" and row["training"]["command"] is None:
            raise BadValueError(f"{path}: a measured row must name the command that reproduces it in "
                                "results['training']['command'], got None: rerun hupbench eval MODEL DATASET "
                                f"--out {path} --training-command 'COMMAND THAT TRAINED IT' (as "
                                f"scripts/paper_protocol.sh does), or move the file out of {results_dir} if it "
                                "is not a leaderboard row")
        rows.append(with_intervals(row))
    return sorted(rows, key=sort_key)


def read_validation_curve(path: Path, cited_by: str | None = None) -> list[tuple[float, float]]:
    """``(train_wall_s, val_mpjpe_all_mm)`` of the ``"event": "val"`` lines of a training run's ``metrics.jsonl``,
    in file order.

    Every line is checked: a JSON object (read strictly, :func:`~hupbench.core.io.parse_json`) whose
    ``step`` is a whole number >= 0 and larger than the step of the same event's line before it (a log that two
    trainings appended to, or an edited one, fails here); a validation line's time (<= ``MAX_TRAIN_WALL_S``) and
    error (<= ``LIMITS["mm"]``) are finite numbers >= 0. ``cited_by`` (a results file) starts every error line.
    """
    where = str(path) if cited_by is None else f"{cited_by}: training log {path}"
    data = read_bytes(path, "training log" if cited_by is None else f"{cited_by}: training log")
    curve = []
    last: dict = {}  # event -> (step, line)
    for lineno, line in enumerate(data.splitlines(), start=1):
        if not line.strip():
            continue
        record = parse_json(line, f"{where}:{lineno}")
        if not isinstance(record, dict):
            raise BadValueError(f"{where}:{lineno}: expected a JSON object, got {type(record).__name__}")
        event = record.get("event")
        step = check_int(record.get("step"), f"{where}:{lineno}: 'step'", low=0)
        previous, first = last.get(event, (-1, None))
        if step <= previous:
            raise BadValueError(f"{where}:{lineno}: {event!r} step {step} "
                                + ("is logged twice" if step == previous else f"comes after step {previous}")
                                + f" (lines {first} and {lineno}): two trainings wrote to this log, or it was "
                                "edited; keep one run's lines in order")
        last[event] = (step, lineno)
        if event != "val":
            continue
        mpjpe = record.get("val_mpjpe_mm")
        values = {"train_wall_s": (record.get("train_wall_s"), MAX_TRAIN_WALL_S),
                  "val_mpjpe_mm['all']": (mpjpe.get("all") if isinstance(mpjpe, dict) else None, LIMITS["mm"])}
        for name, (value, high) in values.items():
            if not (is_number(value) and 0 <= value <= high):
                raise BadValueError(f"{where}:{lineno}: validation line needs {name} as a finite number from 0 to "
                                    f"{high:g}, got {value!r}")
        curve.append((float(values["train_wall_s"][0]), float(values["val_mpjpe_mm['all']"][0])))
    if not curve:
        raise BadValueError(f"{where}: no validation lines ({{\"event\": \"val\", ...}}) to plot")
    return curve


def _write_together(root: Path, files: dict[str, bytes]) -> list[Path]:
    """Write every file under its temporary name, then rename them all: a failure (a full disk) or a
    kill before the renames leaves the old set whole; the renames themselves need no space."""
    try:
        with contextlib.ExitStack() as stack:
            for name, data in files.items():
                stack.enter_context(atomic_output(root / name)).write_bytes(data)
    except OSError as exc:
        # every enclosing atomic_output explains the error again with its own file's name: the innermost
        # explanation names the file whose write failed (an error it did not explain is its own cause)
        failed = exc
        while isinstance(failed.__cause__, type(exc)) and failed.__cause__ is not failed:
            failed = failed.__cause__
        raise failed from None
    return [root / name for name in files]


def run_leaderboard(dir: str | Path = "leaderboard") -> dict:
    """Rebuild README.md and both plots in ``dir`` from ``dir/results/*.json`` (and ``dir/logs/``).

    Returns:
        {"rows": int, "measured": int, "reported": int, "readme": Path, "plots": [Path, Path]}.
    """
    root = check_writable(dir, "leaderboard folder (--dir)")
    if not (root / "results").is_dir():
        raise MissingFileError(f"leaderboard folder (--dir) {root} does not exist" if not root.exists() else
                               f"{root} has no results/ folder (results/<run_name>.json files); is --dir the "
                               "leaderboard folder?")
    for name in (README, LATENCY_PLOT, TRAINING_PLOT):  # a folder in an output's place would stop the renames
        check_writable(root / name, "leaderboard file", file=True)
    clean_stale_tmp(root, recursive=False)
    rows = load_rows(root / "results")
    robust = []
    if (root / ROBUSTNESS).is_dir() and any((root / ROBUSTNESS).glob("*.json")):
        robust = load_rows(root / ROBUSTNESS)
        check_robustness(robust, rows, root / ROBUSTNESS)
    curves = [(row, read_validation_curve(root / row["training"]["log"], f"results/{row['run_name']}.json"))
              for row in rows if row["kind"] == "measured" and row["training"]["log"] is not None]
    # render everything before writing anything, so a bad log leaves the old files in place
    files = {README: render_readme(rows, robust).encode("utf-8"), LATENCY_PLOT: plot_latency(rows),
             TRAINING_PLOT: plot_training(rows, curves)}
    paths = _write_together(root, files)
    measured = sum(row["kind"] == "measured" for row in rows)
    return {"rows": len(rows), "measured": measured, "reported": len(rows) - measured, "readme": paths[0],
            "plots": paths[1:]}
