"""The leaderboard: byte-for-byte rebuild of the committed files, the table, the plots, bad input named."""

import copy
import json
import shutil
import struct
import subprocess
import sys
from pathlib import Path

import matplotlib
import numpy as np
import PIL
import pytest

from hupbench.cli import main
from hupbench.evaluation.intervals import RESAMPLES, SEED, interval_text
from hupbench.evaluation.leaderboard import README, load_rows, read_validation_curve, run_leaderboard
from hupbench.evaluation.leaderboard_plots import DPI, FIGSIZE_IN, pareto_front
from hupbench.evaluation.leaderboard_readme import LATENCY_PLOT, TRAINING_PLOT
from hupbench.evaluation.leaderboard_table import format_duration, grasp_rows, inference_latency_ms, table_row
from hupbench.evaluation.results import keypoint_weighted_all_mm, load_results, write_results
from hupbench.evaluation.split_metrics import split_intervals
from helpers.leaderboard import COMMITTED, OUTPUTS, intervals_block, measured, split_floor_block, triplet, write_log
from helpers import REPO



def png_chunks(data: bytes) -> dict:
    """Chunk type -> list of payloads of a PNG."""
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    chunks, pos = {}, 8
    while pos < len(data):
        (length,) = struct.unpack(">I", data[pos:pos + 4])
        kind = data[pos + 4:pos + 8].decode("ascii")
        chunks.setdefault(kind, []).append(data[pos + 8:pos + 8 + length])
        pos += 12 + length
    return chunks


def png_size(data: bytes) -> tuple[int, int]:
    return struct.unpack(">II", png_chunks(data)["IHDR"][0][:8])


def png_software(data: bytes) -> str:
    for payload in png_chunks(data).get("tEXt", []):
        key, _, value = payload.partition(b"\0")
        if key == b"Software":
            return value.decode("latin-1")
    return ""




def with_grasps(row: dict, track: str = "unseen_grasps", floor_kind: str = "nearest_train_grasp") -> dict:
    """``row`` evaluated on a dataset with tracks and floors: grasps 3 (Theta_Vol z 180) and 12 (orientation not
    recorded), the test split's floor of :func:`test_results.split_floor_block`, the intervals of
    :func:`helpers.leaderboard.intervals_block`."""
    row["breakdowns"] = {"grasp": {"3": {"frames": 2000, "mpjpe_mm": triplet(9.0, 16.0)},
                                   "12": {"frames": 3760, "mpjpe_mm": triplet(11.5, 22.25)}},
                         "theta_vol": {"theta_vol_z=180": {"frames": 2000, "mpjpe_mm": triplet(9.0, 16.0)},
                                       "unknown": {"frames": 3760, "mpjpe_mm": triplet(11.5, 22.25)}}}
    row["dataset"]["grasp_theta_vol_deg"] = {"3": [0.0, 0.0, 180.0], "12": None}
    row["track"] = track
    row["split_floor"] = split_floor_block(frames=(2000, 3760)) | {"floor_kind": floor_kind}
    row["intervals"] = intervals_block()
    return row


def table_lines(text: str, track_title: str = "Unseen grasps") -> list[str]:
    """The rows of one track's table in the README (header and alignment line left out)."""
    section = text.split(f"## Track: {track_title}")[1].split("\n## ")[0]
    return [line for line in section.splitlines() if line.startswith("| ")][1:]




@pytest.fixture
def synthetic_board(tmp_path):
    """The committed paper rows plus three synthetic measured rows with logs (one without a log)."""
    root = tmp_path / "board"
    (root / "results").mkdir(parents=True)
    # the committed rows reported from papers; measured rows are the synthetic ones below
    for path in sorted((COMMITTED / "results").glob("*.json")):
        if json.loads(path.read_text())["kind"] == "reported":
            shutil.copy(path, root / "results" / path.name)
    rows = [measured("fast_small", "HOPE-Net (ResNet-10, 64 px)", 30.0, 25.0, 43.125, 2.0, 5.0, 1500.0),
            measured("slow_big", "HOPE-Net (ResNet-50, 224 px)", 10.456, 8.0, 16.9, 80.0, 150.0, 20 * 3600.0),
            measured("torch_only", "ResNet-50 regressor (224 px)", 12.0, 10.0, 17.25, None, 40.0, 5 * 3600.0,
                     hardware=None, log=False)]
    for row in rows:
        write_results(root / "results" / f"{row['run_name']}.json", row)
        if row["training"]["log"]:
            write_log(root / row["training"]["log"], row["training"]["wall_s"], row["metrics"]["mpjpe_mm"]["all"])
    return root


# ----------------------------------------------------------------------------- committed files

def test_committed_paper_rows():
    hope = load_results(COMMITTED / "results" / "paper_hopenet.json")
    assert hope["kind"] == "reported" and hope["dataset"]["name"] == "HUP-3D (paper)"
    assert (hope["metrics"]["mpjpe_mm"]["all"], hope["metrics"]["mpjpe_mm"]["hand"],
            hope["metrics"]["mpjpe_mm"]["probe"]) == (8.65, 5.33, 17.05)
    assert keypoint_weighted_all_mm(hope["metrics"]["mpjpe_mm"]) == pytest.approx(8.5631, abs=1e-4)  # not 8.65: stated in the README
    resnet = load_results(COMMITTED / "results" / "paper_resnet50.json")
    assert resnet["metrics"]["mpjpe_mm"]["all"] == 9.69 and resnet["metrics"]["mpjpe_mm"]["hand"] is None
    for row in (hope, resnet):
        assert row["source"] == "Birlo et al., HUP-3D, test split of unseen grasps"
        assert row["latency_ms_per_image"]["onnxruntime"]["batch1"] is None


def test_rebuild_reproduces_committed_files_byte_for_byte(tmp_path):
    copy = tmp_path / "leaderboard"
    shutil.copytree(COMMITTED, copy)
    result = run_leaderboard(copy)
    assert result["rows"] == len(list((COMMITTED / "results").glob("*.json")))
    assert (copy / README).read_bytes() == (COMMITTED / README).read_bytes()
    # the pixels are matplotlib's and Pillow's: the committed PNGs name the versions that drew them
    versions = f"matplotlib {matplotlib.__version__}; Pillow {PIL.__version__}"
    for name in (LATENCY_PLOT, TRAINING_PLOT):
        committed = (COMMITTED / name).read_bytes()
        assert png_size(committed) == png_size((copy / name).read_bytes())
        if versions not in png_software(committed):
            pytest.skip(f"{name} was drawn by {png_software(committed)!r}; this environment has {versions}")
        assert (copy / name).read_bytes() == committed, f"{name} differs from the committed file"


def test_plots_have_fixed_size_and_no_date(synthetic_board):
    from hupbench.evaluation.leaderboard_plots import LIST_ROW_IN

    run_leaderboard(synthetic_board)
    rows = load_rows(synthetic_board / "results")
    timed = sum(r["kind"] == "measured" and inference_latency_ms(r)[0] is not None for r in rows)
    assert timed == 3
    # the latency plot lists its numbered points below the axes: one line each, and a margin
    heights = {TRAINING_PLOT: 600, LATENCY_PLOT: round((FIGSIZE_IN[1] + LIST_ROW_IN * (timed + 1)) * DPI)}
    for name in (LATENCY_PLOT, TRAINING_PLOT):
        data = (synthetic_board / name).read_bytes()
        assert png_size(data) == (int(FIGSIZE_IN[0] * DPI), heights[name]) and FIGSIZE_IN[0] * DPI == 900
        text_keys = [p.partition(b"\0")[0] for kind in ("tEXt", "iTXt", "zTXt") for p in png_chunks(data).get(kind, [])]
        assert text_keys == [b"Software"]  # no creation time or other varying metadata
        assert "tIME" not in png_chunks(data)


def test_rebuild_in_a_second_process_gives_identical_bytes(synthetic_board):
    run_leaderboard(synthetic_board)
    first = {name: (synthetic_board / name).read_bytes() for name in OUTPUTS}
    code = f"from hupbench.evaluation.leaderboard import run_leaderboard; run_leaderboard({str(synthetic_board)!r})"
    subprocess.run([sys.executable, "-c", code], check=True, timeout=120)
    for name in OUTPUTS:
        assert (synthetic_board / name).read_bytes() == first[name], name


# ----------------------------------------------------------------------------- table

def test_synthetic_measured_rows_in_table(synthetic_board):
    result = run_leaderboard(synthetic_board)
    assert (result["rows"], result["measured"], result["reported"]) == (5, 3, 2)
    text = (synthetic_board / README).read_text()
    table = table_lines(text)
    # one track (no row names one: all are the paper's), sorted by MPJPE all
    assert [line.split(" | ")[0][2:] for line in table] == [
        "HOPE-Net, HUP-3D paper (backbone and input size not stated)",
        "ResNet-50 baseline, HUP-3D paper (input size not stated)",
        "HOPE-Net (ResNet-50, 224 px)", "ResNet-50 regressor (224 px)", "HOPE-Net (ResNet-10, 64 px)"]
    assert text.count("## Track: ") == 1 and "## Track: Unseen grasps (`unseen_grasps`)" in text
    assert table[2] == ("| HOPE-Net (ResNet-50, 224 px) | measured | hupbench default | `cdcdcdcdcdcd` | 128 | 12.35 | "
                        "10.46 [—] | 8.00 [—] | 16.90 [—] | — | 15.90 | 4.57 | 0.812 | 0.90 / 1.01 / 0.46 | 20.0 h, 1x H100 | 80.00 | "
                        "150.00 | `python train.py run_name=slow_big` |")
    assert table[3].endswith("| 5.0 h | — | 40.00 | `python train.py run_name=torch_only` |")
    assert table[4].split(" | ")[14] == "25 min, 1x H100"
    assert table[0] == ("| HOPE-Net, HUP-3D paper (backbone and input size not stated) | reported in paper | "
                        "HUP-3D (paper) | — | — | — | 8.65 [—] | 5.33 [—] | 17.05 [—] | " + " | ".join(["—"] * 9) + " |")
    # each row names the grasps its test data were rendered from
    assert ("- test data: hupbench default, split `test`, 5760 frames, manifest sha256 `abababababab`, grasps sha256 "
            "`cdcdcdcdcdcd`") in text
    # no results file here has a floor or a grasp breakdown: the README says so instead of a number
    assert "Split floor: — for every row here" in text
    assert text.count("Per grasp: — (the results file records no grasp breakdown") == 3
    assert ("- probe MPJPE with the corners matched under the half turn about the probe's long axis where closer: "
            "15.90 mm (plain: 16.90 mm)") in text
    assert ("- spread ratio of predicted to true 3D keypoints across the test frames, x / y / z: 0.90 / 1.01 / 0.46; "
            "below 0.5 on z: the predictions barely vary along that axis (collapsed)") in text
    assert "(21 × 5.33 + 8 × 17.05) / 29 = 8.56 mm, which is not the row's all (8.65 mm)" in text
    # a measured row whose all is the keypoint-weighted mean is not flagged
    assert "/ 29 = 30.00 mm\n" in text and "not the row's all (30.00 mm)" not in text


def test_floor_and_per_grasp_table(synthetic_board):
    path = synthetic_board / "results" / "slow_big.json"
    write_results(path, with_grasps(load_results(path)))
    run_leaderboard(synthetic_board)
    text = (synthetic_board / README).read_text()
    # the floor beside the row, and named plainly above the table
    row = next(line for line in table_lines(text) if line.startswith("| HOPE-Net (ResNet-50, 224 px)"))
    # each MPJPE and floor with its 95 % interval over the test grasps
    assert row.split(" | ")[6:11] == ["10.46 [10.9-13.8]", "8.00 [9.0-11.0]", "16.90 [16.0-22.0]",
                                      "20.00 [15.0-25.0] / 40.00 [30.0-50.0] / 25.52 [19.1-31.9]", "15.90"]
    assert ("Split floor, hand / probe / all (mm; column *split floor*) [95 % CI over the test grasps]: nearest "
            "training grasp under the true camera: a model that only recognises training grasps cannot do better "
            "than this.") in text
    assert ("- hupbench default (manifest sha256 `abababababab`), test split: 20.00 [15.0-25.0] / 40.00 [30.0-50.0] / "
            "25.52 [19.1-31.9]\n") in text
    assert ("- 95 % CI over the 2 test grasps (10,000 bootstrap resamples of the grasps, seed 0), hand / probe / all "
            "(mm): MPJPE 8.00 [9.0-11.0] / 16.90 [16.0-22.0] / 10.46 [10.9-13.8]; split floor 20.00 [15.0-25.0] / "
            "40.00 [30.0-50.0] / 25.52 [19.1-31.9]\n") in text.split("(`slow_big`)")[1]
    # the per-grasp table in the row's details, grasps by id, with orientation, frames, MPJPE and floor
    details = text.split("(`slow_big`)")[1].split("\n### ")[0]
    assert ("| grasp | Theta_Vol x, y, z (deg) | frames | MPJPE hand (mm) | MPJPE probe (mm) | MPJPE all (mm) | "
            "floor hand / probe / all (mm) | nearest training grasp |") in details
    assert "| 3 | 0, 0, 180 | 2000 | 9.00 | 16.00 | 10.93 | 15.00 / 30.00 / 19.14 | 0 |\n" in details
    assert "| 12 | — | 3760 | 11.50 | 22.25 | 14.47 | 25.00 / 50.00 / 31.90 | 1 |\n" in details
    assert details.index("| 3 | 0, 0, 180") < details.index("| 12 | —")
    assert ("MPJPE by probe orientation Theta_Vol, hand / probe / all (mm): theta_vol_z=180 9.00 / 16.00 / 10.93 "
            "(2000 frames); unknown 11.50 / 22.25 / 14.47 (3760 frames).") in details
    assert "Per grasp: —" not in details
    # rows without them still say what they lack
    assert "Per grasp: — (the results file records no grasp breakdown" in text.split("(`fast_small`)")[1]


def test_grasp_rows_show_what_a_row_has():
    row = with_grasps(measured("r", "r", 1.0, 1.0, 1.0, None, None, None, log=False))
    row["split_floor"]["per_grasp"]["12"]["nearest_train_grasp_id"] = None
    del row["breakdowns"]["grasp"]["12"]
    row["dataset"]["grasp_theta_vol_deg"] = None
    assert grasp_rows(row) == [["3", "—", "2000", "9.00", "16.00", "10.93", "15.00 / 30.00 / 19.14", "0"],
                               ["12", "—", "—", "—", "—", "—", "25.00 / 50.00 / 31.90", "—"]]
    row["split_floor"] = None
    assert grasp_rows(row) == [["3", "—", "2000", "9.00", "16.00", "10.93", "—", "—"]]
    del row["breakdowns"]["grasp"]
    assert grasp_rows(row) == []


def test_two_tracks_make_two_tables(synthetic_board):
    views = with_grasps(measured("views_net", "HUPNet (ResNet-18, 128 px)", 146 / 29, 4.0, 7.75, 3.0, 6.0, 600.0,
                                 log=False),
                        track="unseen_views", floor_kind="nearest_train_view")
    views["split_floor"]["floor_mm"] = triplet(2.0, 4.0)
    views["split_floor"]["nearest_train_view_mm"] = triplet(2.0, 4.0)
    write_results(synthetic_board / "results" / "views_net.json", views)
    grasps = synthetic_board / "results" / "slow_big.json"
    write_results(grasps, with_grasps(load_results(grasps)))
    result = run_leaderboard(synthetic_board)
    assert (result["rows"], result["measured"], result["reported"]) == (6, 4, 2)
    text = (synthetic_board / README).read_text()
    assert ("6 rows (4 measured, 2 reported) in 2 tracks: Unseen grasps (`unseen_grasps`), Unseen views "
            "(`unseen_views`).") in text
    assert text.count("## Track: ") == 2
    assert text.index("## Track: Unseen grasps") < text.index("## Track: Unseen views") < text.index("## What the")
    # row details follow the tables: the unseen-views row last, though its MPJPE is the lowest
    details = text.split("## Row details")[1]
    assert details.index("(`paper_hopenet`)") < details.index("(`fast_small`)") < details.index("(`views_net`)")
    unseen_grasps, unseen_views = table_lines(text, "Unseen grasps"), table_lines(text, "Unseen views")
    # the paper's rows and rows without a track are in the paper's track; the unseen-views row alone in its own
    assert [line.split(" | ")[0][2:] for line in unseen_grasps] == [
        "HOPE-Net, HUP-3D paper (backbone and input size not stated)",
        "ResNet-50 baseline, HUP-3D paper (input size not stated)",
        "HOPE-Net (ResNet-50, 224 px)", "ResNet-50 regressor (224 px)", "HOPE-Net (ResNet-10, 64 px)"]
    assert [line.split(" | ")[0][2:] for line in unseen_views] == ["HUPNet (ResNet-18, 128 px)"]
    assert unseen_views[0].split(" | ")[6:10] == ["5.03 [10.9-13.8]", "4.00 [9.0-11.0]", "7.75 [16.0-22.0]",
                                                  "2.00 [15.0-25.0] / 4.00 [30.0-50.0] / 2.55 [19.1-31.9]"]
    views_section = text.split("## Track: Unseen views")[1].split("\n## ")[0]
    assert "1 row (1 measured, 0 reported)" in views_section
    assert ("Split floor, hand / probe / all (mm; column *split floor*) [95 % CI over the test grasps]: nearest "
            "training view of the same grasp and distance under the true camera: a model that only recalls training views cannot do better than this.") \
        in views_section
    grasps_section = text.split("## Track: Unseen grasps")[1].split("\n## ")[0]
    assert "nearest training grasp under the true camera" in grasps_section and "training view" not in grasps_section
    assert "5 rows (3 measured, 2 reported)" in grasps_section


def test_table_cells_escape_pipes_and_newlines():
    row = measured("r", "a | b\nc", 1.0, 1.0, 1.0, None, None, None, hardware=None, log=False)
    cells = table_row(row)
    assert cells[0] == "a \\| b c"
    assert cells[14] == "—" and cells[15] == "—"  # no training time, no ONNX latency
    assert cells[9] == "—"  # no split floor
    assert cells[3] == "`cdcdcdcdcdcd`"  # the grasps' sha256


@pytest.mark.parametrize("seconds, text", [(None, "—"), (42.4, "42 s"), (59.9, "60 s"), (60.0, "1 min"),
                                           (2100.0, "35 min"), (3600.0, "1.0 h"), (9000.0, "2.5 h")])
def test_format_duration(seconds, text):
    assert format_duration(seconds) == text


def test_latency_prefers_onnxruntime():
    assert inference_latency_ms(measured("a", "a", 1, 1, 1, 3.0, 9.0, None)) == (3.0, "ONNX Runtime")
    assert inference_latency_ms(measured("a", "a", 1, 1, 1, None, 9.0, None)) == (9.0, "PyTorch")
    assert inference_latency_ms(measured("a", "a", 1, 1, 1, None, None, None)) == (None, None)


# ----------------------------------------------------------------------------- pure functions

def test_pareto_front_known_answer():
    points = [(10.0, 5.0),   # 0: front (slowest, most accurate)
              (2.0, 30.0),   # 1: front (fastest)
              (5.0, 12.0),   # 2: front
              (6.0, 12.0),   # 3: dominated by 2 (slower, same error)
              (5.0, 20.0),   # 4: dominated by 2 (same speed, worse)
              (12.0, 6.0),   # 5: dominated by 0
              (5.0, 12.0)]   # 6: duplicate of 2: neither dominates the other
    assert pareto_front(points) == [1, 2, 6, 0]
    assert pareto_front([]) == []
    assert pareto_front([(1.0, 1.0)]) == [0]


def test_read_validation_curve(tmp_path):
    log = tmp_path / "m.jsonl"
    write_log(log, 100.0, 10.0, n=2)
    assert read_validation_curve(log) == [(50.0, 30.0), (100.0, 20.0)]


@pytest.mark.parametrize("content, message", [
    ('{"event": "val", "step": 0, "train_wall_s": 1.0}\n', r"m.jsonl:1: validation line needs val_mpjpe_mm\['all'\]"),
    ('{"event": "train", "step": 0}\n{"event": "val", "step": 0, "train_wall_s": -1, "val_mpjpe_mm": {"all": 1}}\n',
     r"m.jsonl:2: validation line needs train_wall_s as a finite number from 0 to 1e\+08, got -1"),
    ('{"event": "val", "step": 0, "train_wall_s": 1, "val_mpjpe_mm": {"all": 1e308}}\n',
     r"m.jsonl:1: validation line needs val_mpjpe_mm\['all'\] as a finite number from 0 to 10000, got 1e\+308"),
    ('{"event": "train", "step": 0}\nnot json\n', r"m.jsonl:2: not valid JSON: Expecting value"),
    ('{"event": "train", "step": 0, "step": 1}\n', r"m.jsonl:1: not valid JSON: an object names the key\(s\) "
                                                   r"\['step'\] twice"),
    ('[1, 2]\n', r"m.jsonl:1: expected a JSON object, got list"),
    ('{"event": "train", "step": 0}\n', r"m.jsonl: no validation lines"),
    ('{"event": "train"}\n', r"m.jsonl:1: 'step' must be a whole number >= 0, got None"),
    ('{"event": "train", "step": "10"}\n', r"m.jsonl:1: 'step' must be a whole number >= 0, got '10'"),
    ('{"event": "train", "step": 20}\n{"event": "train", "step": 30}\n{"event": "train", "step": 10}\n',
     r"m.jsonl:3: 'train' step 10 comes after step 30 \(lines 2 and 3\): two trainings wrote to this log, or it "
     r"was edited; keep one run's lines in order"),
    ('{"event": "train", "step": 20}\n{"event": "train", "step": 20}\n',
     r"m.jsonl:2: 'train' step 20 is logged twice \(lines 1 and 2\)"),
])
def test_bad_log_is_named(tmp_path, content, message):
    log = tmp_path / "m.jsonl"
    log.write_text(content)
    with pytest.raises(ValueError, match=message):
        read_validation_curve(log)


# ----------------------------------------------------------------------------- bad results files

def test_version_1_rows_show_the_new_metrics_as_missing(synthetic_board):
    path = synthetic_board / "results" / "slow_big.json"
    data = json.loads(path.read_text())
    data["schema_version"] = 1
    del data["metrics"]["probe_symmetric_mpjpe_mm"], data["metrics"]["spread_ratio"]
    del data["track"], data["split_floor"], data["dataset"]["grasp_theta_vol_deg"], data["dataset"]["grasps_sha256"]
    del data["intervals"]
    data["dataset"]["path"] = "/data/hupbench_out/dataset"
    path.write_text(json.dumps(data))
    run_leaderboard(synthetic_board)
    text = (synthetic_board / README).read_text()
    row = next(line for line in text.splitlines() if line.startswith("| HOPE-Net (ResNet-50, 224 px)"))
    cells = row.split(" | ")
    assert cells[3] == "—"  # the grasps' sha256: not recorded then
    assert cells[6:14] == ["10.46 [—]", "8.00 [—]", "16.90 [—]", "—", "—", "4.57", "0.812", "—"]
    assert ("- 95 % CI over the test grasps: — (the results file records neither intervals nor a per-grasp breakdown "
            "to recompute them from: it was written before results schema version 3; `hupbench eval` adds them)\n") \
        in text.split("(`slow_big`)")[1]
    assert "15.90 mm (plain" not in text and "spread ratio of predicted to true 3D keypoints across the test" not in \
        text.split("(`slow_big`)")[1].split("###")[0]


def test_spread_constants_match_the_metrics():
    from hupbench.evaluation import leaderboard_table as leaderboard
    from hupbench import metrics

    assert leaderboard.SPREAD_AXES == metrics.SPREAD_AXES
    assert leaderboard.SPREAD_RATIO_WARN == metrics.SPREAD_RATIO_WARN


def test_wrong_schema_version_is_rejected_with_its_name(synthetic_board):
    path = synthetic_board / "results" / "slow_big.json"
    data = json.loads(path.read_text())
    data["schema_version"] = 6
    path.write_text(json.dumps(data))
    with pytest.raises(ValueError, match=r"slow_big\.json: results\['schema_version'\] must be 5"):
        run_leaderboard(synthetic_board)
    assert not (synthetic_board / README).exists()  # nothing written


def test_cli_reports_bad_file(synthetic_board, capsys):
    (synthetic_board / "results" / "broken.json").write_text("{")
    assert main(["leaderboard", "--dir", str(synthetic_board)]) == 1
    err = capsys.readouterr().err
    assert err.startswith("hupbench leaderboard: error: ") and "broken.json: not valid JSON" in err


def test_cli_rebuilds(synthetic_board, capsys):
    assert main(["leaderboard", "--dir", str(synthetic_board)]) == 0
    out = capsys.readouterr().out
    assert "5 rows (3 measured, 2 reported)" in out
    assert all((synthetic_board / name).is_file() for name in OUTPUTS)


def _edit(board: Path, name: str, edit) -> None:
    path = board / "results" / f"{name}.json"
    data = json.loads(path.read_text())
    edit(data)
    path.write_text(json.dumps(data))


@pytest.mark.parametrize("edit, message", [
    (lambda d: d.update(run_name="other"), (r"slow_big\.json: results\['run_name'\] must equal the file stem "
     r"'slow_big', got 'other' \(rename the file to other\.json, or rerun hupbench eval with --out .*slow_big\.json\)")),
    (lambda d: d["dataset"].update(split="val"), (r"slow_big\.json: the leaderboard compares test-split results, .*"
     r"\(rerun hupbench eval with --split test --out .*slow_big\.json, or move the file out of .*results\)")),
    (lambda d: d["training"].update(command=None), (r"slow_big\.json: a measured row must name the command that "
     r"reproduces it in results\['training'\]\['command'\], got None: rerun hupbench eval MODEL DATASET --out "
     r".*slow_big\.json --training-command 'COMMAND THAT TRAINED IT'")),
])
def test_rows_the_leaderboard_refuses(synthetic_board, edit, message):
    _edit(synthetic_board, "slow_big", edit)
    with pytest.raises(ValueError, match=message):
        load_rows(synthetic_board / "results")


def test_missing_log_is_named(synthetic_board):
    (synthetic_board / "logs" / "fast_small.jsonl").unlink()
    with pytest.raises(FileNotFoundError, match=r"results/fast_small\.json: training log not found: .*fast_small\.jsonl"):
        run_leaderboard(synthetic_board)


def test_empty_or_missing_folder(tmp_path):
    with pytest.raises(FileNotFoundError, match="has no results/ folder"):
        run_leaderboard(tmp_path)
    (tmp_path / "results").mkdir()
    with pytest.raises(ValueError, match=r"no results files \(\*\.json\)"):
        run_leaderboard(tmp_path)


def test_write_together_raises_rather_than_loops(tmp_path):
    """An error that no enclosing writer explains (a folder in a file's place) reaches the caller, once: the
    unwrapping of explained errors stops at an error that is its own cause. A fresh process with a timeout,
    as the fault was an endless loop."""
    (tmp_path / "b.png").mkdir()
    code = ("from pathlib import Path\n"
            "from hupbench.evaluation.leaderboard import _write_together\n"
            "try:\n"
            f"    _write_together(Path({str(tmp_path)!r}), {{'a.md': b'new', 'b.png': b'new', 'c.png': b'new'}})\n"
            "except OSError as exc:\n"
            "    print('RAISED', exc)\n")
    try:
        done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60,
                              cwd=REPO)
    except subprocess.TimeoutExpired:
        pytest.fail("_write_together did not return within 60 s")
    assert done.returncode == 0 and "RAISED" in done.stdout and "b.png" in done.stdout, done.stderr
    assert not (tmp_path / "a.md").exists() and not list(tmp_path.glob(".*.tmp*"))


def test_latency_axis_is_honest():
    """From 0 on a linear axis: 0.07 ms between two rows is drawn as the small difference it is, not zoomed
    onto; a log axis only where the latencies span more than LATENCY_LOG_RATIO times."""
    from hupbench.evaluation.leaderboard_plots import LATENCY_LOG_RATIO, latency_axis

    assert latency_axis([3.60, 3.67]) == ("linear", 0.0, pytest.approx(3.67 * 1.15))
    assert latency_axis([3.7]) == ("linear", 0.0, pytest.approx(3.7 * 1.15))
    assert latency_axis([1.0, 1.0 * LATENCY_LOG_RATIO * 1.5]) == ("log", 0.5, pytest.approx(60.0))
    assert latency_axis([]) == ("log", 1.0, 1000.0)


def test_error_axis_turns_log_where_a_row_diverged():
    """The test errors of the paper protocol's rows (8.65 to 46.88 mm) stay on a linear axis from 0; a row whose
    hand fit diverged to metres (the clinic track's 5,412 mm) beside them puts the axis on a log scale that shows
    both, instead of squashing every other row onto its floor."""
    import matplotlib.pyplot as plt

    from hupbench.evaluation.leaderboard_plots import LATENCY_LOG_RATIO, _error_axis

    fig, ax = plt.subplots()
    try:
        _error_axis(ax, [8.65, 9.88, 46.88], LATENCY_LOG_RATIO)
        assert ax.get_yscale() == "linear" and ax.get_ylim() == pytest.approx((0.0, 46.88 * 1.2))
        _error_axis(ax, [8.65, 9.88, 46.88, 5411.97], LATENCY_LOG_RATIO)
        assert ax.get_yscale() == "log" and ax.get_ylim() == pytest.approx((8.65 / 1.3, 5411.97 * 1.3))
    finally:
        plt.close(fig)


def test_one_measured_row_draws_no_pareto_frontier(synthetic_board, monkeypatch):
    """A frontier of one row is no line: its legend entry is left out (it named an invisible line)."""
    from matplotlib.axes import Axes

    from hupbench.evaluation.leaderboard_plots import plot_latency

    rows = load_rows(synthetic_board / "results")
    labels = []
    original = Axes.legend

    def spy(self, *args, **kwargs):
        labels.extend(self.get_legend_handles_labels()[1])
        return original(self, *args, **kwargs)

    monkeypatch.setattr(Axes, "legend", spy)
    measured_rows = [r for r in rows if r["kind"] == "measured"]
    plot_latency([r for r in rows if r["kind"] == "reported"] + measured_rows[:1])
    assert not any("Pareto" in label for label in labels)
    labels.clear()
    plot_latency(rows)
    # (2 ms, 30 mm), (40 ms, 12 mm), (80 ms, 10.456 mm): each is faster or better than the others
    assert [label for label in labels if "Pareto" in label] == ["Pareto frontier (3 of 3 rows)"]


def test_clinic_rows_get_their_own_table_floor_and_intervals(synthetic_board):
    """A clinic row (a floor kind of its own) goes under its own heading with its own floor, each with its interval."""
    clinic = with_grasps(measured("clinic_net", "HUPNet (ResNet-18, 128 px)", 146 / 29, 4.0, 7.75, 3.0, 6.0, 600.0,
                                  log=False), track="clinic", floor_kind="nearest_train_frame")
    write_results(synthetic_board / "results" / "clinic_net.json", clinic)
    run_leaderboard(synthetic_board)
    text = (synthetic_board / README).read_text()
    assert "## Track: Clinic (`clinic`)" in text and text.count("## Track: ") == 2
    clinic_rows = table_lines(text, "Clinic")
    assert [line.split(" | ")[0][2:] for line in clinic_rows] == ["HUPNet (ResNet-18, 128 px)"]
    assert clinic_rows[0].split(" | ")[6:10] == ["5.03 [10.9-13.8]", "4.00 [9.0-11.0]", "7.75 [16.0-22.0]",
                                                 "20.00 [15.0-25.0] / 40.00 [30.0-50.0] / 25.52 [19.1-31.9]"]
    section = text.split("## Track: Clinic")[1].split("\n## ")[0]
    assert "[95 % CI over the test grasps]: nearest training frame of any grasp and view" in section
    assert "nearest training grasp" not in section
    # the paper protocol's table keeps its rows, with no interval recorded ([—])
    assert "HUPNet (ResNet-18, 128 px)" not in "\n".join(table_lines(text, "Unseen grasps"))
    assert table_lines(text, "Unseen grasps")[2].split(" | ")[6] == "10.46 [—]"


def test_rows_before_intervals_get_them_recomputed_from_their_grasp_breakdown(synthetic_board):
    """A version-4 row records no interval but each grasp's mean error and frames: the leaderboard prints the
    interval eval would have written. With two grasps the 95 % interval spans the two grasps' values."""
    path = synthetic_board / "results" / "slow_big.json"
    data = with_grasps(load_results(path))
    recorded = copy.deepcopy(data)
    data["schema_version"] = 4
    del data["intervals"]
    path.write_text(json.dumps(data))
    (row,) = [r for r in load_rows(synthetic_board / "results") if r["run_name"] == "slow_big"]
    assert row["intervals_from"] == "breakdown"
    expected = split_intervals_of(recorded)
    assert {k: v for k, v in row["intervals"].items() if not k.endswith("_mm")} == \
        {k: v for k, v in expected.items() if not k.endswith("_mm")}
    for block in ("mpjpe_mm", "split_floor_mm"):
        for part in ("all", "hand", "probe"):
            assert row["intervals"][block][part] == pytest.approx(expected[block][part], abs=1e-9)
    run_leaderboard(synthetic_board)
    text = (synthetic_board / README).read_text()
    line = next(line for line in table_lines(text) if line.startswith("| HOPE-Net (ResNet-50, 224 px)"))
    assert line.split(" | ")[6:10] == ["10.46 [10.9-14.5]", "8.00 [9.0-11.5]", "16.90 [16.0-22.2]",
                                       "20.00 [15.0-25.0] / 40.00 [30.0-50.0] / 25.52 [19.1-31.9]"]
    assert ("- 95 % CI over the 2 test grasps (10,000 bootstrap resamples of the grasps, seed 0; recomputed from the "
            "results file's per-grasp breakdown, each grasp's mean error and frames, with `hupbench eval`'s draws), "
            "hand / probe / all (mm): MPJPE 8.00 [9.0-11.5] / 16.90 [16.0-22.2] / 10.46 [10.9-14.5]; split floor "
            "20.00 [15.0-25.0] / 40.00 [30.0-50.0] / 25.52 [19.1-31.9]\n") in text.split("(`slow_big`)")[1]
    # a row that records its intervals keeps them; the papers' rows have nothing to recompute from
    write_results(path, recorded)
    rows = {r["run_name"]: r for r in load_rows(synthetic_board / "results")}
    assert rows["slow_big"]["intervals_from"] == "results" and rows["slow_big"]["intervals"] == intervals_block()
    assert rows["paper_hopenet"]["intervals"] is None and rows["paper_hopenet"]["intervals_from"] is None


def split_intervals_of(row: dict) -> dict:
    """The intervals eval writes for frames whose errors are each grasp's mean in ``row``'s breakdown."""
    grasps = sorted(row["breakdowns"]["grasp"], key=int)
    frames = [row["breakdowns"]["grasp"][g]["frames"] for g in grasps]
    errors = np.concatenate([np.tile(np.r_[[row["breakdowns"]["grasp"][g]["mpjpe_mm"]["hand"]] * 21,
                                           [row["breakdowns"]["grasp"][g]["mpjpe_mm"]["probe"]] * 8], (n, 1))
                             for g, n in zip(grasps, frames)])                                   # (N, 29) mm
    grasp_id = np.repeat([int(g) for g in grasps], frames)                                        # (N,)
    return split_intervals(errors, grasp_id, row["split_floor"], RESAMPLES, SEED)


def test_committed_rows_print_intervals_recomputed_from_their_breakdown():
    """The committed rows that predate intervals (schema < 5) print them recomputed from their breakdown, the rows
    eval wrote since (the clinic track's, the best paper-protocol row's) their own; a recomputed row's probe and
    floor intervals, and the best row's."""
    rows = {r["run_name"]: r for r in load_rows(COMMITTED / "results")}
    older = rows["paper_hupnet_fit_cpu"]
    assert older["intervals_from"] == "breakdown" and older["intervals"]["grasps"] == 2
    assert interval_text(older["intervals"]["mpjpe_mm"]["probe"]) == "[7.7-29.5]"
    assert interval_text(older["intervals"]["split_floor_mm"]["probe"]) == "[53.0-65.6]"
    best = rows["paper_hupnet_handfit_cpu"]
    assert best["intervals_from"] == "results" and best["intervals"]["grasps"] == 2
    assert interval_text(best["intervals"]["mpjpe_mm"]["probe"]) == "[6.3-28.5]"
    for row in rows.values():
        recorded = json.loads((COMMITTED / "results" / f"{row['run_name']}.json").read_text())["schema_version"] >= 5
        expected = None if row["kind"] != "measured" else "results" if recorded else "breakdown"
        assert row["intervals_from"] == expected, row["run_name"]
    assert rows["clinic_hupnet_handfit_2k_cpu"]["intervals_from"] == "results"
    text = (COMMITTED / README).read_text()
    line = next(line for line in table_lines(text) if "`bash scripts/paper_protocol.sh paper_hupnet_fit_cpu`" in line)
    assert line.split(" | ")[8:10] == ["18.62 [7.7-29.5]", "8.17 [6.5-9.9] / 59.30 [53.0-65.6] / 22.27 [19.3-25.2]"]
