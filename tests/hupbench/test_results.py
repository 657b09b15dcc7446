"""The results schema: valid rows pass, every kind of bad field is named by its path."""

import json
import math

import pytest

from hupbench.results import (
    SCHEMA_VERSION,
    blank_results,
    load_results,
    validate_results,
    write_results,
)


def measured_row(run_name="hopenet_r18_128"):
    d = blank_results("measured", run_name)
    d["model"] |= {"name": "hopenet", "label": "HOPE-Net (ResNet-18, 128 px)", "config": {"backbone": "resnet18"},
                   "parameters": 11_700_000, "flops": 1_200_000_000, "input_size": 128, "format": "onnx"}
    d["dataset"] |= {"path": "/data/hup", "manifest_sha256": "ab" * 32, "frames": 5760,
                     "name": "hupbench default (31,680 frames)"}
    d["metrics"] = {"mpjpe_mm": {"all": 12.5, "hand": 10.0, "probe": 19.0, "all_averaging": "keypoint-weighted"},
                    "root_relative_hand_mpjpe_mm": 8.0, "pa_mpjpe_hand_mm": 5.5, "pck_auc_0_50mm": 0.75,
                    "pixel_error_px": 3.2}
    d["breakdowns"] = {"z_ego": {"0.5 m": {"frames": 2880, "mpjpe_mm": {"all": 11.0, "hand": 9.0, "probe": 16.0}}}}
    d["latency_ms_per_image"] = {"pytorch": {"batch1": 20.0, "batch32": 8.0},
                                 "onnxruntime": {"batch1": 10.0, "batch32": None}}
    d["device"] = "cpu: 2 threads"
    d["training"] = {"wall_s": 3600.0, "hardware": "1x H100", "samples_seen": 200_000, "epochs": 10.0,
                     "command": "python train.py model=hopenet", "log": f"logs/{run_name}.jsonl"}
    d["git_commit"] = "0" * 40
    d["created_utc"] = "2025-01-01T00:00:00Z"
    return d


def reported_row():
    d = blank_results("reported", "paper_x")
    d["model"] |= {"name": "HOPE-Net", "label": "HOPE-Net (paper)"}
    d["dataset"]["name"] = "HUP-3D (paper)"
    d["metrics"]["mpjpe_mm"] |= {"all": 8.65, "all_averaging": "unknown"}
    d["source"] = "Birlo et al."
    return d


def test_valid_rows_pass_and_return_themselves():
    for row in (measured_row(), reported_row()):
        assert validate_results(row) is row


def test_blank_is_fresh_and_incomplete():
    a, b = blank_results("measured", "r"), blank_results("measured", "r")
    a["model"]["name"] = "x"
    assert b["model"]["name"] is None
    assert a["schema_version"] == SCHEMA_VERSION == 1
    with pytest.raises(ValueError, match=r"results\['model'\]\['label'\] must be a non-empty string, got None"):
        validate_results(a)
    with pytest.raises(ValueError, match="kind must be one of"):
        blank_results("quoted", "r")


def _set(d, path, value):
    for key in path[:-1]:
        d = d[key]
    d[path[-1]] = value


def _delete(d, path):
    for key in path[:-1]:
        d = d[key]
    del d[path[-1]]


@pytest.mark.parametrize("path, value, message", [
    (("metrics", "mpjpe_mm", "hand"), "x",
     r"results\['metrics'\]\['mpjpe_mm'\]\['hand'\] must be a finite number >= 0 or null, got 'x'"),
    (("metrics", "mpjpe_mm", "all"), None, r"results\['metrics'\]\['mpjpe_mm'\]\['all'\] must be a finite number"),
    (("metrics", "mpjpe_mm", "all"), -1.0, r"\['all'\] must be a finite number >= 0, got -1.0"),
    (("metrics", "mpjpe_mm", "all"), math.nan, r"\['all'\] must be a finite number >= 0, got nan"),
    (("metrics", "mpjpe_mm", "probe"), math.inf, r"\['probe'\] must be .* got inf"),
    (("metrics", "mpjpe_mm", "probe"), True, r"\['probe'\] must be .* got True"),
    (("metrics", "pck_auc_0_50mm"), 1.5, r"\['pck_auc_0_50mm'\] must be a finite number in \[0, 1\] or null, got 1.5"),
    (("latency_ms_per_image", "onnxruntime", "batch1"), -0.1,
     r"results\['latency_ms_per_image'\]\['onnxruntime'\]\['batch1'\] must be"),
    (("kind",), "quoted", r"results\['kind'\] must be one of 'measured', 'reported', got 'quoted'"),
    (("model", "format"), "tflite", r"results\['model'\]\['format'\] must be one of 'pytorch', 'onnx' or null"),
    (("model", "parameters"), 1.5, r"results\['model'\]\['parameters'\] must be an integer >= 0 or null, got 1.5"),
    (("model", "input_size"), 0, r"results\['model'\]\['input_size'\] must be an integer >= 1 or null, got 0"),
    (("model", "config"), [1], r"results\['model'\]\['config'\] must be a dict or null"),
    (("dataset", "split"), "holdout", r"results\['dataset'\]\['split'\] must be one of 'train', 'val', 'test'"),
    (("dataset", "frames"), True, r"results\['dataset'\]\['frames'\] must be an integer"),
    (("run_name",), "../evil", r"results\['run_name'\] must be a file stem matching"),
    (("run_name",), "has space", r"results\['run_name'\] must be a file stem"),
    (("run_name",), ".hidden", r"results\['run_name'\] must be a file stem"),
    (("training", "log"), "/abs/log.jsonl", r"results\['training'\]\['log'\] must be a path relative to leaderboard/"),
    (("training", "log"), "../x.jsonl", r"results\['training'\]\['log'\] must be a path relative"),
    (("training", "command"), "", r"results\['training'\]\['command'\] must be a non-empty string or null"),
    (("breakdowns", "z_ego", "0.5 m", "frames"), -3,
     r"results\['breakdowns'\]\['z_ego'\]\['0.5 m'\]\['frames'\] must be an integer >= 0, got -3"),
    (("breakdowns", "colour"), {}, r"results\['breakdowns'\] has unknown key\(s\) \['colour'\]"),
    (("model",), "hopenet", r"results\['model'\] must be a dict, got 'hopenet'"),
    (("extra",), 1, r"results has unknown key\(s\) \['extra'\]"),
    (("schema_version",), 2, r"results\['schema_version'\] must be 1 .* got 2"),
    (("schema_version",), "1", r"results\['schema_version'\] must be 1 .* got '1'"),
])
def test_bad_field_is_named(path, value, message):
    row = measured_row()
    _set(row, path, value)
    with pytest.raises(ValueError, match=message):
        validate_results(row)


@pytest.mark.parametrize("path", [("source",), ("metrics", "mpjpe_mm", "all_averaging"), ("training", "log"),
                                  ("latency_ms_per_image", "pytorch", "batch32")])
def test_missing_key_is_named(path):
    row = measured_row()
    _delete(row, path)
    parent = "results" + "".join(f"\\['{p}'\\]" for p in path[:-1])
    with pytest.raises(ValueError, match=rf"{parent} is missing key\(s\) \['{path[-1]}'\]"):
        validate_results(row)


def test_reported_row_needs_source_and_all():
    row = reported_row()
    row["source"] = None
    with pytest.raises(ValueError, match=r"results\['source'\] must be a non-empty string, got None"):
        validate_results(row)
    row = reported_row()
    row["metrics"]["mpjpe_mm"]["all"] = None
    with pytest.raises(ValueError, match=r"results\['metrics'\]\['mpjpe_mm'\]\['all'\]"):
        validate_results(row)
    # a measured row may leave source null
    assert validate_results(measured_row())["source"] is None


def test_write_load_round_trip(tmp_path):
    row = measured_row()
    path = write_results(tmp_path / "sub" / "hopenet_r18_128.json", row)
    assert load_results(path) == row
    assert path.read_text().endswith("\n")
    assert not [p for p in path.parent.iterdir() if p.name.startswith(".")]  # no temp file left behind


def test_write_refuses_bad_row_and_writes_nothing(tmp_path):
    row = measured_row()
    row["metrics"]["mpjpe_mm"]["hand"] = "x"
    with pytest.raises(ValueError, match=r"\['hand'\]"):
        write_results(tmp_path / "r.json", row)
    assert not (tmp_path / "r.json").exists()


def test_load_names_the_file(tmp_path):
    row = measured_row()
    row["schema_version"] = 2
    bad = tmp_path / "future.json"
    bad.write_text(json.dumps(row))
    with pytest.raises(ValueError, match=rf"^{bad}: results\['schema_version'\] must be 1"):
        load_results(bad)
    broken = tmp_path / "broken.json"
    broken.write_text("{not json")
    with pytest.raises(ValueError, match=rf"^{broken}: not valid JSON"):
        load_results(broken)
    with pytest.raises(FileNotFoundError, match="missing.json"):
        load_results(tmp_path / "missing.json")
