"""The results schema: valid rows pass, every kind of bad field is named by its path."""

import copy
import json
import math

import pytest

from hupbench.evaluation.results import (
    SCHEMA_VERSION,
    blank_results,
    load_results,
    upgrade_results,
    validate_results,
    validate_split_floor,
    write_results,
)
from helpers.leaderboard import intervals_block, split_floor_block, triplet
from helpers import REPO







def measured_row(run_name="hopenet_r18_128"):
    d = blank_results("measured", run_name)
    d["model"] |= {"name": "hopenet", "label": "HOPE-Net (ResNet-18, 128 px)", "config": {"backbone": "resnet18"},
                   "parameters": 11_700_000, "flops": 1_200_000_000, "input_size": 128, "format": "onnx"}
    d["dataset"] |= {"manifest_sha256": "ab" * 32, "grasps_sha256": "cd" * 32, "frames": 5760,
                     "name": "hupbench default (31,680 frames)"}
    d["metrics"] = {"mpjpe_mm": triplet(10.0, 19.0) | {"all_averaging": "keypoint-weighted"},
                    "root_relative_hand_mpjpe_mm": 8.0, "pa_mpjpe_hand_mm": 5.5, "pck_auc_0_50mm": 0.75,
                    "pixel_error_px": 3.2, "probe_symmetric_mpjpe_mm": 15.5,
                    "spread_ratio": {"x": 0.9, "y": 1.1, "z": 0.4}}
    d["breakdowns"] = {"z_ego": {"0.5 m": {"frames": 2880, "mpjpe_mm": {"all": 11.0, "hand": 9.0, "probe": 16.0}}},
                       "grasp": {"3": {"frames": 2880, "mpjpe_mm": triplet(9.0, 16.0)},
                                 "12": {"frames": 2880, "mpjpe_mm": triplet(11.0, 22.0)}},
                       "theta_vol": {"theta_vol_z=180": {"frames": 2880, "mpjpe_mm": triplet(9.0, 16.0)},
                                     "unknown": {"frames": 2880, "mpjpe_mm": triplet(11.0, 22.0)}}}
    d["dataset"]["grasp_theta_vol_deg"] = {"3": [0.0, 0.0, 180.0], "12": None}
    d["track"] = "unseen_grasps"
    d["split_floor"] = split_floor_block()
    d["intervals"] = intervals_block()
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
    assert a["schema_version"] == SCHEMA_VERSION == 5
    assert a["intervals"] is None
    assert "path" not in a["dataset"] and a["dataset"]["grasps_sha256"] is None
    assert a["metrics"]["probe_symmetric_mpjpe_mm"] is None
    assert a["metrics"]["spread_ratio"] == {"x": None, "y": None, "z": None}
    assert (a["track"], a["split_floor"], a["dataset"]["grasp_theta_vol_deg"]) == (None, None, None)
    with pytest.raises(ValueError, match=r"results\['model'\]\['label'\] must be a non-empty string, got None"):
        validate_results(a)


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
    (("schema_version",), 6, r"results\['schema_version'\] must be 5 .* or one of \[1, 2, 3, 4\] .* got 6"),
    (("schema_version",), "5", r"results\['schema_version'\] must be 5 .* got '5'"),
    (("metrics", "probe_symmetric_mpjpe_mm"), -0.5,
     r"results\['metrics'\]\['probe_symmetric_mpjpe_mm'\] must be a finite number >= 0 or null, got -0.5"),
    (("metrics", "probe_symmetric_mpjpe_mm"), 19.5,
     r"\['probe_symmetric_mpjpe_mm'\] must be at most the plain probe MPJPE \(19.0: .*\), got 19.5"),
    (("metrics", "spread_ratio", "y"), "wide", r"results\['metrics'\]\['spread_ratio'\]\['y'\] must be a finite"),
    (("metrics", "spread_ratio"), {"x": 1.0, "y": 1.0}, r"\['spread_ratio'\] is missing key\(s\) \['z'\]"),
    (("metrics", "spread_ratio"), None, r"results\['metrics'\]\['spread_ratio'\] must be a dict, got None"),
    (("track",), "unseen_people", r"results\['track'\] must be one of 'unseen_grasps', 'unseen_views', 'clinic' "
                                  r"or null, got 'unseen_people'"),
    (("intervals", "mpjpe_mm", "probe"), [22.0, 16.0],
     r"results\['intervals'\]\['mpjpe_mm'\]\['probe'\] must be \[low, high\]: two finite numbers, 0 <= low <= high"),
    (("intervals", "mpjpe_mm", "hand"), 9.0, r"\['intervals'\]\['mpjpe_mm'\]\['hand'\] must be \[low, high\]"),
    (("intervals", "split_floor_mm"), {"hand": [1.0, 2.0]},
     r"results\['intervals'\]\['split_floor_mm'\] is missing key\(s\) \['all', 'probe'\]"),
    (("intervals", "resamples"), 0, r"results\['intervals'\]\['resamples'\] must be an integer >= 1, got 0"),
    (("intervals", "confidence"), 95, r"results\['intervals'\]\['confidence'\] must be a number in \(0, 1\), got 95"),
    (("intervals", "grasps"), 3, r"results\['intervals'\]\['grasps'\] must be the number of evaluated grasps in "
                                 r"results\['breakdowns'\]\['grasp'\] \(2\), got 3"),
    (("intervals", "seed"), None, r"results\['intervals'\]\['seed'\] must be an integer >= 0, got None"),
    (("track",), None, r"results\['track'\] must be one of .* where split_floor is given, got None"),
    (("split_floor", "floor_kind"), "oracle",
     r"results\['split_floor'\]\['floor_kind'\] must be one of 'nearest_train_grasp', 'nearest_train_view', "
     r"'nearest_train_frame', got"),
    (("split_floor", "floor_mm", "probe"), None,
     r"results\['split_floor'\]\['floor_mm'\]\['probe'\] must be a finite number >= 0, got None"),
    (("split_floor", "train_mean_mm"), {"hand": 1.0, "all": 1.0},
     r"results\['split_floor'\]\['train_mean_mm'\] is missing key\(s\) \['probe'\]"),
    (("split_floor", "per_grasp", "3", "nearest_train_grasp_id"), 2.5,
     r"results\['split_floor'\]\['per_grasp'\]\['3'\]\['nearest_train_grasp_id'\] must be an integer id"),
    (("split_floor", "per_grasp", "3", "nearest_train_view_mm"), {"hand": -1.0, "probe": 1.0, "all": 1.0},
     r"\['per_grasp'\]\['3'\]\['nearest_train_view_mm'\]\['hand'\] must be a finite number >= 0, got -1.0"),
    (("split_floor", "per_grasp", "3", "frames"), 2879,
     r"results\['split_floor'\]\['per_grasp'\]\['3'\]\['frames'\] must be the grasp's frames in "
     r"results\['breakdowns'\]\['grasp'\] \(2880\), got 2879"),
    (("split_floor", "per_grasp", "3", "frames"), -1,
     r"results\['split_floor'\]\['per_grasp'\]\['3'\]\['frames'\] must be an integer >= 0 or null, got -1"),
    (("split_floor", "per_grasp", "3", "oracle_mm"), 1.0,
     r"\['per_grasp'\]\['3'\] has unknown key\(s\) \['oracle_mm'\]"),
    (("split_floor", "per_grasp", "grasp 3"), {},
     r"results\['split_floor'\]\['per_grasp'\] must be keyed by grasp ids written as decimal integers, got 'grasp 3'"),
    (("split_floor", "per_grasp"), {},
     r"results\['split_floor'\]\['per_grasp'\] must be keyed by the evaluated grasps \['3', '12'\] .*, got \[\]"),
    (("breakdowns", "grasp", "03"), {"frames": 1, "mpjpe_mm": {"all": 1.0, "hand": 1.0, "probe": 1.0}},
     r"results\['breakdowns'\]\['grasp'\] must be keyed by grasp ids written as decimal integers, got '03'"),
    (("dataset", "grasp_theta_vol_deg", "3"), [0.0, 180.0],
     r"results\['dataset'\]\['grasp_theta_vol_deg'\]\['3'\] must be \[x, y, z\]: three finite numbers"),
    (("dataset", "grasp_theta_vol_deg", "12"), [0.0, 0.0, math.nan], r"\['grasp_theta_vol_deg'\]\['12'\] must be"),
    (("dataset", "grasp_theta_vol_deg"), {"3": None},
     r"results\['dataset'\]\['grasp_theta_vol_deg'\] must be keyed by the evaluated grasps \['3', '12'\]"),
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


def version_4_row():
    """A row as hupbench wrote it before schema version 5: no intervals."""
    row = measured_row()
    row["schema_version"] = 4
    del row["intervals"]
    return row


def version_3_row():
    """A row as hupbench wrote it before schema version 4: the dataset by its path, no grasps' sha256."""
    row = version_4_row()
    row["schema_version"] = 3
    del row["dataset"]["grasps_sha256"]
    row["dataset"]["path"] = "/home/someone/hupbench_out/dataset"
    return row


def version_2_row():
    """A row as hupbench wrote it before schema version 3: no track, floor, grasp or Theta_Vol fields."""
    row = version_3_row()
    row["schema_version"] = 2
    del row["track"], row["split_floor"], row["dataset"]["grasp_theta_vol_deg"]
    del row["breakdowns"]["grasp"], row["breakdowns"]["theta_vol"]
    return row


def version_1_row():
    """A row as hupbench wrote it before schema version 2."""
    row = version_2_row()
    row["schema_version"] = 1
    del row["metrics"]["probe_symmetric_mpjpe_mm"], row["metrics"]["spread_ratio"]
    return row


def test_version_2_rows_load_upgraded_with_track_floor_and_orientations_unknown(tmp_path):
    old = version_2_row()
    assert validate_results(old) is old
    kept = copy.deepcopy(old)
    new = upgrade_results(old)
    assert old == kept
    assert new["schema_version"] == 5
    assert (new["track"], new["split_floor"], new["dataset"]["grasp_theta_vol_deg"]) == (None, None, None)
    assert "path" not in new["dataset"] and new["dataset"]["grasps_sha256"] is None
    assert new["breakdowns"] == old["breakdowns"] and new["metrics"] == old["metrics"]
    path = tmp_path / "v2.json"
    path.write_text(json.dumps(old))
    assert load_results(path) == new
    # version 2 has no room for the new fields
    with_track = version_2_row() | {"track": "unseen_grasps"}
    with pytest.raises(ValueError, match=r"results has unknown key\(s\) \['track'\]"):
        validate_results(with_track)
    with_grasps = version_2_row()
    with_grasps["breakdowns"]["grasp"] = measured_row()["breakdowns"]["grasp"]
    with pytest.raises(ValueError, match=r"results\['breakdowns'\] has unknown key\(s\) \['grasp'\]; expected a "
                                         r"subset of \['latitude', 'z_ego', 'background'\]"):
        validate_results(with_grasps)
    with pytest.raises(AssertionError, match="upgrade_results"):  # only the current version is written
        write_results(tmp_path / "r.json", old)


def test_new_fields_round_trip(tmp_path):
    row = measured_row()
    path = write_results(tmp_path / "hopenet_r18_128.json", row)
    back = load_results(path)
    assert back == row
    assert back["track"] == "unseen_grasps"
    assert back["split_floor"]["per_grasp"]["12"]["floor_mm"] == pytest.approx({"hand": 25.0, "probe": 50.0,
                                                                                "all": 925 / 29})
    assert back["breakdowns"]["grasp"]["3"]["mpjpe_mm"]["probe"] == 16.0
    assert back["breakdowns"]["theta_vol"]["unknown"]["frames"] == 2880
    assert back["dataset"]["grasp_theta_vol_deg"] == {"3": [0.0, 0.0, 180.0], "12": None}


def test_floor_fields_that_need_each_other():
    # no floor on the train split: it is what the floor compares with
    row = measured_row()
    row["dataset"]["split"] = "train"
    with pytest.raises(ValueError, match=r"results\['split_floor'\] must be null for the train split"):
        validate_results(row)
    # a track without a floor (a manifest with a track but no floors, or the train split) is fine
    row["split_floor"] = None
    with pytest.raises(ValueError, match=r"results\['intervals'\]\['split_floor_mm'\] must be null where "
                                         r"results\['split_floor'\] is null"):
        validate_results(row)
    row["intervals"]["split_floor_mm"] = None
    assert validate_results(row)["track"] == "unseen_grasps"
    # no grasp breakdown: the floor and the orientations need not name its grasps
    row = measured_row()
    del row["breakdowns"]["grasp"]
    row["dataset"]["grasp_theta_vol_deg"] = {"7": [0, 0, 90]}
    assert validate_results(row) is row


def test_split_floor_errors_name_the_block_they_come_from():
    block = split_floor_block()
    assert validate_split_floor(block, "ds/manifest.json: manifest['split_floors']['splits']['test']") is block
    block["floor_mm"] = {"hand": 1.0, "probe": 2.0}
    with pytest.raises(ValueError, match=r"^ds/manifest.json: manifest\['split_floors'\]\['splits'\]\['test'\]"
                                         r"\['floor_mm'\] is missing key\(s\) \['all'\]"):
        validate_split_floor(block, "ds/manifest.json: manifest['split_floors']['splits']['test']")
    with pytest.raises(ValueError, match=r"^results\['split_floor'\] must be a dict, got 'far'"):
        validate_split_floor("far")


def test_version_1_rows_load_upgraded_with_the_new_fields_unknown(tmp_path):
    old = version_1_row()
    assert validate_results(old) is old
    kept = copy.deepcopy(old)
    new = upgrade_results(old)
    assert old == kept  # the input is not changed
    assert new["schema_version"] == 5
    assert new["metrics"]["probe_symmetric_mpjpe_mm"] is None
    assert new["metrics"]["spread_ratio"] == {"x": None, "y": None, "z": None}
    assert {k: v for k, v in new["metrics"].items() if k in old["metrics"]} == old["metrics"]
    path = tmp_path / "old.json"
    path.write_text(json.dumps(old))
    assert load_results(path) == new
    # version 1 has no room for the new fields, and only the current version is written
    with_new = version_1_row()
    with_new["metrics"]["spread_ratio"] = {"x": 1.0, "y": 1.0, "z": 1.0}
    with pytest.raises(ValueError, match=r"results\['metrics'\] has unknown key\(s\) \['spread_ratio'\]"):
        validate_results(with_new)
    with pytest.raises(AssertionError, match="upgrade_results"):
        write_results(tmp_path / "r.json", old)
    assert (new["track"], new["split_floor"], new["dataset"]["grasp_theta_vol_deg"]) == (None, None, None)
    assert upgrade_results(measured_row()) == measured_row()


def test_committed_results_load():
    for path in sorted((REPO / "leaderboard" / "results").glob("*.json")):
        row = load_results(path)
        assert row["schema_version"] == SCHEMA_VERSION
        written = json.loads(path.read_text())["schema_version"]
        if written == 1:
            assert row["metrics"]["probe_symmetric_mpjpe_mm"] is None
        if written < 3:
            assert (row["track"], row["split_floor"], row["dataset"]["grasp_theta_vol_deg"]) == (None, None, None)
        assert "path" not in row["dataset"]


def test_load_names_the_file(tmp_path):
    row = measured_row()
    row["schema_version"] = 6
    bad = tmp_path / "future.json"
    bad.write_text(json.dumps(row))
    with pytest.raises(ValueError, match=rf"^{bad}: results\['schema_version'\] must be 5"):
        load_results(bad)
    broken = tmp_path / "broken.json"
    broken.write_text("{not json")
    with pytest.raises(ValueError, match=rf"^{broken}: not valid JSON"):
        load_results(broken)
    with pytest.raises(FileNotFoundError, match="missing.json"):
        load_results(tmp_path / "missing.json")


def test_middle_mcp_relative_error_is_optional_in_version_3(tmp_path):
    """Files written before the metric lack it and still load unchanged; present, it is checked like the others."""
    old = measured_row()
    assert "middle_mcp_relative_hand_mpjpe_mm" not in old["metrics"]
    path = tmp_path / "old.json"
    path.write_text(json.dumps(old))
    assert load_results(path) == old
    new = measured_row()
    new["metrics"]["middle_mcp_relative_hand_mpjpe_mm"] = 6.5
    assert validate_results(new)["metrics"]["middle_mcp_relative_hand_mpjpe_mm"] == 6.5
    assert "middle_mcp_relative_hand_mpjpe_mm" in blank_results("measured", "r")["metrics"]
    new["metrics"]["middle_mcp_relative_hand_mpjpe_mm"] = -1.0
    with pytest.raises(ValueError, match=r"results\['metrics'\]\['middle_mcp_relative_hand_mpjpe_mm'\] must be a "
                                         r"finite number >= 0 or null, got -1.0"):
        validate_results(new)
    # version 2 has no room for it
    v2 = version_2_row()
    v2["metrics"]["middle_mcp_relative_hand_mpjpe_mm"] = 6.5
    with pytest.raises(ValueError, match=r"unknown key\(s\) \['middle_mcp_relative_hand_mpjpe_mm'\]"):
        validate_results(v2)


def _probe_pose_block(**change):
    return {"add_mm": 20.0, "add_s_mm": 8.0, "mssd_mm": 30.0, "mspd_px": 9.5, "add_accuracy": 0.4,
            "add_s_accuracy": 0.9, "ar_mssd": 0.6, "ar_mspd": 0.5, "diameter_mm": 182.4, "image_width_px": 256,
            "symmetry": "half_turn", "model_points": 6508} | change


def test_probe_pose_blocks_are_optional_in_version_3(tmp_path):
    """Files written before the BOP scores lack them and load unchanged; present, every field is checked."""
    old = measured_row()
    path = tmp_path / "old.json"
    path.write_text(json.dumps(old))
    assert load_results(path) == old
    assert {"probe_pose", "split_floor_probe_pose"} <= set(blank_results("measured", "r")["metrics"])
    new = measured_row()
    new["metrics"] |= {"probe_pose": _probe_pose_block(), "split_floor_probe_pose": None}
    write_results(tmp_path / "new.json", new)
    assert load_results(tmp_path / "new.json") == new
    new["metrics"]["probe_pose"]["mspd_px"] = None   # a frame with a point behind the camera
    validate_results(new)


@pytest.mark.parametrize("change, message", [
    ({"ar_mssd": 1.5}, r"\['probe_pose'\]\['ar_mssd'\] must be a finite number in \[0, 1\], got 1.5"),
    ({"add_mm": None}, r"\['probe_pose'\]\['add_mm'\] must be a finite number >= 0, got None"),
    ({"diameter_mm": 0.0}, r"\['probe_pose'\]\['diameter_mm'\] must be a finite number > 0, got 0.0"),
    ({"image_width_px": 256.0}, r"\['probe_pose'\]\['image_width_px'\] must be an integer >= 1, got 256.0"),
    ({"add_s_mm": 25.0}, r"\['probe_pose'\]\['add_s_mm'\] must be at most add_mm \(20.0\), got 25.0"),
    ({"vsd": 0.1}, r"\['probe_pose'\] has unknown key\(s\) \['vsd'\]"),
])
def test_bad_probe_pose_fields_are_named(change, message):
    row = measured_row()
    row["metrics"]["probe_pose"] = _probe_pose_block(**change)
    with pytest.raises(ValueError, match=message):
        validate_results(row)
    row = measured_row()
    row["metrics"]["split_floor_probe_pose"] = _probe_pose_block(**change)
    with pytest.raises(ValueError, match=message.replace("probe_pose", "split_floor_probe_pose", 1)):
        validate_results(row)


def test_version_3_rows_load_without_their_path(tmp_path):
    """A file written before the dataset record named the grasps: its machine's path is dropped on load, the
    grasps' sha256 unknown; version 4 has no room for a path."""
    old = version_3_row()
    kept = copy.deepcopy(old)
    new = upgrade_results(old)
    assert old == kept
    assert new["dataset"] == {k: v for k, v in measured_row()["dataset"].items()} | {"grasps_sha256": None}
    assert {k: v for k, v in new.items() if k not in ("dataset", "schema_version", "intervals")} == \
        {k: v for k, v in old.items() if k not in ("dataset", "schema_version")}
    path = tmp_path / "v3.json"
    path.write_text(json.dumps(old))
    assert load_results(path) == new
    with_path = measured_row()
    with_path["dataset"]["path"] = "/data/hup"
    with pytest.raises(ValueError, match=r"results\['dataset'\] has unknown key\(s\) \['path'\]"):
        validate_results(with_path)


@pytest.mark.parametrize("key", ["manifest_sha256", "grasps_sha256"])
def test_dataset_hashes_are_sha256(key):
    row = measured_row()
    row["dataset"][key] = "AB" * 32
    with pytest.raises(ValueError, match=rf"results\['dataset'\]\['{key}'\] must be a sha256: 64 lowercase "
                                         r"hexadecimal digits or null, got 'ABAB"):
        validate_results(row)


def test_all_must_agree_with_hand_and_probe():
    """A measured row's all is the keypoint-weighted mean of its hand and probe (1.0 against 500 and 900 mm is
    refused, not ranked first); a reported row's may be averaged otherwise but lies between them."""
    row = measured_row()
    row["metrics"]["mpjpe_mm"] |= {"all": 1.0, "hand": 500.0, "probe": 900.0}
    with pytest.raises(ValueError, match=r"results\['metrics'\]\['mpjpe_mm'\]\['all'\] must be the keypoint-weighted "
                                         r"mean of hand and probe, \(21 x 500 \+ 8 x 900\) / 29 = 610.34 mm "
                                         r"\(within 0.01 mm\), in a measured row, got 1.0"):
        validate_results(row)
    row["metrics"]["mpjpe_mm"]["all"] = 610.345
    assert validate_results(row) is row
    paper = reported_row()
    paper["metrics"]["mpjpe_mm"] |= {"all": 8.65, "hand": 5.33, "probe": 17.05}  # the paper's, not 8.56
    assert validate_results(paper) is paper
    paper["metrics"]["mpjpe_mm"]["all"] = 1.0
    with pytest.raises(ValueError, match=r"\['all'\] must be between the hand and probe MPJPE \(5.33 and 17.05 mm\)"):
        validate_results(paper)


@pytest.mark.parametrize("path, value, message", [
    (("metrics", "mpjpe_mm", "all"), 1e308, r"\['all'\] must be at most 10000 mm \(a larger value is a unit slip"),
    (("latency_ms_per_image", "onnxruntime", "batch1"), 1e308, r"\['batch1'\] must be at most 1e\+06 ms"),
    (("metrics", "pixel_error_px"), 1e6, r"\['pixel_error_px'\] must be at most 100000 px"),
])
def test_hand_typed_values_beyond_their_unit_are_refused(path, value, message):
    row = reported_row()
    _set(row, path, value)
    with pytest.raises(ValueError, match=message):
        validate_results(row)
    floor = split_floor_block()
    floor["floor_mm"]["hand"] = 2e4
    with pytest.raises(ValueError, match=r"\['floor_mm'\]\['hand'\] must be at most 10000 mm"):
        validate_split_floor(floor)  # a manifest's floor: verify's, from labels alone


def test_a_measured_row_keeps_what_a_diverged_fit_measured():
    """eval's own numbers reach past the hand-typed limits: the clinic track's hand fit diverged to a hand MPJPE of
    7,460 mm (95 % CI 196-21,622 mm) and a 2D error of 2.45 million px (docs/clinic.md), a result the row must carry,
    not refuse; 1000 km stays damage."""
    row = measured_row()
    row["metrics"]["mpjpe_mm"] |= {"hand": 7459.89, "probe": 36.19, "all": (21 * 7459.89 + 8 * 36.19) / 29}
    row["metrics"]["pixel_error_px"] = 2452889.05
    row["intervals"]["mpjpe_mm"] = {"hand": [196.0, 21622.4], "probe": [33.1, 39.1], "all": [152.3, 15667.7]}
    assert validate_results(row) is row
    with pytest.raises(ValueError, match=r"\['pixel_error_px'\] must be at most 100000 px"):
        validate_results(copy.deepcopy(row) | {"kind": "reported", "source": "typed by hand"})
    row["metrics"]["mpjpe_mm"] |= {"hand": 2e9, "all": (21 * 2e9 + 8 * 36.19) / 29}
    with pytest.raises(ValueError, match=r"\['all'\] must be at most 1e\+09 mm"):
        validate_results(row)  # beyond 1000 km: damage, not a fit
    with pytest.raises(ValueError, match=r"\['pixel_error_px'\] must be at most 100000 px"):
        validate_results(reported_row() | {"metrics": reported_row()["metrics"] | {"pixel_error_px": 2452889.05}})


@pytest.mark.parametrize("value", ["yesterday", "2025-13-01T00:00:00Z", "2025-01-01 00:00:00", 20250101])
def test_created_utc_is_a_utc_time(value):
    row = measured_row()
    row["created_utc"] = value
    with pytest.raises(ValueError, match=r"results\['created_utc'\] must be a UTC time '%Y-%m-%dT%H:%M:%SZ' or null"):
        validate_results(row)


def test_duplicate_keys_and_deep_nesting_are_named(tmp_path):
    """JSON that names a key twice (readers keep one value, silently) and JSON nested deeper than the parser
    follows (a RecursionError before) are refused as invalid, naming the file."""
    text = json.dumps(measured_row())
    twice = tmp_path / "twice.json"
    twice.write_text(text.replace('"hand": 10.0', '"hand": 10.0, "hand": 1.0', 1))
    with pytest.raises(ValueError, match=rf"^{twice}: not valid JSON: an object names the key\(s\) \['hand'\] twice"):
        load_results(twice)
    deep = tmp_path / "deep.json"
    deep.write_text("[" * 100_000 + "]" * 100_000)
    with pytest.raises(ValueError, match=rf"^{deep}: not valid JSON: maximum recursion depth exceeded"):
        load_results(deep)


def test_a_floor_needs_only_its_kind_headline_and_per_grasp_floors():
    """A floor of any kind is read by its kind, headline and per-grasp floors; the figures of the other kinds and
    of the mean training grasp are optional."""
    block = {"floor_kind": "nearest_train_grasp", "floor_mm": triplet(20.0, 40.0),
             "per_grasp": {"3": {"floor_mm": triplet(15.0, 30.0), "frames": 2880},
                           "12": {"floor_mm": triplet(25.0, 50.0), "frames": None}}}
    assert validate_split_floor(block) is block
    block["per_grasp"]["3"]["nearest_train_grasp_id"] = 0
    block["nearest_train_view_mm"] = None
    assert validate_split_floor(block) is block
    del block["per_grasp"]["12"]["frames"]
    with pytest.raises(ValueError, match=r"\['per_grasp'\]\['12'\] is missing key\(s\) \['frames'\]"):
        validate_split_floor(block)
