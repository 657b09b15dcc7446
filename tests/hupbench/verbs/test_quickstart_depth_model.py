"""The quickstart with a model that reads depth (the recommended HUPNet with its segmentation head and fits) in place
of its HOPE-Net: every stage runs, and the predict stage hands the test frame's depth map to the model with its image
(before, predict refused the run's own model: "reads RGB and depth: pass --depth"). About 45 s on a 2-core CPU, the
same as the fast quickstart's own: marked slow, since test_quickstart_quiet.py already runs the pipeline once."""

import json
from pathlib import Path

import pytest

from hupbench.config import compose
from hupbench.verbs.quickstart import run_quickstart, summary_lines

#: the model that reads depth, in place of the fast run's own model entry
DEPTH_MODEL = ["model=hupnet_seg", "loss.probe_symmetry=half_turn"]


@pytest.mark.slow
def test_a_depth_model_runs_every_stage_and_predicts_with_its_depth(tmp_path):
    # the fast run's training list as packaged (64 px, its steps and batch), its model swapped
    train = [o for o in compose("quickstart").fast_overrides.train if not o.startswith("model=")] + DEPTH_MODEL
    overrides = ",".join(f"'{o}'" for o in train)
    cfg = compose("quickstart", [f"out_dir={tmp_path}", "fast=true", f"fast_overrides.train=[{overrides}]"])
    result = run_quickstart(cfg, log=lambda *_: None)
    work = tmp_path / "fast"
    assert set(result["stages"]) == {"preview", "grasps", "dataset", "verify", "train", "eval", "export", "predict"}
    record = json.loads((work / "predict" / "predictions.json").read_text())["images"][0]
    assert record["ok"] and len(record["keypoints_3d_m"]) == 29, record
    assert Path(record["depth"]).parent == work / "dataset" / "test" / "depth", record
    assert Path(record["depth"]).stem == Path(record["path"]).stem, record
    # the next-step command gives the model its depth too
    text = "\n".join(summary_lines(result))
    assert f"--depth {work / 'dataset' / 'test' / 'depth'}" in text
