"""The leaderboard's depth sensor table (hupbench.evaluation.leaderboard_robustness): robustness rows go beside their
model's row, one column per sensor, and a file that belongs to no model, names no sensor, is of another dataset or
repeats a sensor is refused naming it."""

from __future__ import annotations

import copy
import json
import shutil
from pathlib import Path

import pytest

from hupbench.core.errors import BadValueError
from hupbench.evaluation.leaderboard import README, run_leaderboard
from hupbench.evaluation.leaderboard_table import number_cell

COMMITTED = Path(__file__).resolve().parents[3] / "leaderboard"
BASE = "clinic_hupnet_handfit_2k_cpu"  # a row of the current results schema


def robustness_row(sensor: str, **dataset) -> dict:
    """The committed clinic row as if evaluated again under ``sensor``."""
    row = json.loads((COMMITTED / "results" / f"{BASE}.json").read_text())
    row = copy.deepcopy(row)
    row["run_name"] = f"{BASE}_{sensor}"
    row["dataset"]["depth_sensor"] = sensor
    row["dataset"].update(dataset)
    return row


def board(tmp_path, *rows: dict) -> Path:
    root = tmp_path / "leaderboard"
    shutil.copytree(COMMITTED, root)
    shutil.rmtree(root / "robustness", ignore_errors=True)
    (root / "robustness").mkdir()
    for row in rows:
        (root / "robustness" / f"{row['run_name']}.json").write_text(json.dumps(row))
    return root


def test_robustness_rows_make_one_row_per_model_and_a_column_per_sensor(tmp_path):
    root = board(tmp_path, robustness_row("none"), robustness_row("hololens2_ahat"))
    run_leaderboard(root)
    text = (root / README).read_text()
    section = text[text.index("## Robustness to the depth camera"):]
    section = section[: section.index("\n## ")]
    lines = [line for line in section.splitlines() if line.startswith("| ")]
    assert lines[0].startswith("| Model | Track | Split floor | `none` | `azure_kinect_nfov` | `hololens2_ahat` |")
    assert len(lines) == 2  # the header and one model
    cells = lines[1].split(" | ")
    assert "bash scripts/paper_protocol.sh clinic_hupnet_handfit_2k_cpu" in lines[1]
    all_mm = json.loads((COMMITTED / "results" / f"{BASE}.json").read_text())["metrics"]["mpjpe_mm"]["all"]
    assert cells[3].split(" / ")[2].startswith(f"{number_cell(all_mm)} [")  # hand / probe / all: all last
    assert cells[5] == cells[3]
    assert cells[4] == "—"  # no Azure Kinect file


@pytest.mark.parametrize("change, message", [
    (lambda row: row["dataset"].pop("depth_sensor"), "depth_sensor'] is missing"),
    (lambda row: row["training"].update(command="python train.py"), "no measured row of results/ has its training"),
    (lambda row: row["dataset"].update(manifest_sha256="0" * 64), "another dataset"),
])
def test_a_robustness_row_that_fits_no_model_is_refused_naming_it(tmp_path, change, message):
    odd = robustness_row("hololens2_ahat")
    change(odd)
    root = board(tmp_path, robustness_row("none"), odd)
    before = (root / README).read_bytes()
    with pytest.raises(BadValueError, match=message) as error:
        run_leaderboard(root)
    assert f"{BASE}_hololens2_ahat.json" in str(error.value)
    assert (root / README).read_bytes() == before


def test_one_model_under_one_sensor_twice_is_refused(tmp_path):
    twin = robustness_row("hololens2_ahat")
    twin["run_name"] = f"{BASE}_ahat_again"
    root = board(tmp_path, robustness_row("hololens2_ahat"), twin)
    with pytest.raises(BadValueError, match="under hololens2_ahat twice"):
        run_leaderboard(root)


@pytest.mark.parametrize("sensor, suffix", [("hololens2_ahat", ", hololens2_ahat depth"), ("none", ""), (None, "")])
def test_a_row_that_read_a_sensor_s_depth_says_so_in_its_label(sensor, suffix):
    """Two rows of one model on one dataset, one on the clean z-buffer and one through a depth camera, are told apart
    by their label in the tables and the plots."""
    from hupbench.evaluation.leaderboard_table import plot_label, row_label, table_row

    row = robustness_row(sensor or "none")
    if sensor is None:
        row["dataset"].pop("depth_sensor")
    assert row_label(row) == row["model"]["label"] + suffix
    assert table_row(row)[0] == row["model"]["label"] + suffix
    assert plot_label(row).startswith(row["model"]["label"] + suffix + ", ")   # the clinic track's name after it
