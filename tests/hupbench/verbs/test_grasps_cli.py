import json

import numpy as np

from hupbench.cli import main
from hupbench.config import compose
from hupbench.verbs.grasps import run_grasps

# The refinement is chaotic: a last-digit difference between CPUs' kernels (ATen's AVX-512 / AVX2 / scalar
# code, MKL's code paths) grows from 1e-7 to 1e-2 rad or m in its 40 steps and decides which candidates pass
# the plausibility thresholds. 2 x 4 candidates gave 0 or 1 plausible at seed 0 (it failed on an AMD EPYC);
# 2 x 8 give 4-5 at seed 0 under each of those kernel variants there, and 3-12 at seeds 0-9.
SMALL = ["generate.theta_vol_deg=[[0,0,0],[0,0,180]]", "generate.starts_per_theta=8", "refine.iterations=200",
         "generate.n_select=1", "sheet.tile_px=96", "threads=1"]
N_CANDIDATES = 16


def test_grasps_writes_npz_json_and_contact_sheet(tmp_path):
    result = run_grasps(compose("grasps", [f"out_dir={tmp_path}", *SMALL]), log=lambda *_: None)
    assert result["selected"] == 1 and result["candidates"] == N_CANDIDATES
    data = np.load(tmp_path / "grasps.npz")
    assert data["hand_pose"].shape == (1, 48) and data["hand_trans"].shape == (1, 3)
    assert data["keypoints_probe"].shape == (1, 21, 3) and data["T_gen_probe"].shape == (1, 4, 4)
    assert data["score_plausible"].all()
    assert (data["score_max_penetration_mm"] <= 2.0).all() and (data["score_pads_in_contact"] >= 3).all()
    record = json.loads((tmp_path / "grasps.json").read_text())
    assert [row["grasp_id"] for row in record["grasps"]] == data["grasp_id"].tolist()
    assert record["candidates"]["total"] == N_CANDIDATES
    candidates = np.load(tmp_path / "candidates.npz")
    assert len(candidates["grasp_id"]) == N_CANDIDATES
    # the selected grasp is one of the plausible candidates, and the counts agree everywhere
    assert candidates["score_plausible"][data["grasp_id"]].all()
    assert record["candidates"]["plausible"] == result["plausible"] == candidates["score_plausible"].sum()
    assert (tmp_path / "contact_sheet.png").stat().st_size > 1000


def test_grasps_cli_errors(tmp_path, capsys):
    assert main(["grasps", f"out_dir={tmp_path}", *SMALL, "generate.n_select=50"]) == 1
    assert "cannot select 50 grasps" in capsys.readouterr().err
    assert main(["grasps", f"out_dir={tmp_path}", *SMALL, "generate.pinned_ids=[0,99]"]) == 1
    assert "unknown grasp id(s) [99]" in capsys.readouterr().err
    assert main(["grasps", f"out_dir={tmp_path}", *SMALL, "generate.theta_vol_deg=[[0,0]]"]) == 1
    assert "Theta_Vol" in capsys.readouterr().err
    # nothing that looks complete was written by the failed runs
    assert not (tmp_path / "grasps.npz").exists()
