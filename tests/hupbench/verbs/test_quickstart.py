import json
import re

import cv2
import pytest

from hupbench.cli import main
from hupbench.config import compose
from hupbench.verbs.quickstart import run_quickstart


def test_quickstart_writes_preview_and_run_record(tmp_path):
    cfg = compose("quickstart", [f"out_dir={tmp_path}", "stop_after=preview"])
    result = run_quickstart(cfg, log=lambda *_: None)
    sheet = cv2.imread(result["preview"])
    assert sheet is not None and sheet.shape[0] > 256 and sheet.shape[1] > 512
    # all 29 keypoints of the default view are inside the image
    assert result["keypoints_in_view"] == 29
    record = json.loads((tmp_path / "run.json").read_text())
    assert record["config"]["camera"]["fx"] == 480.0
    # the tests run inside the repository, so the record names a real commit
    assert re.fullmatch(r"[0-9a-f]{40}(\+dirty)?", record["git_commit"]), record["git_commit"]
    assert record["packages"]["pyrender"] == "0.1.45"
    assert record["render_platform"] in ("egl", "osmesa")


def test_quickstart_modalities_override(tmp_path):
    cfg = compose("quickstart", [f"out_dir={tmp_path}", "render.modalities=[depth]", "stop_after=preview"])
    result = run_quickstart(cfg, log=lambda *_: None)
    sheet = cv2.imread(result["preview"])
    # one depth tile and one keypoint tile side by side
    assert sheet.shape[1] < 2 * (256 + 6) + 6 + 1 and sheet.shape[0] < 256 + 22 + 13


def test_cli_reports_bad_input(tmp_path, capsys):
    assert main(["quickstart", f"out_dir={tmp_path}", "camera.width=0"]) == 1
    assert "camera.width must be a whole number from 1 to 4096 (pixels), got 0" in capsys.readouterr().err
    assert main(["quickstart", f"out_dir={tmp_path}", "render.modalities=[rgb,normals]"]) == 1
    assert "unknown modality 'normals'" in capsys.readouterr().err
    assert main(["quickstart", "no_such_key=1"]) == 1
    assert "no_such_key" in capsys.readouterr().err
    assert main(["quickstart", "novalue"]) == 1
    assert "key=value" in capsys.readouterr().err
    assert main(["quickstart", f"out_dir={tmp_path}", "stop_after=training"]) == 1
    assert "stop_after must be one of preview, grasps" in capsys.readouterr().err
    # a bad override of a later stage fails before the first stage renders anything
    assert main(["quickstart", f"out_dir={tmp_path}", "train=['model=nope']"]) == 1
    assert "Could not find 'model/nope'" in capsys.readouterr().err
    assert not (tmp_path / "preview.png").exists()


def test_cli_without_verb_prints_help(capsys):
    assert main([]) == 2
    assert "quickstart" in capsys.readouterr().out


@pytest.mark.parametrize("override", ["view.distance_m=-1", "view.elevation_deg=120"])
def test_bad_view_is_rejected(tmp_path, override, capsys):
    assert main(["quickstart", f"out_dir={tmp_path}", override]) == 1
    err = capsys.readouterr().err
    assert "distance_m must be positive" in err or "elevation_deg must be in [-90, 90]" in err
