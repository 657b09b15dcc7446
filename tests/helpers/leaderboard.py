"""Leaderboard rows for tests: a measured results file, its training log, a split's floor block."""

import json
from pathlib import Path

from hupbench.evaluation.leaderboard import README
from hupbench.evaluation.leaderboard_readme import LATENCY_PLOT, TRAINING_PLOT
from hupbench.evaluation.results import blank_results

from helpers import REPO


def triplet(hand, probe):
    return {"hand": hand, "probe": probe, "all": (21 * hand + 8 * probe) / 29}


def split_floor_block(frames=(2880, 2880)):
    """The test split's floor as the manifest holds it: grasps 3 and 12 (``frames`` each), nearest training
    grasps 0 and 1."""
    return {"floor_kind": "nearest_train_grasp", "floor_mm": triplet(20.0, 40.0),
            "nearest_train_grasp_mm": triplet(20.0, 40.0), "nearest_train_view_mm": None,
            "train_mean_mm": triplet(35.0, 60.0),
            "per_grasp": {"3": {"floor_mm": triplet(15.0, 30.0), "nearest_train_grasp_id": 0,
                                "nearest_train_grasp_mm": triplet(15.0, 30.0), "nearest_train_view_mm": None,
                                "train_mean_mm": triplet(30.0, 50.0), "frames": frames[0]},
                          "12": {"floor_mm": triplet(25.0, 50.0), "nearest_train_grasp_id": 1,
                                 "nearest_train_grasp_mm": triplet(25.0, 50.0), "nearest_train_view_mm": None,
                                 "train_mean_mm": triplet(40.0, 70.0), "frames": frames[1]}}}


def intervals_block(floor=True):
    """A results file's bootstrap intervals over two test grasps (``floor``: of the split floor too)."""
    return {"method": "percentile bootstrap over test grasps", "confidence": 0.95, "resamples": 10_000, "seed": 0,
            "grasps": 2, "mpjpe_mm": {"hand": [9.0, 11.0], "probe": [16.0, 22.0], "all": [10.9, 13.8]},
            "split_floor_mm": {"hand": [15.0, 25.0], "probe": [30.0, 50.0], "all": [19.1, 31.9]} if floor else None}


#: the committed leaderboard folder
COMMITTED = REPO / "leaderboard"
#: what the leaderboard writes
OUTPUTS = (README, LATENCY_PLOT, TRAINING_PLOT)


def measured(name, label, all_mm, hand, probe, onnx_ms, torch_ms, wall_s, hardware="1x H100", log=True):
    d = blank_results("measured", name)
    d["model"] |= {"name": "hopenet", "label": label, "parameters": 12_345_678, "input_size": 128, "format": "onnx"}
    d["dataset"] |= {"name": "hupbench default", "frames": 5760, "manifest_sha256": "ab" * 32,
                     "grasps_sha256": "cd" * 32}
    d["metrics"] = {"mpjpe_mm": {"all": all_mm, "hand": hand, "probe": probe, "all_averaging": "mean over 29 keypoints"},
                    "root_relative_hand_mpjpe_mm": 7.0, "pa_mpjpe_hand_mm": 4.5678, "pck_auc_0_50mm": 0.81234,
                    "pixel_error_px": 2.0, "probe_symmetric_mpjpe_mm": probe - 1.0,
                    "spread_ratio": {"x": 0.9, "y": 1.01, "z": 0.456}}
    d["latency_ms_per_image"]["onnxruntime"]["batch1"] = onnx_ms
    d["latency_ms_per_image"]["pytorch"]["batch1"] = torch_ms
    d["training"] |= {"wall_s": wall_s, "hardware": hardware, "command": f"python train.py run_name={name}",
                      "log": f"logs/{name}.jsonl" if log else None}
    return d


def write_log(path: Path, wall_s: float, final_mm: float, n: int = 5) -> None:
    lines = [json.dumps({"event": "train", "step": 0, "samples_seen": 0, "wall_s": 0.0, "train_wall_s": 0.0,
                         "loss": 1.0, "lr": 1e-3})]
    for i in range(1, n + 1):
        lines.append(json.dumps({"event": "val", "step": 10 * i, "epoch": float(i), "samples_seen": 640 * i,
                                 "wall_s": 1.1 * wall_s * i / n, "train_wall_s": wall_s * i / n,
                                 "val_mpjpe_mm": {"all": final_mm * (1 + 2 / i), "hand": 1.0, "probe": 2.0}}))
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n")
