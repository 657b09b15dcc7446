"""The quickstart's closing summary: folders explained, every picture listed, the split in words, next commands."""

from pathlib import Path

from hupbench.verbs.quickstart import split_words, summary_lines


def _result(tmp_path):
    work = tmp_path / "fast"
    for name in ("grasps", "dataset", "run", "results", "predict"):
        (work / name).mkdir(parents=True)
    return {
        "out_dir": str(tmp_path), "seconds": 90.0, "render_platform": "egl", "stages": {"preview": 1.0, "grasps": 20.0},
        "preview": str(tmp_path / "preview.png"), "grasps_npz": str(work / "grasps" / "grasps.npz"),
        "contact_sheet": str(work / "grasps" / "contact_sheet.png"), "dataset": str(work / "dataset"),
        "checkpoint": str(work / "run" / "checkpoints" / "last.pt"), "run_dir": str(work / "run"),
        "val_mpjpe_mm": {"first": 250.04, "last": 120.06, "steps": 10},
        "results": str(work / "results" / "quickstart.json"),
        "eval_figures": {"samples": str(work / "results" / "figures" / "samples.png"),
                         "worst": str(work / "results" / "figures" / "worst.png"),
                         "pck": str(work / "results" / "figures" / "pck.png")},
        "metrics": {"all": 100.0, "hand": 90.0, "probe": 126.25}, "floor_mm": None,
        "onnx": str(work / "model.onnx"), "parity": {"points3d_mm": 1e-4},
        "predictions": str(work / "predict" / "predictions.json"),
        "overlay": str(work / "predict" / "000000_overlay.png"), "run_info": str(tmp_path / "run.json"),
    }


def test_summary_lists_folders_pictures_and_next_commands(tmp_path):
    result = _result(tmp_path)
    text = "\n".join(summary_lines(result))
    work = tmp_path / "fast"
    # the folders, full/ and fast/ explained
    assert f"{tmp_path / 'full'} everything the full run makes, {work} everything --fast makes" in text
    for name in ("grasps", "dataset", "run", "results", "predict"):
        assert f"  {work / name}/: " in text
    # every picture
    for key in ("preview", "contact_sheet", "overlay"):
        assert result[key] in text
    for name, path in result["eval_figures"].items():
        assert f"eval figure, {name}: {path}" in text
    # the validation figure names its step; the next commands use this run's paths
    assert "250.0 mm untrained -> 120.1 mm at step 10 (the progress bar's last figure)" in text
    assert f"hupbench predict {result['onnx']} my_photos/" in text
    assert f"tensorboard --logdir {work / 'run' / 'tb'}" in text
    assert f"hupbench verify {result['dataset']} --sample-sheet" in text
    assert f"hupbench eval {result['checkpoint']} {result['dataset']} --figures" in text
    assert "hupbench train +experiment=" in text and "python train.py +experiment=" in text
    assert "{" not in text  # no Python dict printed


def test_split_in_words():
    assert split_words({"train": 3, "val": 1, "test": 1}).startswith(
        "3 grasps to train on, 1 to validate on, 1 held out for the test")
    assert split_words({"train": 1, "val": 1, "test": 1}).startswith("1 grasp to train on")


def test_summary_prints_the_test_error_beside_the_split_floor(tmp_path):
    result = _result(tmp_path) | {"floor_mm": {"all": 22.27, "hand": 8.17, "probe": 59.3}}
    lines = summary_lines(result)
    assert ("test MPJPE: all 100.0 mm (mean over 29 keypoints), hand 90.0 mm, probe 126.2 mm  (a short CPU run: see "
            "leaderboard/ for the real ones)") in lines
    floor = lines.index("test split's floor (the nearest training grasp under the true camera, what recalling training "
                        "grasps scores): all 22.3 mm, hand 8.2 mm, probe 59.3 mm")
    assert lines[floor - 1].startswith("test MPJPE: ")


def test_the_next_predict_command_of_a_depth_model_passes_the_depth(tmp_path):
    """A model that reads depth refuses images without their depth maps: the next-step command gives it the
    quickstart's own test frames and their depth folder, which predict reads as they are."""
    result = _result(tmp_path) | {"reads_depth": True}
    text = "\n".join(summary_lines(result))
    dataset = Path(result["dataset"])
    assert (f"hupbench predict {result['onnx']} {dataset / 'test' / 'rgb'} --depth {dataset / 'test' / 'depth'} "
            "--out predictions") in text
    assert "my_photos/" not in text
