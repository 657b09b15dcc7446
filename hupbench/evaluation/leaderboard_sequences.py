"""The leaderboard's sequence table: each row evaluated on a split of clips (a results file with a ``sequence`` block,
:mod:`hupbench.evaluation.sequence_metrics`) scored as motion, per frame and tracked.

Its cells: MPJPE all, acceleration error and jitter, untracked -> tracked, each with its 95 % interval over the test
grasps and the paired interval of the difference (tracked minus untracked); the probe's speed error over the patient;
the split's floor (MPJPE all) beside them; the tracked fits (their time per frame) and the filter with the split it
was chosen on.
"""

from __future__ import annotations

from hupbench.evaluation.leaderboard_table import MISSING, code_cell, interval_cell, markdown_table, text_cell

#: the metrics of the table, with their column names
METRICS = (("mpjpe_all_mm", "MPJPE all (mm)"), ("acceleration_error_mm_per_frame2", "accel. error (mm/frame²)"),
           ("jitter_mm_per_s3", "jitter (mm/s³)"), ("probe_room_speed_mm_per_s_error", "probe speed error (mm/s)"))


def _cell(block: dict, key: str) -> str:
    """``untracked [low-high] -> tracked [low-high], difference [low-high]`` of one metric."""
    intervals = block["intervals"]

    def interval(bounds: list[float]) -> str:
        return f"[{bounds[0]:.1f}-{bounds[1]:.1f}]"

    return (f"{block['untracked'][key]:.2f} {interval(intervals['untracked'][key])} → {block['tracked'][key]:.2f} "
            f"{interval(intervals['tracked'][key])}, Δ {interval(intervals['tracked_minus_untracked'][key])}")


def sequence_section(rows: list[dict]) -> list[str]:
    """The table of the rows with a ``sequence`` block (none: no section)."""
    rows = [row for row in rows if row.get("sequence") is not None]
    if not rows:
        return []
    out = ["## Sequences: scored as motion, per frame and tracked", "",
           ("Rows evaluated on a split of clips (`hupbench generate +track=clinic_sequences`): each clip's frames in "
            "time order, per frame (untracked) and tracked: the fits started where they left the frame before "
            "(a model with fits), then the 1-euro filter whose settings `hupbench eval` chose on the validation "
            "split. Each cell: untracked → tracked, each with its 95 % interval over the "
            "test grasps, and Δ the paired interval of tracked minus untracked (below 0: tracking lowers it). The "
            "probe's speed error is over the patient: each frame's prediction taken to the room with the headset's "
            "pose (docs/sequences.md)."), ""]
    columns = ["Model", *(name for _, name in METRICS), "split floor all (mm)", "tracking", "clips", "Command"]
    aligns = [":--", *("--:" for _ in METRICS), "--:", ":--", "--:", ":--"]
    table = []
    for row in rows:
        block = row["sequence"]
        settings = block["filter"]["settings"]
        tracking = "no filter kept the MPJPE" if settings is None else \
            f"1-euro {settings['min_cutoff_hz']:g} Hz, β {settings['beta']:g} (chosen on " \
            f"{block['filter']['chosen_on']})"
        fitted = block.get("tracked_fits")
        if fitted is not None:
            tracking = f"fits from the frame before ({fitted['ms_per_frame']:.1f} ms/frame), then {tracking}"
        floor, bounds = row.get("split_floor"), (row.get("intervals") or {}).get("split_floor_mm")
        floor_cell = MISSING if floor is None else \
            interval_cell(floor["floor_mm"]["all"], (bounds or {}).get("all"))
        table.append([text_cell(row["model"]["label"]), *(_cell(block, key) for key, _ in METRICS), floor_cell,
                      tracking,
                      f"{block['clips']} × {block['frames_per_clip']} at {block['fps']:g} fps",
                      code_cell(row["training"]["command"])])
    return out + markdown_table(columns, aligns, table)
