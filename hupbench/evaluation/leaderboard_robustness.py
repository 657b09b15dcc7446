"""The leaderboard's depth sensor table: each model of ``robustness/*.json`` evaluated on its test split under each
depth camera of :mod:`hupbench.core.depth_sensor` (``bash scripts/sensor_robustness.sh EXPERIMENT``).

A robustness file is a results file whose ``dataset.depth_sensor`` names the depth the model read; it belongs to the
leaderboard row of ``results/`` that names the same training command and track (the model's row), and every file of
one model must be of one dataset (the same frames under each sensor). Its cells: MPJPE hand / probe / all (mm) with
the 95 % intervals over the test grasps.
"""

from __future__ import annotations

from pathlib import Path

from hupbench.core.depth_sensor import NONE, PRESETS
from hupbench.core.errors import BadValueError
from hupbench.evaluation.leaderboard_table import (
    TRACK_TITLES,
    code_cell,
    interval_triplet_cell,
    markdown_table,
    row_intervals,
    row_track,
    text_cell,
)

#: the leaderboard's folder of depth sensor results
ROBUSTNESS = "robustness"
#: the table's columns, in order: the clean z-buffer, then each preset
SENSORS = (NONE, *PRESETS)


def check_robustness(robust: list[dict], rows: list[dict], folder: Path) -> None:
    """Each robustness row names its depth sensor and the training command and track of one measured leaderboard row;
    one model's files are of one dataset and hold each sensor once; else a BadValueError naming the file."""
    models = {(row["training"]["command"], row_track(row)) for row in rows if row["kind"] == "measured"}
    seen: dict[tuple, dict] = {}
    for row in robust:
        path = folder / f"{row['run_name']}.json"
        sensor = row["dataset"].get("depth_sensor")
        if sensor is None:
            raise BadValueError(f"{path}: results['dataset']['depth_sensor'] is missing: a robustness row is a depth "
                                "model evaluated with `hupbench eval --depth-sensor` (scripts/sensor_robustness.sh)")
        key = (row["training"]["command"], row_track(row))
        if key not in models:
            raise BadValueError(f"{path}: no measured row of results/ has its training command {key[0]!r} on the "
                                f"{key[1]} track: a robustness row goes beside its model's leaderboard row")
        first = seen.setdefault(key, {"manifest": row["dataset"]["manifest_sha256"], "sensors": {},
                                      "path": path})
        if row["dataset"]["manifest_sha256"] != first["manifest"]:
            raise BadValueError(f"{path}: another dataset (manifest sha256 {row['dataset']['manifest_sha256']}) than "
                                f"{first['path']} ({first['manifest']}), a robustness row of the same model: the "
                                "table compares the same frames under each sensor")
        if sensor in first["sensors"]:
            raise BadValueError(f"{path} and {folder / first['sensors'][sensor]}.json: one model under "
                                f"{sensor} twice")
        first["sensors"][sensor] = row["run_name"]


def robustness_section(robust: list[dict], rows: list[dict]) -> list[str]:
    """The README's depth sensor section (empty without robustness rows)."""
    if not robust:
        return []
    by_model: dict[tuple, dict[str, dict]] = {}
    for row in robust:
        by_model.setdefault((row["training"]["command"], row_track(row)), {})[row["dataset"]["depth_sensor"]] = row
    base = {(row["training"]["command"], row_track(row)): row for row in rows if row["kind"] == "measured"}
    columns = ["Model", "Track", "Split floor"] + [f"`{s}`" for s in SENSORS] + ["Command"]
    table = []
    for key in sorted(by_model, key=lambda k: (base[k]["model"]["label"], k)):
        sensors, model = by_model[key], base[key]
        any_row = next(iter(sensors.values()))
        floor = any_row["split_floor"]
        table.append([text_cell(model["model"]["label"]), TRACK_TITLES[key[1]][0],
                      "—" if floor is None else interval_triplet_cell(floor["floor_mm"],
                                                                     row_intervals(any_row, "split_floor_mm"))]
                     + [interval_triplet_cell(sensors[s]["metrics"]["mpjpe_mm"], row_intervals(sensors[s], "mpjpe_mm"))
                        if s in sensors else "—" for s in SENSORS] + [code_cell(key[0])])
    return [
        "## Robustness to the depth camera",
        "",
        ("Each depth model's checkpoint evaluated on its track's test split, the depth it reads made by one depth "
         "camera model (`hupbench/core/depth_sensor.py`) from the clean z-buffer: `none` is the z-buffer itself, "
         "then an Azure Kinect (NFOV unbinned), a HoloLens 2's AHAT (range wraps beyond 1 m) and its Long-Throw "
         "camera, each with its resolution, field of view and place beside the colour camera, noise growing with "
         "range, a per-frame offset, skin read behind its surface, mixed and flying pixels at depth edges, no "
         "depth on dark plastic and at grazing angles. The same frames and the same seeded noise for every model. "
         "Cells: MPJPE hand / probe / all, mm [95 % CI over the test grasps]; the split floor beside. From "
         f"[`{ROBUSTNESS}/`]({ROBUSTNESS}/), made by `bash scripts/sensor_robustness.sh EXPERIMENT` after "
         "`bash scripts/paper_protocol.sh EXPERIMENT` (the command in the last column)."),
        "",
    ] + markdown_table(columns, ["---", "---", "---:"] + ["---:"] * len(SENSORS) + ["---"], table)
