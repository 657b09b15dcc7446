"""hupbench eval: checkpoint vs exported ONNX agreement, known answers through the whole pipeline, bad input."""

import json
import math
import re

import numpy as np
import pytest
import torch

from hupbench.evaluation import evaluate as EV
from hupbench.evaluation.probe_pose import probe_pose_scores
from hupbench import metrics as M
from hupbench.core import probe_symmetry as PS
from hupbench.core.contract import read_annotations
from hupbench.core.io import file_sha256
from hupbench.cli import main
from hupbench.data import HUPDataset, ReaderConfig
from hupbench.evaluation.intervals import METHOD
from hupbench.evaluation.results import load_results
from helpers.models import INPUT_SIZE, make_checkpoint


def evaluate(model, dataset, log=lambda *_: None, **options):
    """``run_eval`` of the options given as keywords, quiet unless ``log`` is given."""
    return EV.run_eval(EV.EvalOptions(model, dataset, **options), log=log)


def _flatten(d, prefix=""):
    out = {}
    for k, v in d.items():
        if isinstance(v, dict):
            out |= _flatten(v, f"{prefix}{k}.")
        else:
            out[prefix + k] = v
    return out


def test_onnx_eval_matches_checkpoint_eval(exported, tiny_dataset, tmp_path):
    ckpt, onnx_path = exported
    (tmp_path / "board" / "logs").mkdir(parents=True)
    (tmp_path / "board" / "logs" / "tiny_pt.jsonl").write_text("")
    r_pt = evaluate(ckpt, tiny_dataset, out=tmp_path / "board" / "results" / "tiny_pt.json", latency=False,
                    batch_size=8, training_command="bash scripts/paper_protocol.sh tiny",
                    training_log="logs/tiny_pt.jsonl")
    r_onnx = evaluate(onnx_path, tiny_dataset, out=tmp_path / "tiny_onnx.json", latency=True,
                      label="HOPE-Net (ResNet-10, 64 px, exported)")
    a, b = load_results(r_pt["out"]), load_results(r_onnx["out"])
    assert a == r_pt["results"] and b == r_onnx["results"]
    # every metric and every breakdown within 0.1 mm (2D: 0.01 px, AUC: 0.001)
    fa, fb = _flatten(a["metrics"] | {"breakdowns": a["breakdowns"]}), _flatten(b["metrics"] | {"breakdowns": b["breakdowns"]})
    assert fa.keys() == fb.keys()
    assert fa["probe_pose.symmetry"] == fb["probe_pose.symmetry"] == "half_turn"
    for key in fa:
        if key.endswith("symmetry"):
            continue
        if isinstance(fa[key], str):
            assert fa[key] == fb[key] == M.ALL_AVERAGING
        elif key.endswith("frames"):
            assert fa[key] == fb[key]
        else:
            tol = {"metrics.pixel_error_px": 0.01, "metrics.pck_auc_0_50mm": 0.001}.get(key, 0.1)
            assert abs(fa[key] - fb[key]) <= tol, key
    assert abs(a["metrics"]["mpjpe_mm"]["all"] - b["metrics"]["mpjpe_mm"]["all"]) < 1e-3
    # the same architecture: parameters and FLOPs agree (the ONNX side rebuilds the config)
    assert a["model"]["parameters"] == b["model"]["parameters"] > 1_000_000
    assert a["model"]["flops"] == b["model"]["flops"] > 0
    assert (a["model"]["format"], b["model"]["format"]) == ("pytorch", "onnx")
    assert a["model"]["label"] == "HOPE-Net (ResNet-10, 64 px)"  # made from the config
    assert b["model"]["label"] == "HOPE-Net (ResNet-10, 64 px, exported)"  # given
    assert a["model"]["input_size"] == b["model"]["input_size"] == INPUT_SIZE
    # latency: PyTorch is not timed for an ONNX file; onnxruntime is, at batch 1 and 32
    assert b["latency_ms_per_image"]["pytorch"] == {"batch1": None, "batch32": None}
    assert all(v > 0 for v in b["latency_ms_per_image"]["onnxruntime"].values())
    assert a["latency_ms_per_image"]["onnxruntime"] == {"batch1": None, "batch32": None}
    # provenance and the training block of the checkpoint
    assert a["run_name"] == "tiny_pt" and b["run_name"] == "tiny_onnx"
    assert a["dataset"]["manifest_sha256"] == file_sha256(tiny_dataset / "manifest.json")
    assert a["dataset"]["frames"] == 20 and a["dataset"]["split"] == "test"
    assert a["training"] == {"wall_s": 0.0, "hardware": None, "samples_seen": 0, "epochs": 0.0,
                             "command": "bash scripts/paper_protocol.sh tiny", "log": "logs/tiny_pt.jsonl"}
    assert b["training"]["wall_s"] is None
    assert len(a["git_commit"]) >= 7 and "threads" in a["device"]
    # breakdown buckets of the tiny dataset: rings at 60 and 120 degrees, one distance, two backgrounds
    assert {k: v["frames"] for k, v in a["breakdowns"]["latitude"].items()} == {"egocentric": 10, "non_egocentric": 10}
    assert {k: v["frames"] for k, v in a["breakdowns"]["z_ego"].items()} == {"0.5 m": 20}
    assert {k: v["frames"] for k, v in a["breakdowns"]["background"].items()} == {"consultation_room": 10,
                                                                                  "plain_white": 10}
    test_grasp = json.loads((tiny_dataset / "manifest.json").read_text())["grasp_ids"]["test"]
    assert {k: v["frames"] for k, v in a["breakdowns"]["grasp"].items()} == {str(g): 20 for g in test_grasp}
    # how many hand keypoints each frame shows, from the stored visibility
    shown = read_annotations(tiny_dataset, "test", ("visible",))["visible"][:, :21].sum(axis=1)
    expected = {name: int(((shown >= low) & (shown <= high)).sum())
                for name, low, high in (("0-5 of 21", 0, 5), ("6-10 of 21", 6, 10), ("11-15 of 21", 11, 15),
                                        ("16-21 of 21", 16, 21))}
    assert {k: v["frames"] for k, v in a["breakdowns"]["hand_visible"].items()} == {
        k: n for k, n in expected.items() if n}


def test_known_answers_through_the_pipeline(exported, tiny_dataset, tmp_path, monkeypatch):
    """Predictions = ground truth shifted by 5.2 mm in 3D and 3 px in 2D: every metric is hand-computable."""
    ckpt, _ = exported
    truth = iter(torch.utils.data.DataLoader(HUPDataset(tiny_dataset, "test", ReaderConfig(input_size=INPUT_SIZE)),
                                             batch_size=7))
    width = json.loads((tiny_dataset / "manifest.json").read_text())["image_size"][0]

    def shifted_truth(self, images):
        batch = next(truth)
        assert images.shape[0] == batch["image"].shape[0]
        points3d = batch["keypoints_3d"].double().numpy() + np.array([0.0, 0.0052, 0.0])
        points2d = batch["keypoints_2d"].double().numpy() + np.array([2 * 3.0 / width, 0.0])  # 3 px of the stored image
        return points2d, points3d

    monkeypatch.setattr(EV.EvalModel, "predict", shifted_truth)
    r = evaluate(ckpt, tiny_dataset, out=tmp_path / "shifted.json", latency=False, batch_size=7)["results"]
    m = r["metrics"]
    assert m["mpjpe_mm"]["all"] == pytest.approx(5.2, abs=1e-4)
    assert m["mpjpe_mm"]["hand"] == pytest.approx(5.2, abs=1e-4)
    assert m["mpjpe_mm"]["probe"] == pytest.approx(5.2, abs=1e-4)
    assert m["root_relative_hand_mpjpe_mm"] == pytest.approx(0.0, abs=1e-4)
    assert m["middle_mcp_relative_hand_mpjpe_mm"] == pytest.approx(0.0, abs=1e-4)
    assert m["pa_mpjpe_hand_mm"] == pytest.approx(0.0, abs=1e-4)
    # PCK steps from 0 to 1 between the 5.0 and 5.5 mm thresholds: area (0.25 + 44.5) / 50
    assert m["pck_auc_0_50mm"] == pytest.approx(44.75 / 50)
    assert m["pixel_error_px"] == pytest.approx(3.0, abs=1e-4)
    for axis in ("latitude", "z_ego", "background"):
        for bucket in r["breakdowns"][axis].values():
            assert bucket["mpjpe_mm"]["all"] == pytest.approx(5.2, abs=1e-4)
    # a shift keeps the labels (the half turn is further) and moves every frame alike (spread unchanged)
    assert m["probe_symmetric_mpjpe_mm"] == pytest.approx(5.2, abs=1e-4)
    assert m["spread_ratio"] == pytest.approx({"x": 1.0, "y": 1.0, "z": 1.0}, abs=1e-6)
    # the probe's pose: moved by 5.2 mm, every mesh point is 5.2 mm off (ADD, MSSD); ADD-S finds nearer points
    pose = m["probe_pose"]
    assert pose["add_mm"] == pytest.approx(5.2, abs=1e-3) and pose["mssd_mm"] == pytest.approx(5.2, abs=1e-3)
    assert 0.0 < pose["add_s_mm"] < 5.2
    assert (pose["symmetry"], pose["model_points"], pose["image_width_px"]) == ("half_turn", 6508, width)
    assert 165.0 <= pose["diameter_mm"] < 166.0   # the mesh's diameter: about its 165 mm length
    # 5.2 mm is below 0.1 and 0.05 of the diameter
    assert (pose["add_accuracy"], pose["add_s_accuracy"], pose["ar_mssd"]) == (1.0, 1.0, 1.0)
    # MSPD from the annotated pose (T_cam_world: the world is the probe frame) through cv2.projectPoints
    mspd = _mspd_of_a_shift(tiny_dataset, [0.0, 0.0052, 0.0])                    # (N,) px
    assert pose["mspd_px"] == pytest.approx(mspd.mean(), rel=1e-4)
    thresholds = 5.0 * np.arange(1, 11) * width / 640                              # BOP's 5..50 px at 640 px
    assert pose["ar_mspd"] == pytest.approx(np.mean([np.mean(mspd < t) for t in thresholds]))
    assert 0.0 < pose["ar_mspd"] < 1.0   # the shift is 1-2 px at 64 px: some thresholds pass, some do not
    assert r["metrics"]["split_floor_probe_pose"] == pytest.approx(_floor_probe_pose(tiny_dataset, width))
    table = EV.format_table(r)
    assert re.search(r"\nprobe ADD / ADD-S / MSSD +5\.20 / \d\.\d\d / 5\.20 mm \(diameter 165\.\d mm, symmetry "
                     r"half_turn\)\n", table)
    assert re.search(r"\nprobe BOP scores +ADD < 0\.1 d 1\.000, ADD-S < 0\.1 d 1\.000, AR_MSSD 1\.000, AR_MSPD "
                     + re.escape(f"{pose['ar_mspd']:.3f}\n"), table)
    assert re.search(r"\nprobe MSPD +\d\.\d\d px \(64 px wide images\)\n", table)
    assert "\nsplit floor probe ADD / ADD-S / MSSD " in table


def test_a_probe_mesh_that_is_not_the_datasets_gets_no_pose_metrics(exported, tiny_dataset, tmp_path, monkeypatch):
    """A mesh whose box does not meet the dataset's corners (here 10 % larger) would score another object."""
    from types import SimpleNamespace

    from hupbench.datagen.assets.probe import build_probe

    ckpt, _ = exported
    probe = build_probe()
    larger = SimpleNamespace(corners_probe=probe.corners_probe * 1.1, mesh=probe.mesh)
    monkeypatch.setattr(EV, "dataset_probe", lambda dataset, manifest: larger)
    lines = []
    r = evaluate(ckpt, tiny_dataset, out=tmp_path / "larger.json", latency=False, log=lines.append)["results"]
    assert r["metrics"]["probe_pose"] is None and r["metrics"]["split_floor_probe_pose"] is None
    assert any(re.fullmatch(r"warning: no probe pose metrics: the probe mesh's box meets the true corners only within "
                            r"\d+\.\d{3} mm \(allowed 0\.01 mm\): the mesh is not the dataset's probe", line)
               for line in lines)
    assert "probe ADD" not in EV.format_table(r) and r["metrics"]["mpjpe_mm"]["probe"] > 0


def _floor_probe_pose(dataset, width):
    """The probe pose scores of the test split's floor, its frames matched here: each frame's prediction is the
    probe of its grasp's nearest training grasp (as the manifest records it) in the same view and distance."""
    from hupbench.datagen.assets.probe import build_probe

    floor = json.loads((dataset / "manifest.json").read_text())["split_floors"]["splits"]["test"]
    with np.load(dataset / "train" / "annotations.npz") as tr, np.load(dataset / "test" / "annotations.npz") as te:
        train, test = dict(tr), dict(te)
    rows = []
    for grasp, view, z in zip(test["grasp_id"], test["view_id"], test["z_ego"]):
        nearest = floor["per_grasp"][str(grasp)]["nearest_train_grasp_id"]
        same = (train["grasp_id"] == nearest) & (train["view_id"] == view) & (train["z_ego"] == z)
        rows.append(np.flatnonzero(same)[0])
    floor_corners = train["keypoints_3d_cam"][rows, 21:].astype(np.float64)
    scores, _ = probe_pose_scores(floor_corners, test["keypoints_3d_cam"][:, 21:].astype(np.float64),
                                     test["K"].astype(np.float64), width, build_probe())
    assert scores["add_mm"] > 5.0   # another grasp's probe: not the truth
    return scores


def _mspd_of_a_shift(dataset, shift_m):
    """(N,) per-frame MSPD (px) of the probe mesh moved by ``shift_m`` in the camera frame from its annotated
    pose, under the half turn, computed with OpenCV's projection."""
    import cv2

    from hupbench.datagen.assets.probe import build_probe

    with np.load(dataset / "test" / "annotations.npz") as ann:
        T, K = ann["T_cam_world"].astype(np.float64), ann["K"].astype(np.float64)
    points = np.asarray(build_probe().mesh.vertices)
    per_frame = []
    for T_i, K_i in zip(T, K):
        rvec = cv2.Rodrigues(T_i[:3, :3])[0]
        moved = cv2.projectPoints(points, rvec, T_i[:3, 3] + shift_m, K_i, None)[0].reshape(-1, 2)
        candidates = []
        for S in M.PROBE_SYMMETRY_ROTATIONS["half_turn"]:
            true = cv2.projectPoints(points, cv2.Rodrigues(T_i[:3, :3] @ S)[0], T_i[:3, 3], K_i, None)[0].reshape(-1, 2)
            candidates.append(np.linalg.norm(moved - true, axis=1).max())
        per_frame.append(min(candidates))
    return np.array(per_frame)


def test_half_turned_corners_and_a_collapsed_axis(exported, tiny_dataset, tmp_path, monkeypatch):
    """Predicted corners relabelled by the half turn, every keypoint's x frozen: eval says both."""
    ckpt, _ = exported
    reader = HUPDataset(tiny_dataset, "test", ReaderConfig(input_size=INPUT_SIZE))
    truth = iter(torch.utils.data.DataLoader(reader, batch_size=len(reader)))
    half_turn = list(M.PROBE_SYMMETRIES["half_turn"][1])

    def turned_and_frozen(self, images):
        batch = next(truth)
        points3d = batch["keypoints_3d"].double().numpy()
        points3d[:, 21:] = points3d[:, 21:][:, half_turn]
        points3d[..., 0] = points3d[0, :, 0]  # the same x for every frame, per keypoint
        return batch["keypoints_2d"].double().numpy(), points3d

    monkeypatch.setattr(EV.EvalModel, "predict", turned_and_frozen)
    lines = []
    r = evaluate(ckpt, tiny_dataset, out=tmp_path / "turned.json", latency=False, batch_size=len(reader),
                 log=lines.append)["results"]
    m = r["metrics"]
    with np.load(tiny_dataset / "test" / "annotations.npz") as ann:
        gt = ann["keypoints_3d_cam"].astype(np.float64)
    expected = gt.copy()
    expected[:, 21:] = gt[:, 21:][:, half_turn]
    expected[..., 0] = expected[0, :, 0]
    # per frame the better of the two labellings counts: relabelled back, only the frozen x remains
    # (the half turn swaps corners across x = 0, so on some frames the identity can still win)
    as_labelled = np.linalg.norm(expected[:, 21:] - gt[:, 21:], axis=-1).mean(axis=1)  # (N,) metres
    relabelled = np.linalg.norm(expected[:, 21:][:, half_turn] - gt[:, 21:], axis=-1).mean(axis=1)
    assert m["probe_symmetric_mpjpe_mm"] == pytest.approx(1000 * np.minimum(as_labelled, relabelled).mean(), rel=1e-4)
    turned_share = 100.0 * np.mean(relabelled < as_labelled)
    assert turned_share > 50.0
    plain = 1000 * np.linalg.norm(expected - gt, axis=-1)[:, 21:].mean()
    assert m["mpjpe_mm"]["probe"] == pytest.approx(plain, rel=1e-4)
    assert m["mpjpe_mm"]["probe"] > m["probe_symmetric_mpjpe_mm"] + 10.0
    assert m["spread_ratio"]["x"] == 0.0
    assert m["spread_ratio"]["y"] == pytest.approx(1.0, abs=1e-9) and m["spread_ratio"]["z"] == pytest.approx(1.0)
    warnings = [line for line in lines if line.startswith("warning:")]
    assert len(warnings) == 1 and "along the camera x axis" in warnings[0] and "spread ratio 0.00 < 0.5" in warnings[0]
    assert any(f"the half-turned corner labels were closer on {turned_share:.1f} % of frames" in line
               for line in lines)
    # stored, and shown in the table
    assert load_results(tmp_path / "turned.json")["metrics"]["spread_ratio"]["x"] == 0.0
    table = EV.format_table(r)
    assert "spread ratio x / y / z" in table and "0.00 / 1.00 / 1.00" in table


def test_probe_symmetry_group_is_read_from_the_dataset(tiny_dataset):
    with np.load(tiny_dataset / "test" / "annotations.npz") as ann:
        points, T = ann["keypoints_3d_cam"], ann["T_cam_world"]
    assert PS.probe_symmetry_group(points, T) == M.PROBE_SYMMETRIES["half_turn"]
    # a box moved off the probe axis by 3 mm (in the probe frame) is not half-turn symmetric
    moved = points.astype(np.float64).copy()
    moved[:, 21:] += (T[:, :3, :3] @ np.array([0.003, 0.0, 0.0]))[:, None]   # R_cam_world (3 mm along x)
    with pytest.raises(ValueError, match="not symmetric under the rotation"):
        PS.probe_symmetry_group(moved, T)
    # corners that move between frames: not a probe at the world origin
    drifting = points.astype(np.float64).copy()
    drifting[1, 21:] += T[1, :3, :3] @ np.array([0.0, 0.0, 0.001])   # 1 mm along the probe axis in frame 1
    with pytest.raises(ValueError, match="differ between frames by 1.000 mm"):
        PS.probe_symmetry_group(drifting, T)


def test_eval_cli_prints_table(exported, tiny_dataset, tmp_path, capsys):
    _, onnx_path = exported
    out = tmp_path / "cli_run.json"
    assert main(["eval", str(onnx_path), str(tiny_dataset), "--out", str(out), "--no-latency",
                 "--batch-size", "16", "--threads", "1"]) == 0
    printed = capsys.readouterr().out
    results = load_results(out)
    all_mm = results["metrics"]["mpjpe_mm"]["all"]
    low, high = results["intervals"]["mpjpe_mm"]["all"]
    assert re.search(rf"\nMPJPE all +{all_mm:.2f} mm \[95 % CI {low:.1f}-{high:.1f}\]", printed)
    assert re.search(r"\n95 % CI +" + re.escape(f"{results['intervals']['method']}; 1 test grasp, 10,000 resamples, "
                                                 "seed 0\n"), printed)
    assert "latitude: egocentric" in printed and f"results written to {out}" in printed
    assert results["device"].endswith("1 threads")
    assert torch.get_num_threads() >= 1  # restored after the run


def _dataset_copy(src, dst, edit):
    """A dataset folder whose manifest is ``edit(manifest)``; the split folders are linked, not copied."""
    dst.mkdir()
    for split in ("train", "val", "test"):
        (dst / split).symlink_to(src / split, target_is_directory=True)
    manifest = json.loads((src / "manifest.json").read_text())
    (dst / "manifest.json").write_text(json.dumps(edit(manifest)))
    return dst


def test_bad_input(exported, tiny_dataset, tmp_path, capsys):
    ckpt, _ = exported
    out = {"out": tmp_path / "r.json", "latency": False}
    (tmp_path / "notes.txt").write_text("hello")
    with pytest.raises(ValueError, match=r"unknown model file type 'notes.txt'.*\.pt.*\.onnx"):
        evaluate(tmp_path / "notes.txt", tiny_dataset, **out)
    with pytest.raises(FileNotFoundError, match="checkpoint .*missing.pt does not exist"):
        evaluate(tmp_path / "missing.pt", tiny_dataset, **out)
    with pytest.raises(FileNotFoundError, match="dataset .*nowhere does not exist"):
        evaluate(ckpt, tmp_path / "nowhere", **out)
    (tmp_path / "empty_dir").mkdir()
    with pytest.raises(FileNotFoundError, match="no manifest.json"):
        evaluate(ckpt, tmp_path / "empty_dir", **out)
    foreign = tmp_path / "foreign.pt"
    torch.save({"state_dict": {"w": torch.zeros(2)}}, foreign)
    with pytest.raises(ValueError, match="not a hupbench checkpoint"):
        evaluate(foreign, tiny_dataset, **out)
    fake_onnx = tmp_path / "fake.onnx"
    fake_onnx.write_bytes(b"\x00\x01 not onnx")
    with pytest.raises(ValueError, match="fake.onnx"):
        evaluate(fake_onnx, tiny_dataset, **out)
    hand_only = make_checkpoint(tmp_path / "hand21.pt", tiny_dataset, n_keypoints=21)
    with pytest.raises(ValueError, match="predicts 21 keypoints"):
        evaluate(hand_only, tiny_dataset, **out)
    short = _dataset_copy(tiny_dataset, tmp_path / "ds21", lambda m: m | {"keypoint_names": m["keypoint_names"][:21]})
    with pytest.raises(ValueError, match="has 21 keypoints; the benchmark needs 29"):
        evaluate(ckpt, short, **out)
    empty = _dataset_copy(tiny_dataset, tmp_path / "ds_empty", lambda m: m | {"counts": m["counts"] | {"test": 0},
                                                                         # one grasp fewer: consistent counts
                                                                         "layout": {"shape": [2, *m["layout"]["shape"][1:]]}})
    with pytest.raises(ValueError, match="split 'test' of .* is empty"):
        evaluate(ckpt, empty, **out)
    with pytest.raises(ValueError, match="split must be one of"):
        evaluate(ckpt, tiny_dataset, split="holdout", **out)
    with pytest.raises(ValueError, match="must equal the results file stem"):
        evaluate(ckpt, tiny_dataset, run_name="other", **out)
    with pytest.raises(ValueError, match="batch_size must be a whole number >= 1"):
        evaluate(ckpt, tiny_dataset, batch_size=0, **out)
    assert not (tmp_path / "r.json").exists()
    assert main(["eval", str(tmp_path / "notes.txt"), str(tiny_dataset), "--out", str(tmp_path / "r.json")]) == 1
    assert "hupbench eval: error: unknown model file type" in capsys.readouterr().err


def _floor_triplet(hand, probe):
    return {"hand": hand, "probe": probe, "all": (21 * hand + 8 * probe) / 29}


def _with_floors(manifest, theta_vol=(0.0, 0.0, 180.0)):
    """A manifest as the generator writes it with tracks and floors (values made up, shapes exact)."""
    grasps = manifest["grasp_ids"]
    floors = {split: {"floor_kind": "nearest_train_grasp", "floor_mm": _floor_triplet(12.0, 30.0),
                      "nearest_train_grasp_mm": _floor_triplet(12.0, 30.0), "train_mean_mm": _floor_triplet(20.0, 45.0),
                      "nearest_train_view_mm": None,
                      "per_grasp": {str(g): {"floor_mm": _floor_triplet(12.0, 30.0),
                                             "nearest_train_grasp_id": grasps["train"][0],
                                             "nearest_train_grasp_mm": _floor_triplet(12.0, 30.0),
                                             "train_mean_mm": _floor_triplet(20.0, 45.0),
                                             "nearest_train_view_mm": None, "frames": 20} for g in grasps[split]}}
              for split in ("val", "test")}
    out = {k: v for k, v in manifest.items() if k not in ("split_floors", "grasp_theta_vol_deg")}
    return out | {"protocol": manifest["protocol"] | {"track": "unseen_grasps"},
                  "split_floors": {"definition": "nearest training grasp, true camera",
                                   "splits": floors},
                  "grasp_theta_vol_deg": {str(grasps["test"][0]): list(theta_vol), str(grasps["train"][0]): None}}


def _without_floors(manifest):
    """A manifest as datasets made before tracks and floors have it."""
    out = {k: v for k, v in manifest.items() if k not in ("split_floors", "grasp_theta_vol_deg")}
    return out | {"protocol": {k: v for k, v in manifest["protocol"].items() if k != "track"}}


def _shifted_truth_predictor(tiny_dataset, batch_size, shift_m=0.0052):
    """EvalModel.predict replaced: the truth moved by ``shift_m`` along y (every error is shift_m * 1000 mm)."""
    truth = iter(torch.utils.data.DataLoader(HUPDataset(tiny_dataset, "test", ReaderConfig(input_size=INPUT_SIZE)),
                                             batch_size=batch_size))

    def predict(self, images):
        batch = next(truth)
        return batch["keypoints_2d"].double().numpy(), batch["keypoints_3d"].double().numpy() + [0.0, shift_m, 0.0]
    return predict


def test_grasp_and_theta_vol_breakdowns_and_the_split_floor(exported, tiny_dataset, tmp_path, monkeypatch):
    ckpt, _ = exported
    dataset = _dataset_copy(tiny_dataset, tmp_path / "ds_floors", _with_floors)
    manifest = json.loads((dataset / "manifest.json").read_text())
    (test_grasp,) = manifest["grasp_ids"]["test"]
    monkeypatch.setattr(EV.EvalModel, "predict", _shifted_truth_predictor(tiny_dataset, 8))
    lines = []
    out = evaluate(ckpt, dataset, out=tmp_path / "floors.json", latency=False, batch_size=8, log=lines.append)
    r = out["results"]
    assert load_results(out["out"]) == r
    # every frame is 5.2 mm off: so is every grasp and every orientation
    assert list(r["breakdowns"]["grasp"]) == [str(test_grasp)]
    assert list(r["breakdowns"]["theta_vol"]) == ["theta_vol_z=180"]
    for axis in ("grasp", "theta_vol"):
        (bucket,) = r["breakdowns"][axis].values()
        assert bucket["frames"] == 20
        assert bucket["mpjpe_mm"] == pytest.approx({"hand": 5.2, "probe": 5.2, "all": 5.2}, abs=1e-4)
    assert r["dataset"]["grasp_theta_vol_deg"] == {str(test_grasp): [0.0, 0.0, 180.0]}
    # the test split's floor copied from the manifest
    assert r["track"] == "unseen_grasps"
    assert r["split_floor"] == manifest["split_floors"]["splits"]["test"]
    assert r["split_floor"]["floor_mm"]["all"] == pytest.approx((21 * 12 + 8 * 30) / 29)
    # one test grasp: every resample is that grasp, the intervals have zero width
    intervals = r["intervals"]
    assert {k: v for k, v in intervals.items() if not k.endswith("_mm")} == \
        {"method": METHOD, "confidence": 0.95, "resamples": 10_000, "seed": 0, "grasps": 1}
    for part, floor_mm in (("all", (21 * 12 + 8 * 30) / 29), ("hand", 12.0), ("probe", 30.0)):
        assert intervals["mpjpe_mm"][part] == pytest.approx([5.2, 5.2], abs=1e-4)
        assert intervals["split_floor_mm"][part] == pytest.approx([floor_mm, floor_mm])
    assert "test MPJPE probe: 5.20 mm [95 % CI 5.2-5.2], split floor 30.00 [30.0-30.0]" in lines
    assert ("test split floor: nearest_train_grasp: nearest training grasp under the true camera: a model that only "
            "recognises training grasps cannot do better than this") in lines
    assert f"test 95 % CI: {METHOD}; 1 test grasp, 10,000 resamples, seed 0" in lines
    table = out["table"]
    assert re.search(r"\nMPJPE all +5\.20 mm \[95 % CI 5\.2-5\.2\], split floor 16\.97 \[17\.0-17\.0\]\n", table)
    assert re.search(r"\nMPJPE hand +5\.20 mm \[95 % CI 5\.2-5\.2\], split floor 12\.00 \[12\.0-12\.0\]\n", table)
    assert re.search(r"\ntrack +unseen_grasps\n", table)
    assert f"grasp: {test_grasp}" in table and "theta_vol: theta_vol_z=180" in table
    # the floor's probe pose: the manifest's nearest training grasp in each frame's view
    width = manifest["image_size"][0]
    assert r["metrics"]["split_floor_probe_pose"] == pytest.approx(_floor_probe_pose(dataset, width))
    assert any(line.startswith("split floor probe pose (BOP): ADD ") for line in lines)
    # a nearest-training-view floor does not record which frames it chose: no pose scores for it
    def view_floor(m):
        test_floor = _with_floors(m)["split_floors"]["splits"]["test"]
        test_floor |= {"floor_kind": "nearest_train_view", "nearest_train_view_mm": _floor_triplet(3.0, 9.0)}
        return _with_floors(m) | {"split_floors": {"definition": "d", "splits": {"test": test_floor}}}
    view_dataset = _dataset_copy(tiny_dataset, tmp_path / "ds_view_floor", view_floor)
    monkeypatch.setattr(EV.EvalModel, "predict", _shifted_truth_predictor(tiny_dataset, 20))
    lines.clear()
    r = evaluate(ckpt, view_dataset, out=tmp_path / "view_floor.json", latency=False, batch_size=20,
                 log=lines.append)["results"]
    assert r["metrics"]["split_floor_probe_pose"] is None and r["metrics"]["probe_pose"] is not None
    assert ("no probe pose metrics of the split floor: only the nearest-training-grasp floor records its choice"
            in lines)
    # the train split has no floor, but the dataset's track
    monkeypatch.undo()
    r = evaluate(ckpt, dataset, split="train", out=tmp_path / "train.json", latency=False)["results"]
    assert (r["track"], r["split_floor"]) == ("unseen_grasps", None)
    assert r["dataset"]["grasp_theta_vol_deg"] == {str(manifest["grasp_ids"]["train"][0]): None}
    assert "theta_vol" not in r["breakdowns"]  # no train grasp has a recorded orientation
    assert list(r["breakdowns"]["grasp"]) == [str(manifest["grasp_ids"]["train"][0])]


def test_datasets_without_tracks_and_floors(exported, tiny_dataset, tmp_path):
    ckpt, _ = exported
    dataset = _dataset_copy(tiny_dataset, tmp_path / "ds_old", _without_floors)
    r = evaluate(ckpt, dataset, out=tmp_path / "old.json", latency=False)["results"]
    assert (r["track"], r["split_floor"], r["dataset"]["grasp_theta_vol_deg"]) == (None, None, None)
    assert set(r["breakdowns"]) == {"latitude", "z_ego", "background", "grasp", "hand_visible"}
    assert "split floor" not in EV.format_table(r)
    # the MPJPE's interval needs no floor
    assert r["intervals"]["split_floor_mm"] is None and r["intervals"]["grasps"] == 1
    assert r["intervals"]["mpjpe_mm"]["all"] == pytest.approx([r["metrics"]["mpjpe_mm"]["all"]] * 2)


def _edited(change):
    """A manifest edit: :func:`_with_floors`, then ``change`` (which damages it in place)."""
    def edit(manifest):
        manifest = _with_floors(manifest)
        change(manifest)
        return manifest
    return edit


@pytest.mark.parametrize("change, message", [
    (lambda m: m["protocol"].update(track="unseen_people"),
     r"manifest.json: manifest\['protocol'\]\['track'\] must be one of unseen_grasps, unseen_views, "
     r"clinic, got 'unseen_people'"),
    (lambda m: m["split_floors"]["splits"]["test"]["floor_mm"].pop("probe"),
     r"manifest.json: manifest\['split_floors'\]\['splits'\]\['test'\]\['floor_mm'\] is missing key\(s\) \['probe'\]"),
    (lambda m: m["split_floors"]["splits"]["test"].update(per_grasp={"999": m["split_floors"]["splits"]["test"]
                                                                         ["per_grasp"].popitem()[1]}),
     r"manifest.json: manifest\['split_floors'\]\['splits'\]\['test'\]\['per_grasp'\] must hold the split's grasps "
     r"\[\d+\], got \['999'\]"),
    (lambda m: m.update(grasp_theta_vol_deg={"0": [0, 180]}),
     r"manifest.json: manifest\['grasp_theta_vol_deg'\]\['0'\] must be \[x, y, z\]: three finite numbers"),
])
def test_bad_floors_in_the_manifest_are_named(exported, tiny_dataset, tmp_path, change, message):
    ckpt, _ = exported
    dataset = _dataset_copy(tiny_dataset, tmp_path / "ds_bad", _edited(change))
    with pytest.raises(ValueError, match=message):
        evaluate(ckpt, dataset, out=tmp_path / "bad.json", latency=False)
    assert not (tmp_path / "bad.json").exists()


def test_latency_helper_median():
    calls = []
    from hupbench.evaluation.latency import measure_latency_ms

    ms = measure_latency_ms(lambda images: calls.append(images.shape), input_size=16, batch=4, warmup=2, repeats=5)
    assert ms >= 0 and math.isfinite(ms)
    assert len(calls) >= 7 and calls[0] == (4, 3, 16, 16)
    # given frames, each run takes the next batch of them in turn
    seen = []
    frames = np.arange(3, dtype=np.float32)[:, None, None, None] * np.ones((3, 4, 8, 8), np.float32)
    measure_latency_ms(lambda images: seen.append(images[:, 0, 0, 0].tolist()), input_size=8, batch=2, warmup=1,
                       repeats=2, channels=4, frames=frames)
    assert seen[:3] == [[0.0, 1.0], [2.0, 0.0], [1.0, 2.0]] and all(len(s) == 2 for s in seen)


@pytest.mark.slow
def test_checkpoint_eval_times_pytorch_and_onnxruntime(exported, tiny_dataset, tmp_path):
    ckpt, _ = exported
    r = evaluate(ckpt, tiny_dataset, out=tmp_path / "timed.json", latency=True)["results"]
    for runtime in ("pytorch", "onnxruntime"):
        assert all(v > 0 for v in r["latency_ms_per_image"][runtime].values()), runtime
    assert not list(tmp_path.glob("*.onnx"))


def test_model_label_names_what_the_model_reads_and_its_heads():
    from hupbench.evaluation.evaluate import model_label

    assert model_label({"name": "hupnet", "backbone": "resnet18"}, 128) == "HUPNet (ResNet-18, 128 px)"
    assert model_label({"name": "hupnet", "backbone": "resnet18", "input_channels": 4}, 128) == \
        "HUPNet (ResNet-18, 128 px, RGB-D)"
    assert model_label({"name": "hupnet", "backbone": "resnet18", "input_channels": 4, "depth_anchor": True,
                        "probe_head": "rigid", "probe_crop_px": 64, "backbone_size": 128}, 256) == \
        "HUPNet (ResNet-18, 256 px, backbone at 128 px, RGB-D, depth-anchored, rigid probe, 64 px probe crop)"
    assert model_label({"name": "hupnet", "backbone": "resnet18", "input_channels": 4, "depth_anchor": True,
                        "heatmap_stride": 4, "probe_fit": "depth", "hand_fit": "depth"}, 128) == \
        "HUPNet (ResNet-18, 128 px, RGB-D, depth-anchored, stride-4 heatmaps, probe fitted to depth, hand fitted " \
        "to depth)"
    assert model_label({"name": "hupnet", "backbone": "resnet18", "input_channels": 4, "depth_anchor": True,
                        "segmentation": True, "probe_fit": "depth", "hand_fit": "depth"}, 128) == \
        "HUPNet (ResNet-18, 128 px, RGB-D, depth-anchored, segmentation, probe fitted to depth, hand fitted to depth)"
    # a hand fit started from the model's training hands says so, unless its settings turn them off
    hands = [[[0.0, 0.0, 0.5]] * 21] * 3
    fitting = {"name": "hupnet", "backbone": "resnet10", "hand_fit": "depth", "hand_templates": hands}
    assert model_label(fitting | {"fit_settings": {"hand": {"iterations": 24}}}, 128) == \
        "HUPNet (ResNet-10, 128 px, hand fitted to depth (from 3 training hands, iterations=24))"
    assert model_label(fitting | {"fit_settings": {"hand": {"templates": False}}}, 128) == \
        "HUPNet (ResNet-10, 128 px, hand fitted to depth (templates=False))"


def test_eval_without_out_writes_beside_the_model_not_the_leaderboard(exported, tiny_dataset, tmp_path, monkeypatch,
                                                                      capsys):
    """No --out: the results go to <model folder>/eval/<model file>.<split>.json, and nothing appears under
    leaderboard/ (a first eval must not leave the repository's leaderboard broken)."""
    import shutil

    _, onnx_path = exported
    model = tmp_path / "run" / "model.onnx"
    model.parent.mkdir()
    shutil.copy(onnx_path, model)
    monkeypatch.chdir(tmp_path)
    (tmp_path / "leaderboard" / "results").mkdir(parents=True)
    assert main(["eval", str(model), str(tiny_dataset), "--no-latency", "--split", "val"]) == 0
    expected = tmp_path / "run" / "eval" / "model.onnx.val.json"
    assert EV.default_results_path(model, "val") == expected
    printed = capsys.readouterr().out
    assert f"results written to {expected}" in printed
    assert "not a leaderboard row: --out leaderboard/results/NAME.json --training-command" in printed
    results = load_results(expected)
    assert (results["dataset"]["split"], results["run_name"]) == ("val", "tiny_hopenet")  # the ONNX metadata's
    assert list((tmp_path / "leaderboard" / "results").iterdir()) == []


def test_eval_figures(exported, tiny_dataset, tmp_path, monkeypatch, capsys):
    """--figures DIR: sample frames, the worst frames and the PCK curve as PNGs; the worst are the frames of
    largest MPJPE."""
    import cv2

    from hupbench.evaluation import figures as F

    ckpt, _ = exported
    monkeypatch.setattr(EV.EvalModel, "predict", _shifted_truth_predictor(tiny_dataset, 8))
    figures = tmp_path / "figs"
    assert main(["eval", str(ckpt), str(tiny_dataset), "--out", str(tmp_path / "r.json"), "--no-latency",
                 "--batch-size", "8", "--figures", str(figures)]) == 0
    printed = capsys.readouterr().out
    for key, name in F.FIGURES.items():
        path = figures / name
        assert f"figure, {key}: {path}" in printed
        image = cv2.imread(str(path))
        assert image is not None and image.std() > 10, name  # drawn, not blank
    # two panels of PANEL_IN inches per row, N_SAMPLE rows: a 64 px frame is drawn enlarged
    samples = cv2.imread(str(figures / "samples.png"))
    assert samples.shape[1] == round(2 * F.PANEL_IN * F.DPI)
    assert samples.shape[0] > F.N_SAMPLE * F.PANEL_IN * F.DPI
    # the default folder is beside the model
    assert EV.default_figures_dir(ckpt, "test") == ckpt.parent / "eval" / "model.pt.test.figures"


def test_frame_choice_known_answer():
    from hupbench.evaluation.figures import frame_choice

    errors = np.array([1.0, 9.0, 3.0, 9.0, 2.0, 7.0, 0.5, 4.0, 8.0])
    samples, worst = frame_choice(errors, n_sample=3, n_worst=4)
    assert samples == [0, 4, 8]
    assert worst == [1, 3, 8, 5]  # largest first, ties by row
    assert frame_choice(np.array([5.0]), n_sample=4, n_worst=4) == ([0], [0])


def test_the_dataset_is_recorded_by_name_and_hashes_and_its_grasps_hash_printed(exported, tiny_dataset, tmp_path):
    """The results name the dataset by its name and the sha256 of its manifest and grasps, never by a path of the
    machine that evaluated it; eval prints the grasps' sha256 (in its log and its table)."""
    ckpt, _ = exported
    lines = []
    answer = evaluate(ckpt, tiny_dataset, out=tmp_path / "r.json", latency=False, log=lines.append)
    record = answer["results"]["dataset"]
    assert record["grasps_sha256"] == file_sha256(tiny_dataset / "grasps.npz")
    assert record["manifest_sha256"] == file_sha256(tiny_dataset / "manifest.json")
    assert record["name"] == "hupbench dataset (60 frames)" and "path" not in record
    assert str(tiny_dataset.parent) not in json.dumps(load_results(tmp_path / "r.json"))
    assert f"grasps sha256 {record['grasps_sha256']}" in "\n".join(lines)
    assert re.search(rf"dataset grasps sha256\s+{record['grasps_sha256']}", answer["table"])


def test_the_pytorch_network_runs_channels_last_with_the_checkpoints_outputs(exported):
    """eval's PyTorch network runs in channels_last (faster at batch 1); what it outputs is the checkpoint's model's
    in the default layout."""
    from hupbench.checkpoint import load_model
    from hupbench.evaluation.prediction import EvalModel
    from hupbench.inference.export import contract_model

    ckpt, _ = exported
    net = EvalModel(ckpt)
    model, payload = load_model(ckpt)
    plain = contract_model(model, payload, str(ckpt))
    images = torch.rand(3, net.channels, net.input_size, net.input_size, generator=torch.Generator().manual_seed(0))
    out = net.network(images)
    with torch.inference_mode():
        ref = dict(zip(plain.outputs, plain(images)))
    np.testing.assert_allclose(out.points3d, ref["points3d"].double().numpy(), atol=1e-6)
    np.testing.assert_allclose(out.points2d, ref["points2d"].double().numpy(), atol=1e-6)
