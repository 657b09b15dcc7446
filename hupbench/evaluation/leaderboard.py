"""``hupbench leaderboard``: ``README.md`` (a table per track, the notes and each row's details) and two plots
(error against latency and against training time), rebuilt from ``leaderboard/results/*.json`` and the
training logs under ``logs/``. (layout: long because the README and both plots share the row helpers.)

A broken input is an error naming the file, and nothing is rewritten: a row that silently dropped out of
the table would be a wrong leaderboard nobody notices. The three outputs are renamed into place together,
so a full disk or a kill leaves the old set or the new one. The same files give the same bytes: rows are
sorted, numbers formatted explicitly, nothing reads the clock, and the plots use matplotlib's defaults at a
fixed size with a PNG ``Software`` tag naming only the versions that decide the pixels.

Convention: errors in mm, latency in ms per image at batch 1, times in seconds inside and minutes or hours
on the plot axes.
"""

from __future__ import annotations

import contextlib
import io
import json
import math
import re
from collections.abc import Sequence
from pathlib import Path

from hupbench.core.io import atomic_output, check_writable, clean_stale_tmp
from hupbench.core.contract import TRACKS, UNSEEN_GRASPS
from hupbench.datagen.dataset.floors import FLOOR_KINDS
from hupbench.core.keypoints import NUM_CORNERS, NUM_HAND
from hupbench.evaluation.results import FLOOR_NAMES, SCHEMA_VERSION, load_results
from hupbench.core.errors import BadValueError, MissingFileError

README = "README.md"
LATENCY_PLOT = "mpjpe_vs_latency.png"
TRAINING_PLOT = "val_mpjpe_vs_training_time.png"
FIGSIZE_IN = (9.0, 6.0)
DPI = 100  # FIGSIZE_IN x DPI = 900 x 600 px
MISSING = "—"
# "all" that differs from the keypoint-weighted mean by more than the two-decimal rounding of the inputs
WEIGHTED_MEAN_TOLERANCE_MM = 0.01
#: the track of rows whose results name none (the paper's, and datasets made before tracks)
PAPER_TRACK = UNSEEN_GRASPS
#: each track's table heading and what it holds out
TRACK_TITLES = {
    "unseen_grasps": ("Unseen grasps", "the test split's grasps are not in the training split (the HUP-3D paper's "
                      "protocol). Rows whose results name no track (the paper's, and results of datasets made "
                      "before tracks) belong here."),
    "unseen_views": ("Unseen views", "every grasp is in the training split; the test split's camera views of the "
                     "sphere are not."),
}


# ----------------------------------------------------------------------------- rows

def load_rows(results_dir: str | Path) -> list[dict]:
    """Every ``<run_name>.json`` of a folder (at least one), validated, sorted by :func:`sort_key`: each
    must be a test-split result named by its run name, and a measured row must name its command."""
    results_dir = Path(results_dir)
    if not results_dir.is_dir():
        raise MissingFileError(f"results folder not found: {results_dir}")
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
        rows.append(row)
    return sorted(rows, key=sort_key)


def sort_key(row: dict) -> tuple[float, str]:
    """Table order: MPJPE all ascending, then run name (unique), so that ties are deterministic."""
    return (row["metrics"]["mpjpe_mm"]["all"], row["run_name"])


def inference_latency_ms(row: dict) -> tuple[float | None, str | None]:
    """``(ms per image at batch 1, "ONNX Runtime")`` where measured, else PyTorch's, else ``(None, None)``."""
    latency = row["latency_ms_per_image"]
    if latency["onnxruntime"]["batch1"] is not None:
        return latency["onnxruntime"]["batch1"], "ONNX Runtime"
    if latency["pytorch"]["batch1"] is not None:
        return latency["pytorch"]["batch1"], "PyTorch"
    return None, None


def pareto_front(points: Sequence[tuple[float, float]]) -> list[int]:
    """Indices of the ``(x, y)`` points no other point beats (no worse on both, better on one; lower is
    better), ordered by x, then y, then index; identical points do not dominate each other."""
    front = []
    for i, (xi, yi) in enumerate(points):
        dominated = any(xj <= xi and yj <= yi and (xj < xi or yj < yi) for j, (xj, yj) in enumerate(points) if j != i)
        if not dominated:
            front.append(i)
    return sorted(front, key=lambda i: (points[i][0], points[i][1], i))


def read_validation_curve(path: str | Path) -> list[tuple[float, float]]:
    """``(train_wall_s, val_mpjpe_all_mm)`` of the ``"event": "val"`` lines of a training run's ``metrics.jsonl``,
    in file order. Every line is checked: an event's step logged twice means two trainings appended to one log
    (a resumed run drops the lines after its checkpoint before it logs again)."""
    path = Path(path)
    if not path.is_file():
        raise MissingFileError(f"training log not found: {path}")
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise BadValueError(f"{path}: not a UTF-8 text file (byte {exc.start}): not a training log") from None
    curve = []
    seen: dict[tuple, int] = {}  # (event, step) -> line
    for lineno, line in enumerate(text.splitlines(), start=1):
        if not line.strip():
            continue
        try:
            record = json.loads(line)
        except json.JSONDecodeError as exc:
            raise BadValueError(f"{path}:{lineno}: not a JSON line (a truncated or damaged copy?): {exc}") from None
        if not isinstance(record, dict):
            raise BadValueError(f"{path}:{lineno}: expected a JSON object, got {type(record).__name__}")
        step = record.get("step")
        if isinstance(step, int) and not isinstance(step, bool):
            first = seen.setdefault((record.get("event"), step), lineno)
            if first != lineno:
                raise BadValueError(f"{path}:{lineno}: {record.get('event')!r} step {step} is logged twice (lines {first} "
                                    f"and {lineno}): two trainings wrote to this log; keep one run's lines")
        if record.get("event") != "val":
            continue
        seconds = record.get("train_wall_s")
        mpjpe = record.get("val_mpjpe_mm")
        mpjpe_all = mpjpe.get("all") if isinstance(mpjpe, dict) else None
        for name, value in (("train_wall_s", seconds), ("val_mpjpe_mm['all']", mpjpe_all)):
            if not _finite_non_negative(value):
                raise BadValueError(f"{path}:{lineno}: validation line needs {name} as a finite number >= 0, "
                                    f"got {value!r}")
        curve.append((float(seconds), float(mpjpe_all)))
    if not curve:
        raise BadValueError(f"{path}: no validation lines ({{\"event\": \"val\", ...}}) to plot")
    return curve


def _finite_non_negative(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value) and value >= 0


# ----------------------------------------------------------------------------- table

def _number(value: float | None, digits: int = 2) -> str:
    return MISSING if value is None else f"{value:.{digits}f}"


def format_duration(seconds: float | None) -> str:
    """``"42 s"``, ``"35 min"`` or ``"2.5 h"``; the missing mark for None."""
    if seconds is None:
        return MISSING
    if seconds < 60:
        return f"{seconds:.0f} s"
    if seconds < 3600:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"


def _cell(text: str) -> str:
    # a pipe would end the cell and a newline the row
    return " ".join(str(text).split()).replace("|", "\\|")


def _code(text: str | None) -> str:
    return MISSING if text is None else f"`{_cell(text)}`"


TABLE_COLUMNS = ("model", "kind", "test data", "input (px)", "params (M)", "MPJPE all (mm)", "MPJPE hand (mm)",
                 "MPJPE probe (mm)", "split floor hand / probe / all (mm)", "MPJPE probe, half-turn symmetric (mm)",
                 "PA-MPJPE hand (mm)", "AUC 0-50 mm", "spread ratio x / y / z", "training (time, hardware)",
                 "latency ONNX Runtime (ms/image, batch 1)", "latency PyTorch (ms/image, batch 1)", "command")
#: the axes and threshold of the spread ratios (hupbench.metrics.SPREAD_AXES, SPREAD_RATIO_WARN), kept
#: here as plain values so that the leaderboard does not import torch
SPREAD_AXES = ("x", "y", "z")
SPREAD_RATIO_WARN = 0.5


# numbers right-aligned, text left
_ALIGN = {c: "---" if c in ("model", "kind", "test data", "training (time, hardware)", "command") else "---:"
          for c in TABLE_COLUMNS}


def triplet_cell(mm: dict | None) -> str:
    """``"12.00 / 30.00 / 17.00"``: hand / probe / all (mm) of a {"hand", "probe", "all"} dict (None: missing mark)."""
    if mm is None:
        return MISSING
    return " / ".join(_number(mm[part]) for part in ("hand", "probe", "all"))


def row_track(row: dict) -> str:
    """The track whose table holds the row: its results' track, else ``PAPER_TRACK``."""
    return row["track"] or PAPER_TRACK


def plot_label(row: dict) -> str:
    """The row's model label in the plots, with its track when it is not the paper's."""
    track = row_track(row)
    return row["model"]["label"] + ("" if track == PAPER_TRACK else f", {TRACK_TITLES[track][0].lower()}")


def spread_cell(row: dict) -> str:
    """``"0.02 / 0.01 / 0.95"`` (x / y / z spread ratios), a missing mark per unknown axis, one mark if all are."""
    ratios = row["metrics"]["spread_ratio"]
    if all(ratios[a] is None for a in SPREAD_AXES):
        return MISSING
    return " / ".join(_number(ratios[a]) for a in SPREAD_AXES)


def table_row(row: dict) -> list[str]:
    """The cells of a validated results row, one per :data:`TABLE_COLUMNS` (two decimals for mm and ms,
    three for AUC)."""
    model, metrics, training = row["model"], row["metrics"], row["training"]
    mpjpe = metrics["mpjpe_mm"]
    params = None if model["parameters"] is None else model["parameters"] / 1e6
    if training["wall_s"] is None and training["hardware"] is None:
        train_cell = MISSING
    else:
        train_cell = format_duration(training["wall_s"]) + (f", {training['hardware']}" if training["hardware"] else "")
    latency = row["latency_ms_per_image"]
    return [
        _cell(model["label"]),
        "measured" if row["kind"] == "measured" else "reported in paper",
        _cell(row["dataset"]["name"]),
        MISSING if model["input_size"] is None else str(model["input_size"]),
        _number(params),
        _number(mpjpe["all"]),
        _number(mpjpe["hand"]),
        _number(mpjpe["probe"]),
        triplet_cell(None if row["split_floor"] is None else row["split_floor"]["floor_mm"]),
        _number(metrics["probe_symmetric_mpjpe_mm"]),
        _number(metrics["pa_mpjpe_hand_mm"]),
        _number(metrics["pck_auc_0_50mm"], 3),
        spread_cell(row),
        _cell(train_cell),
        _number(latency["onnxruntime"]["batch1"]),
        _number(latency["pytorch"]["batch1"]),
        _code(training["command"]),
    ]


def keypoint_weighted_all_mm(row: dict) -> float | None:
    """(21 x hand + 8 x probe) / 29: the mean over all 29 keypoints implied by the hand and probe numbers."""
    mpjpe = row["metrics"]["mpjpe_mm"]
    if mpjpe["hand"] is None or mpjpe["probe"] is None:
        return None
    return (NUM_HAND * mpjpe["hand"] + NUM_CORNERS * mpjpe["probe"]) / (NUM_HAND + NUM_CORNERS)


def _details(row: dict) -> list[str]:
    model, dataset, training = row["model"], row["dataset"], row["training"]
    mpjpe = row["metrics"]["mpjpe_mm"]
    lines = [f"### {_cell(model['label'])} (`{row['run_name']}`)", ""]
    kind = "measured here" if row["kind"] == "measured" else "reported in a paper, not measured here"
    lines.append(f"- kind: {kind}; results file [`results/{row['run_name']}.json`](results/{row['run_name']}.json)")
    data = f"- test data: {_cell(dataset['name'])}, split `{dataset['split']}`"
    if dataset["frames"] is not None:
        data += f", {dataset['frames']} frames"
    if dataset["manifest_sha256"] is not None:
        data += f", manifest sha256 `{dataset['manifest_sha256'][:12]}`"
    lines.append(data)
    lines.append(f"- MPJPE all {mpjpe['all']:.2f} mm, averaged: {_cell(mpjpe['all_averaging'])}")
    weighted = keypoint_weighted_all_mm(row)
    if weighted is not None:
        check = (f"- keypoint-weighted mean of hand and probe: (21 × {mpjpe['hand']:.2f} + 8 × {mpjpe['probe']:.2f})"
                 f" / 29 = {weighted:.2f} mm")
        if abs(weighted - mpjpe["all"]) > WEIGHTED_MEAN_TOLERANCE_MM:
            check += f", which is not the row's all ({mpjpe['all']:.2f} mm)"
        lines.append(check)
    symmetric = row["metrics"]["probe_symmetric_mpjpe_mm"]
    if symmetric is not None:
        lines.append(f"- probe MPJPE with the corners matched under the half turn about the probe's long axis where "
                     f"closer: {symmetric:.2f} mm (plain: {_number(mpjpe['probe'])} mm)")
    ratios = row["metrics"]["spread_ratio"]
    if any(ratios[a] is not None for a in SPREAD_AXES):
        low = [a for a in SPREAD_AXES if ratios[a] is not None and ratios[a] < SPREAD_RATIO_WARN]
        line = f"- spread ratio of predicted to true 3D keypoints across the test frames, x / y / z: {spread_cell(row)}"
        if low:
            line += (f"; below {SPREAD_RATIO_WARN} on {', '.join(low)}: the predictions barely vary along "
                     f"{'that axis' if len(low) == 1 else 'those axes'} (collapsed)")
        lines.append(line)
    if row["metrics"]["root_relative_hand_mpjpe_mm"] is not None or row["metrics"]["pixel_error_px"] is not None:
        middle = row["metrics"].get("middle_mcp_relative_hand_mpjpe_mm")  # absent in files written before it
        lines.append(f"- root-relative hand MPJPE {_number(row['metrics']['root_relative_hand_mpjpe_mm'])} mm"
                     + ("" if middle is None else f" (relative to the middle-finger MCP: {middle:.2f} mm)")
                     + f"; 2D error {_number(row['metrics']['pixel_error_px'])} px")
    if model["flops"] is not None or model["format"] is not None:
        flops = MISSING if model["flops"] is None else f"{model['flops'] / 1e9:.2f}"
        lines.append(f"- GFLOPs per image {flops}; evaluated from {model['format'] or MISSING}")
    latency = row["latency_ms_per_image"]
    if any(v is not None for runtime in latency.values() for v in runtime.values()):
        lines.append(f"- latency ms/image, batch 1 / batch 32: ONNX Runtime {_number(latency['onnxruntime']['batch1'])}"
                     f" / {_number(latency['onnxruntime']['batch32'])}, PyTorch {_number(latency['pytorch']['batch1'])}"
                     f" / {_number(latency['pytorch']['batch32'])}; device: {_cell(row['device'] or MISSING)}")
    if training["samples_seen"] is not None or training["epochs"] is not None:
        lines.append(f"- training: {training['samples_seen'] if training['samples_seen'] is not None else MISSING}"
                     f" samples, {_number(training['epochs'], 1)} epochs")
    if training["command"] is not None:
        lines.append(f"- reproduce: `{_cell(training['command'])}`")
    if training["log"] is not None:
        lines.append(f"- training log: [`{training['log']}`]({training['log']})")
    if row["git_commit"] is not None:
        lines.append(f"- git commit `{row['git_commit']}`" + (f", evaluated {row['created_utc']}" if row["created_utc"] else ""))
    if row["source"] is not None:
        lines.append(f"- source: {_cell(row['source'])}")
    return lines + [""] + _grasp_details(row)


def _natural_key(label: str) -> list:
    """Sort key that orders the numbers inside labels by value: "theta_vol_z=45" before "theta_vol_z=180"."""
    return [(0, float(part), "") if i % 2 else (1, 0.0, part)
            for i, part in enumerate(re.split(r"(-?\d+(?:\.\d+)?)", label))]


GRASP_COLUMNS = ("grasp", "Theta_Vol x, y, z (deg)", "frames", "MPJPE hand (mm)", "MPJPE probe (mm)", "MPJPE all (mm)",
                 "floor hand / probe / all (mm)", "nearest training grasp")


def grasp_rows(row: dict) -> list[list[str]]:
    """The cells (per :data:`GRASP_COLUMNS`) of each grasp that a results row's grasp breakdown or its
    floor names, in increasing id."""
    measured = row["breakdowns"].get("grasp", {})
    floors = {} if row["split_floor"] is None else row["split_floor"]["per_grasp"]
    theta_vol = row["dataset"]["grasp_theta_vol_deg"] or {}
    out = []
    for grasp in sorted(set(measured) | set(floors), key=int):
        bucket, floor = measured.get(grasp), floors.get(grasp)
        mpjpe = {} if bucket is None else bucket["mpjpe_mm"]
        angles = theta_vol.get(grasp)
        nearest = None if floor is None else floor["nearest_train_grasp_id"]
        out.append([grasp, MISSING if angles is None else ", ".join(f"{a:g}" for a in angles),
                    MISSING if bucket is None else str(bucket["frames"]),
                    _number(mpjpe.get("hand")), _number(mpjpe.get("probe")), _number(mpjpe.get("all")),
                    triplet_cell(None if floor is None else floor["floor_mm"]),
                    MISSING if nearest is None else str(nearest)])
    return out


def _grasp_details(row: dict) -> list[str]:
    """The row's per-grasp table and its MPJPE by probe orientation, or a line saying they are not recorded."""
    table = grasp_rows(row)
    if not table:
        if row["kind"] != "measured":
            return []
        return [f"Per grasp: {MISSING} (the results file records no grasp breakdown: it was written before results "
                f"schema version {SCHEMA_VERSION}; `hupbench eval` adds it).", ""]
    floor = row["split_floor"]
    lines = ["Per test grasp" + ("" if floor is None else f" (floor: {FLOOR_NAMES[floor['floor_kind']]})") + ":", ""]
    lines += _table(GRASP_COLUMNS, ["---:"] * len(GRASP_COLUMNS), table)
    by_theta = row["breakdowns"].get("theta_vol")
    if by_theta:
        shown = "; ".join(f"{_cell(label)} {triplet_cell(by_theta[label]['mpjpe_mm'])} ({by_theta[label]['frames']} "
                          f"frames)" for label in sorted(by_theta, key=_natural_key))
        lines += [f"MPJPE by probe orientation Theta_Vol, hand / probe / all (mm): {shown}.", ""]
    return lines


def _floor_lines(rows: list[dict]) -> list[str]:
    """The test split's floor of each dataset the rows were evaluated on, named by what it is."""
    floors: dict[str, dict[tuple, dict]] = {}  # floor kind -> (dataset name, manifest sha256) -> floor_mm
    for row in rows:
        if row["split_floor"] is not None:
            key = (row["dataset"]["name"], row["dataset"]["manifest_sha256"] or "")
            floors.setdefault(row["split_floor"]["floor_kind"], {}).setdefault(key, row["split_floor"]["floor_mm"])
    if not floors:
        return [f"Split floor: {MISSING} for every row here (results files written before results schema version "
                f"{SCHEMA_VERSION}, datasets made before split floors, and the paper record none).", ""]
    lines = []
    for kind in (k for k in FLOOR_KINDS if k in floors):
        lines += [f"Split floor, hand / probe / all (mm; column *split floor*): {FLOOR_NAMES[kind]}.", ""]
        for (name, sha), mm in sorted(floors[kind].items()):
            lines.append(f"- {_cell(name)}" + (f" (manifest sha256 `{sha[:12]}`)" if sha else "")
                         + f", test split: {triplet_cell(mm)}")
        lines.append("")
    return lines


def _table(columns: Sequence[str], aligns: list[str], rows: list[list[str]]) -> list[str]:
    """A Markdown table's lines and the blank line after it."""
    return ["| " + " | ".join(columns) + " |", "|" + "|".join(aligns) + "|",
            *("| " + " | ".join(cells) + " |" for cells in rows), ""]


def _count(n: int, noun: str) -> str:
    return f"{n} {noun}" + ("" if n == 1 else "s")


def _track_section(track: str, rows: list[dict]) -> list[str]:
    """One track's heading, what it holds out, its floors and its table (rows already sorted)."""
    title, holds_out = TRACK_TITLES[track]
    n_measured = sum(row["kind"] == "measured" for row in rows)
    out = [f"## Track: {title} (`{track}`)", "", f"{title}: {holds_out}", ""]
    out += _floor_lines(rows)
    out += [f"{_count(len(rows), 'row')} ({n_measured} measured, {len(rows) - n_measured} reported), sorted by MPJPE "
            f"all, then run name. {MISSING} means not measured or not reported.", ""]
    return out + _table(TABLE_COLUMNS, [_ALIGN[c] for c in TABLE_COLUMNS], [table_row(row) for row in rows])


def render_readme(rows: list[dict]) -> str:
    """The leaderboard README (Markdown ending in one newline) of validated rows sorted by :func:`sort_key`."""
    n_measured = sum(row["kind"] == "measured" for row in rows)
    tracks = [t for t in TRACKS if any(row_track(row) == t for row in rows)]
    out = [
        "# hupbench leaderboard",
        "",
        ("<!-- Generated by `hupbench leaderboard` from results/*.json. Do not edit by hand: edit or add a results "
         "file and rebuild. -->"),
        "",
        ("3D hand and ultrasound-probe pose estimation from one RGB image: how far the predicted keypoints are "
         "from the truth (MPJPE, mm) against what the model costs to train and to run. One row per results "
         f"file in [`results/`](results/) (schema version {SCHEMA_VERSION}, validated on load; files written in "
         f"earlier versions are read with the fields added since unknown, {MISSING}), in one table per track: "
         "what the test split holds out from training."),
        "",
        ("- **measured** rows were evaluated here by `hupbench eval` on the test split of the dataset they name. "
         "Every measured row names the committed command that reproduces its training (last column), and its "
         "results file records the model config, the dataset manifest hash, the git commit and the device."),
        ("- **reported in paper** rows quote a paper's numbers on that paper's data. They were not measured "
         "here, have no latency or training time, and their test data differ from the measured rows'."),
        "",
        ("Rebuild the table and both plots from the repository root with `hupbench leaderboard --dir leaderboard`; "
         "the same results files give the same bytes. To add a row, evaluate a model with "
         "`hupbench eval MODEL DATASET` into `leaderboard/results/<run_name>.json`, copy its training log to "
         "`leaderboard/logs/<run_name>.jsonl`, and rebuild."),
        "",
        (f"{_count(len(rows), 'row')} ({n_measured} measured, {len(rows) - n_measured} reported) in "
         f"{_count(len(tracks), 'track')}: " + ", ".join(f"{TRACK_TITLES[t][0]} (`{t}`)" for t in tracks) + "."),
        "",
    ]
    by_track = {track: [row for row in rows if row_track(row) == track] for track in tracks}
    for track in tracks:
        out += _track_section(track, by_track[track])
    out += [
        "## What the numbers mean",
        "",
        ("- MPJPE: mean Euclidean distance between predicted and true 3D keypoints in the camera frame, in mm, "
         "with no root or scale alignment. *hand* averages the 21 hand joints, *probe* the 8 corners of the "
         "probe's box, *all* the 29 keypoints together."),
        ("- How *all* is averaged matters when hand and probe errors differ: the mean over all 29 keypoints is "
         "(21 × hand + 8 × probe) / 29. Each row below states how its *all* was averaged. The HUP-3D paper's "
         "8.65 mm is not the keypoint-weighted mean of its 5.33 mm (hand) and 17.05 mm (probe), which is "
         "(21 × 5.33 + 8 × 17.05) / 29 = 8.56 mm; the paper does not say how its total is averaged."),
        ("- MPJPE probe, half-turn symmetric: the probe MPJPE with each frame's predicted corners compared with "
         "the true corners both as labelled and relabelled by the half turn about the probe's long axis (corner "
         "(ix, iy, iz) of the box becomes (1 − ix, 1 − iy, iz)), whichever is closer, as the BOP benchmark scores "
         "symmetric objects. It never exceeds the plain probe MPJPE; the gap is the error of confusing the two ends "
         "of the probe's transducer array. The probe carries an orientation marker on the +x end of its head "
         "(`datagen/assets/probe.py`), so the two ends can be told apart in the image and the plain probe MPJPE is the "
         "benchmark number; datasets rendered before the marker was added do not show it."),
        ("- Spread ratio x / y / z: for each camera axis, the standard deviation across the test frames of a "
         "predicted 3D coordinate, averaged over the 29 keypoints, divided by the same for the truth. 1 means the "
         "predictions vary as much as the truth; near 0 means the model gives about the same value for every "
         f"image (a collapsed model). `hupbench eval` warns below {SPREAD_RATIO_WARN}."),
        ("- Split floor (hand / probe / all, mm, mean distance per keypoint as in MPJPE), from the dataset's "
         "manifest: what a model that only recalls training labels scores on the test split. Unseen grasps: each "
         f"test grasp replaced by the {FLOOR_NAMES['nearest_train_grasp']}. Unseen views: each test frame replaced "
         f"by the {FLOOR_NAMES['nearest_train_view']}. A row near or above its floor has learnt little beyond the "
         "training labels. Each measured row's details list its MPJPE and floor per test grasp, with the grasp's "
         "probe orientation Theta_Vol (Euler angles x, y, z of the probe in the grasp generator, degrees)."),
        ("- PA-MPJPE hand: hand MPJPE after a Procrustes alignment (scale, rotation, translation) of the 21 "
         "predicted joints to the true ones. AUC 0-50 mm: area under the 3D PCK curve (fraction of keypoints "
         "within a threshold) for thresholds from 0 to 50 mm, normalised to [0, 1]."),
        ("- Training time is the training run's whole wall time (validation passes included) on the named hardware; "
         "the training-time plot counts training steps only. "
         "Latency is wall time per image at batch 1 on the row's device (see its details), ONNX Runtime and "
         "PyTorch measured separately."),
        "",
        "## Plots",
        "",
        f"![MPJPE against inference latency]({LATENCY_PLOT})",
        "",
        ("MPJPE (all) against inference latency per image at batch 1 (ONNX Runtime where measured, else PyTorch). "
         "The line joins the Pareto frontier: the rows no other row beats on both error and latency. Paper rows "
         "have no latency and are drawn as horizontal reference lines."),
        "",
        f"![Validation MPJPE against training wall time]({TRAINING_PLOT})",
        "",
        ("Validation MPJPE (all) against training wall time, one line per measured row with a training log; the "
         "paper's test numbers are dashed reference lines."),
        "",
        "## Row details",
        "",
        "By track, in the tables' order.",
        "",
    ]
    for track in tracks:
        for row in by_track[track]:
            out += _details(row)
    return "\n".join(out).rstrip("\n") + "\n"


# ----------------------------------------------------------------------------- plots

@contextlib.contextmanager
def _figure(rows: list[dict], extra_height_in: float = 0.0):
    """(figure, axes, reported rows) on the Agg canvas (no pyplot, no global backend switch) in matplotlib's
    default style, the reported rows drawn as reference lines; ``extra_height_in`` inches are added below
    the axes (for a list of the points)."""
    import matplotlib
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    with matplotlib.rc_context():
        matplotlib.rcdefaults()  # the user's matplotlibrc must not change the committed bytes
        fig = Figure(figsize=(FIGSIZE_IN[0], FIGSIZE_IN[1] + extra_height_in), dpi=DPI)
        FigureCanvasAgg(fig)
        ax = fig.add_subplot()
        reported = [row for row in rows if row["kind"] == "reported"]
        _draw_references(ax, reported)
        yield fig, ax, reported


def _png_bytes(fig, ax, xlabel: str, ylabel: str, title: str, legend_loc: str, bottom_in: float = 0.0) -> bytes:
    """The figure as PNG bytes, labelled; ``bottom_in`` inches at the bottom are kept clear of the axes."""
    import matplotlib
    import PIL

    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(True, alpha=0.3)
    ax.legend(loc=legend_loc, fontsize=8)
    height_in = fig.get_size_inches()[1]
    fig.tight_layout(rect=(0.0, bottom_in / height_in, 1.0, 1.0))
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=DPI,
                metadata={"Software": f"hupbench leaderboard; matplotlib {matplotlib.__version__}; "
                                      f"Pillow {PIL.__version__}"})
    return buffer.getvalue()


def _plain_log_ticks(axis) -> None:
    """Ticks at 1, 2, 5 x 10^k labelled as plain numbers (``20``, not ``2 x 10^1``)."""
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    axis.set_major_locator(LogLocator(base=10, subs=(1.0, 2.0, 5.0)))
    axis.set_major_formatter(FuncFormatter(lambda value, _: f"{value:g}"))
    axis.set_minor_formatter(NullFormatter())


def _reference_label(row: dict) -> str:
    return f"{row['dataset']['name']}: {row['model']['name']} {row['metrics']['mpjpe_mm']['all']:.2f} mm"


_REFERENCE_STYLES = ("--", ":", "-.", (0, (5, 1, 1, 1)))


def _draw_references(ax, reported: list[dict]) -> None:
    for k, row in enumerate(reported):
        y = row["metrics"]["mpjpe_mm"]["all"]
        ax.axhline(y, color="0.35", linestyle=_REFERENCE_STYLES[k % len(_REFERENCE_STYLES)], linewidth=1.2,
                   label=_reference_label(row) + " (test, reported)")
    # in order of height, labels go alternately below and above their line, so two close lines keep
    # readable labels
    by_height = sorted(reported, key=sort_key)
    for k, row in enumerate(by_height):
        ax.text(0.01, row["metrics"]["mpjpe_mm"]["all"], " " + _reference_label(row),
                transform=ax.get_yaxis_transform(), ha="left", va="top" if k % 2 == 0 else "bottom",
                fontsize=8, color="0.25")


def _y_limit(values: list[float]) -> float:
    return max(values) * 1.2 if values else 1.0


#: latencies spread over more than this ratio (slowest / fastest) are drawn on a log axis
LATENCY_LOG_RATIO = 20.0
#: inches of figure height per row listed under the latency plot
LIST_ROW_IN = 0.13


def latency_axis(latencies_ms: Sequence[float]) -> tuple[str, float, float]:
    """("linear" | "log", low, high) x limits of the latency plot: from 0 on a linear axis, so that a few
    hundredths of a millisecond between rows look as small as they are; a log axis (a factor 2 beyond the
    extremes) where the latencies span more than ``LATENCY_LOG_RATIO`` times; 1 to 1000 ms with none."""
    if not latencies_ms:
        return "log", 1.0, 1000.0
    low, high = min(latencies_ms), max(latencies_ms)
    if high / max(low, 1e-9) > LATENCY_LOG_RATIO:
        return "log", low / 2, high * 2
    return "linear", 0.0, high * 1.15 if high > 0 else 1.0


def plot_latency(rows: list[dict]) -> bytes:
    """PNG of MPJPE all against inference latency: measured rows with a batch-1 latency as numbered points
    (the numbers listed under the plot), their Pareto frontier where it joins two or more rows, reported
    rows as horizontal reference lines."""
    points, labels, runtimes = [], [], []
    for row in rows:
        ms, runtime = inference_latency_ms(row)
        if row["kind"] == "measured" and ms is not None:
            points.append((ms, row["metrics"]["mpjpe_mm"]["all"]))
            labels.append(plot_label(row))
            runtimes.append(runtime)
    with _figure(rows, extra_height_in=LIST_ROW_IN * (len(points) + 1) if points else 0.0) as (fig, ax, reported):
        for runtime, marker in (("ONNX Runtime", "o"), ("PyTorch", "s")):
            chosen = [p for p, r in zip(points, runtimes) if r == runtime]
            if chosen:
                ax.scatter([p[0] for p in chosen], [p[1] for p in chosen], marker=marker, s=45, zorder=3,
                           color="tab:blue" if runtime == "ONNX Runtime" else "tab:orange",
                           label=f"measured, {runtime} latency (numbered as listed below)")
        for k, (x, y) in enumerate(points, start=1):
            ax.annotate(str(k), (x, y), xytext=(5, 3), textcoords="offset points", fontsize=8)
        front = [points[i] for i in pareto_front(points)]
        if len(front) > 1:  # one row alone is no frontier: a legend entry for it would name an invisible line
            ax.plot([p[0] for p in front], [p[1] for p in front], color="tab:green", linewidth=1.5, zorder=2,
                    drawstyle="steps-post", label=f"Pareto frontier ({len(front)} of {len(points)} rows)")
        scale, low, high = latency_axis([p[0] for p in points])
        ax.set_xscale(scale)
        ax.set_xlim(low, high)
        if scale == "log":
            _plain_log_ticks(ax.xaxis)
        if not points:
            ax.text(0.5, 0.5, "no measured rows with a latency yet\n(hupbench eval writes them)",
                    transform=ax.transAxes, ha="center", va="center", color="0.4")
        ax.set_ylim(0, _y_limit([p[1] for p in points] + [r["metrics"]["mpjpe_mm"]["all"] for r in reported]))
        if points:
            listing = "\n".join(f"{k}: {label} ({x:.2f} ms, {y:.2f} mm)"
                                 for k, (label, (x, y)) in enumerate(zip(labels, points), start=1))
            fig.text(0.01, 0.01, listing, ha="left", va="bottom", fontsize=7.5, family="monospace")
        log_scale = ", log scale" if scale == "log" else ""
        return _png_bytes(fig, ax, f"inference latency (ms per image, batch 1{log_scale})",
                          "test MPJPE, all 29 keypoints (mm)", "Error against inference latency (lower left is better)",
                          "lower right", bottom_in=LIST_ROW_IN * (len(points) + 1) if points else 0.0)


def plot_training(rows: list[dict], leaderboard_dir: str | Path) -> bytes:
    """PNG of validation MPJPE against training wall time, one line per measured row with a log (its
    ``training.log`` relative to ``leaderboard_dir``)."""
    import matplotlib

    curves = []
    for row in rows:
        if row["kind"] == "measured" and row["training"]["log"] is not None:
            log_path = Path(leaderboard_dir) / row["training"]["log"]
            try:
                curves.append((row, read_validation_curve(log_path)))
            except FileNotFoundError as exc:
                raise MissingFileError(f"results/{row['run_name']}.json: training log: {exc}") from exc
            except ValueError as exc:
                # not type(exc)(...): a UnicodeDecodeError is a ValueError that takes five arguments
                raise BadValueError(f"results/{row['run_name']}.json: training log: {exc}") from exc
    longest_s = max((s for _, curve in curves for s, _ in curve), default=0.0)
    hours = longest_s > 2 * 3600
    scale, unit = (3600.0, "h") if hours else (60.0, "min")

    with _figure(rows) as (fig, ax, reported):
        colours = matplotlib.colormaps["tab10"].colors
        for k, (row, curve) in enumerate(curves):
            hardware = f", {row['training']['hardware']}" if row["training"]["hardware"] else ""
            ax.plot([s / scale for s, _ in curve], [m for _, m in curve], marker="o", markersize=3, linewidth=1.5,
                    color=colours[k % len(colours)], label=f"{plot_label(row)}{hardware}")
        if curves:
            ax.set_xlim(0, longest_s / scale * 1.05 if longest_s > 0 else 1.0)
        else:
            ax.set_xlim(0, 1)
            ax.text(0.5, 0.5, "no measured rows with a training log yet", transform=ax.transAxes,
                    ha="center", va="center", color="0.4")
        values = [m for _, c in curves for _, m in c] + [r["metrics"]["mpjpe_mm"]["all"] for r in reported]
        positive = [v for v in values if v > 0]
        if positive and max(positive) / min(positive) > 5:
            # early validation errors are often ten times the final ones: a log axis shows both ends
            ax.set_yscale("log")
            ax.set_ylim(min(positive) / 1.3, max(positive) * 1.3)
            _plain_log_ticks(ax.yaxis)
        else:
            ax.set_ylim(0, _y_limit(values))
        log_scale = ", log scale" if ax.get_yscale() == "log" else ""
        return _png_bytes(fig, ax, f"training wall time ({unit}, validation passes excluded)",
                          f"validation MPJPE, all 29 keypoints (mm){log_scale}", "Validation error against training time (paper lines: test split)", "upper right")


# ----------------------------------------------------------------------------- verb

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
    root = Path(dir)
    if not root.exists():
        raise MissingFileError(f"leaderboard folder (--dir) {root} does not exist")
    if not root.is_dir():
        raise BadValueError(f"leaderboard folder (--dir) {root} is not a folder")
    if not (root / "results").is_dir():
        raise MissingFileError(f"{root} has no results/ folder (results/<run_name>.json files); is --dir the "
                               "leaderboard folder?")
    check_writable(root, "leaderboard folder")
    for name in (README, LATENCY_PLOT, TRAINING_PLOT):  # a folder in an output's place would stop the renames
        check_writable(root / name, "leaderboard file", file=True)
    clean_stale_tmp(root, recursive=False)
    rows = load_rows(root / "results")
    # render everything before writing anything, so a bad log leaves the old files in place
    files = {README: render_readme(rows).encode("utf-8"), LATENCY_PLOT: plot_latency(rows),
             TRAINING_PLOT: plot_training(rows, root)}
    paths = _write_together(root, files)
    measured = sum(row["kind"] == "measured" for row in rows)
    return {"rows": len(rows), "measured": measured, "reported": len(rows) - measured, "readme": paths[0],
            "plots": paths[1:]}
