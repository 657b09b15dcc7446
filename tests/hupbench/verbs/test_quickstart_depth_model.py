"""The quickstart with a model that reads depth (the recommended HUPNet with its segmentation head and fits) in place
of its HOPE-Net: every stage runs, and the predict stage hands the test frame's depth map to the model with its image
(before, predict refused the run's own model: "reads RGB and depth: pass --depth"). About 45 s on a 2-core CPU, the
same as the fast quickstart's own: marked slow, since test_quickstart_quiet.py already runs the pipeline once."""

import json
from pathlib import Path

import pytest

from hupbench.config import compose
from hupbench.verbs.quickstart import run_quickstart, summary_lines

DEPTH_MODEL = ["model=hupnet_seg", "loss.probe_symmetry=half_turn", "data.reader.input_size=64", "data.batch_size=4",
               "data.num_workers=0", "data.val_frames=null", "train.max_steps=4", "train.val_every=2",
               "train.ckpt_every=2", "threads=2", "precision=fp32"]


@pytest.mark.slow
def test_a_depth_model_runs_every_stage_and_predicts_with_its_depth(tmp_path):
    overrides = ",".join(f"'{o}'" for o in DEPTH_MODEL)
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
