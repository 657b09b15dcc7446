"""The leaderboard's sequence table: a row scored on clips gets untracked -> tracked cells with intervals and the
paired difference; rows without a sequence block add no section."""

from hupbench.evaluation.leaderboard_sequences import METRICS, sequence_section


def _row(settings):
    keys = [key for key, _ in METRICS]
    block = {"fps": 30.0, "clips": 20, "frames_per_clip": 151,
             "filter": {"settings": settings, "chosen_on": "val"},
             "untracked": dict.fromkeys(keys, 10.0), "tracked": dict.fromkeys(keys, 8.5),
             "intervals": {"untracked": dict.fromkeys(keys, [9.0, 11.0]), "tracked": dict.fromkeys(keys, [7.5, 9.5]),
                           "tracked_minus_untracked": dict.fromkeys(keys, [-2.0, -1.0])}}
    return {"model": {"label": "HUPNet | seg"}, "training": {"command": "bash scripts/paper_protocol.sh x"},
            "sequence": block, "split_floor": {"floor_mm": {"all": 50.2}},
            "intervals": {"split_floor_mm": {"all": [45.9, 54.9]}}}


def test_a_row_on_clips_gets_its_cells_and_rows_on_frames_none():
    assert sequence_section([{"model": {"label": "x"}, "sequence": None}, {"model": {"label": "y"}}]) == []
    lines = sequence_section([_row({"min_cutoff_hz": 1.0, "beta": 10.0}), _row(None)])
    table = [line for line in lines if line.startswith("| ")]
    assert len(table) == 3  # header and two rows
    assert "10.00 [9.0-11.0] → 8.50 [7.5-9.5], Δ [-2.0--1.0]" in table[1]
    assert "1-euro 1 Hz, β 10 (chosen on val)" in table[1] and "HUPNet \\| seg" in table[1]
    assert "no filter kept the MPJPE" in table[2] and "20 × 151 at 30 fps" in table[2]
    assert "| 50.20 [45.9-54.9] |" in table[1]
    assert "frame before" not in table[1]
    fitted = _row(None)
    fitted["sequence"]["tracked_fits"] = {"probe_tracking_iterations": 4, "hand_tracking_iterations": 2,
                                          "ms_per_frame": 12.34}
    row = [line for line in sequence_section([fitted]) if line.startswith("| ")][1]
    assert "fits from the frame before (12.3 ms/frame), then no filter kept the MPJPE" in row
