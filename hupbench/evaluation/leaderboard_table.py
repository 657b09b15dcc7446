"""The leaderboard's cells: a validated results row as Markdown table cells, its track, its label and its order.

Numbers are formatted explicitly (two decimals for mm and ms, three for the AUC, one for the bounds of a 95 %
interval over the test grasps) so that the same results give the same bytes; an unknown value is the missing mark
:data:`MISSING`, and so is the interval of a row whose results record neither an interval nor a grasp breakdown
to recompute it from (``"9.88 [—]"``).

Convention: errors in mm, latency in ms per image at batch 1, times in seconds.
"""

from __future__ import annotations

import re
from collections.abc import Sequence

from hupbench.core.contract import UNSEEN_GRASPS
from hupbench.core.depth_sensor import PRESETS
from hupbench.evaluation.intervals import PARTS, interval_text, intervals_block

MISSING = "—"
#: the track of rows whose results name none (the paper's, and datasets made before tracks)
PAPER_TRACK = UNSEEN_GRASPS
#: each track's table heading and what it holds out
TRACK_TITLES = {
    "unseen_grasps": ("Unseen grasps", "the test split's grasps are not in the training split (the HUP-3D paper's "
                      "protocol). Rows whose results name no track (the paper's, and results of datasets made "
                      "before tracks) belong here."),
    "unseen_views": ("Unseen views", "every grasp is in the training split; the test split's camera views of the "
                     "sphere are not."),
    "clinic": ("Clinic", "hands of many sizes on a patient's abdomen in a room with depth, seen from where a "
               "sonographer's head can be; the test split's grasps and hands are not in the training split."),
}
#: the axes and threshold of the spread ratios (hupbench.metrics.SPREAD_AXES, SPREAD_RATIO_WARN), kept
#: here as plain values so that the leaderboard does not import torch
SPREAD_AXES = ("x", "y", "z")
SPREAD_RATIO_WARN = 0.5
#: hexadecimal digits of a sha256 shown in the table and the details
SHA_DIGITS = 12

TABLE_COLUMNS = ("model", "kind", "test data", "grasps sha256", "input (px)", "params (M)", "MPJPE all (mm) [95 % CI]",
                 "MPJPE hand (mm) [95 % CI]", "MPJPE probe (mm) [95 % CI]",
                 "split floor hand / probe / all (mm) [95 % CI]",
                 "MPJPE probe, half-turn symmetric (mm)", "PA-MPJPE hand (mm)", "AUC 0-50 mm", "spread ratio x / y / z",
                 "training (time, hardware)", "latency ONNX Runtime (ms/image, batch 1)",
                 "latency PyTorch (ms/image, batch 1)", "command")
#: numbers right-aligned, text left
TABLE_ALIGN = ["---" if c in ("model", "kind", "test data", "grasps sha256", "training (time, hardware)", "command")
               else "---:" for c in TABLE_COLUMNS]
GRASP_COLUMNS = ("grasp", "Theta_Vol x, y, z (deg)", "frames", "MPJPE hand (mm)", "MPJPE probe (mm)", "MPJPE all (mm)",
                 "floor hand / probe / all (mm)", "nearest training grasp")


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


def number_cell(value: float | None, digits: int = 2) -> str:
    """``value`` with ``digits`` decimals, the missing mark for None."""
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


def text_cell(text: str) -> str:
    """``text`` on one line, safe inside a Markdown table cell."""
    return " ".join(str(text).split()).replace("|", "\\|")  # a pipe would end the cell and a newline the row


def code_cell(text: str | None) -> str:
    """``text`` as inline code in a cell, the missing mark for None."""
    return MISSING if text is None else f"`{text_cell(text)}`"


def sha_cell(sha256: str | None) -> str:
    """The first :data:`SHA_DIGITS` digits of a sha256 as inline code, the missing mark for None."""
    return MISSING if sha256 is None else f"`{sha256[:SHA_DIGITS]}`"


def triplet_cell(mm: dict | None) -> str:
    """``"12.00 / 30.00 / 17.00"``: hand / probe / all (mm) of a {"hand", "probe", "all"} dict (None: missing mark)."""
    if mm is None:
        return MISSING
    return " / ".join(number_cell(mm[part]) for part in ("hand", "probe", "all"))


def interval_cell(value: float | None, bounds: list[float] | None) -> str:
    """``"18.62 [7.7-29.5]"``: a value (two decimals) and its 95 % interval over the test grasps (one decimal),
    ``"18.62 [—]"`` where the results record no interval, the missing mark where the value is unknown."""
    return MISSING if value is None else f"{number_cell(value)} {interval_text(bounds, missing=f'[{MISSING}]')}"


def interval_triplet_cell(mm: dict | None, bounds: dict | None) -> str:
    """:func:`triplet_cell` of hand / probe / all with each value's interval (``bounds``: part -> [low, high],
    or None where none is recorded)."""
    if mm is None:
        return MISSING
    return " / ".join(interval_cell(mm[part], None if bounds is None else bounds[part])
                      for part in ("hand", "probe", "all"))


#: where a row's intervals come from (``with_intervals``' ``"intervals_from"``)
RECORDED, RECOMPUTED = "results", "breakdown"


def with_intervals(row: dict) -> dict:
    """``row`` with ``"intervals_from"``: :data:`RECORDED` where its results file records intervals; else, where
    it records a grasp breakdown, :data:`RECOMPUTED` and the intervals ``hupbench eval`` writes, recomputed from
    that breakdown and the split floor's ``per_grasp``
    (:func:`~hupbench.evaluation.intervals.intervals_block`, default resamples and seed); else None (a paper's
    number, a results file written before grasp breakdowns)."""
    grasps = row["breakdowns"].get("grasp")
    if row["intervals"] is not None:
        return row | {"intervals_from": RECORDED}
    if not grasps or any(b["frames"] < 1 or any(b["mpjpe_mm"][p] is None for p in PARTS) for b in grasps.values()):
        return row | {"intervals_from": None}
    floor = None if row["split_floor"] is None else row["split_floor"]["per_grasp"]
    return row | {"intervals": intervals_block(grasps, floor), "intervals_from": RECOMPUTED}


def row_intervals(row: dict, block: str) -> dict | None:
    """The row's intervals (part -> [low, high]) of ``block`` ("mpjpe_mm" or "split_floor_mm"), None if none."""
    return None if row["intervals"] is None else row["intervals"][block]


def row_track(row: dict) -> str:
    """The track whose table holds the row: its results' track, else ``PAPER_TRACK``."""
    return row["track"] or PAPER_TRACK


def row_label(row: dict) -> str:
    """The row's model label, with the depth camera it read where that is a sensor's (``dataset.depth_sensor`` a
    preset of :mod:`hupbench.core.depth_sensor`), not the clean z-buffer: two rows of one model on one dataset
    differ by it."""
    sensor = row["dataset"].get("depth_sensor")
    return row["model"]["label"] + (f", {sensor} depth" if sensor in PRESETS else "")


def plot_label(row: dict) -> str:
    """The row's model label in the plots (:func:`row_label`), with its track when it is not the paper's."""
    track = row_track(row)
    return row_label(row) + ("" if track == PAPER_TRACK else f", {TRACK_TITLES[track][0].lower()}")


def spread_cell(row: dict) -> str:
    """``"0.02 / 0.01 / 0.95"`` (x / y / z spread ratios), a missing mark per unknown axis, one mark if all are."""
    ratios = row["metrics"]["spread_ratio"]
    if all(ratios[a] is None for a in SPREAD_AXES):
        return MISSING
    return " / ".join(number_cell(ratios[a]) for a in SPREAD_AXES)


def table_row(row: dict) -> list[str]:
    """The cells of a validated results row, one per :data:`TABLE_COLUMNS`."""
    model, metrics, training = row["model"], row["metrics"], row["training"]
    mpjpe = metrics["mpjpe_mm"]
    params = None if model["parameters"] is None else model["parameters"] / 1e6
    if training["wall_s"] is None and training["hardware"] is None:
        train_cell = MISSING
    else:
        train_cell = format_duration(training["wall_s"]) + (f", {training['hardware']}" if training["hardware"] else "")
    latency = row["latency_ms_per_image"]
    return [
        text_cell(row_label(row)),
        "measured" if row["kind"] == "measured" else "reported in paper",
        text_cell(row["dataset"]["name"]),
        sha_cell(row["dataset"]["grasps_sha256"]),
        MISSING if model["input_size"] is None else str(model["input_size"]),
        number_cell(params),
        *(interval_cell(mpjpe[part], (row_intervals(row, "mpjpe_mm") or {}).get(part))
          for part in ("all", "hand", "probe")),
        interval_triplet_cell(None if row["split_floor"] is None else row["split_floor"]["floor_mm"],
                              row_intervals(row, "split_floor_mm")),
        number_cell(metrics["probe_symmetric_mpjpe_mm"]),
        number_cell(metrics["pa_mpjpe_hand_mm"]),
        number_cell(metrics["pck_auc_0_50mm"], 3),
        spread_cell(row),
        text_cell(train_cell),
        number_cell(latency["onnxruntime"]["batch1"]),
        number_cell(latency["pytorch"]["batch1"]),
        code_cell(training["command"]),
    ]


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
        nearest = None if floor is None else floor.get("nearest_train_grasp_id")
        out.append([grasp, MISSING if angles is None else ", ".join(f"{a:g}" for a in angles),
                    MISSING if bucket is None else str(bucket["frames"]),
                    number_cell(mpjpe.get("hand")), number_cell(mpjpe.get("probe")), number_cell(mpjpe.get("all")),
                    triplet_cell(None if floor is None else floor["floor_mm"]),
                    MISSING if nearest is None else str(nearest)])
    return out


def natural_key(label: str) -> list:
    """Sort key that orders the numbers inside labels by value: "theta_vol_z=45" before "theta_vol_z=180"."""
    return [(0, float(part), "") if i % 2 else (1, 0.0, part)
            for i, part in enumerate(re.split(r"(-?\d+(?:\.\d+)?)", label))]


def markdown_table(columns: Sequence[str], aligns: Sequence[str], rows: list[list[str]]) -> list[str]:
    """A Markdown table's lines and the blank line after it."""
    return ["| " + " | ".join(columns) + " |", "|" + "|".join(aligns) + "|",
            *("| " + " | ".join(cells) + " |" for cells in rows), ""]
