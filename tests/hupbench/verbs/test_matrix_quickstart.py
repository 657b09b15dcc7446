"""The bad-input matrix of `hupbench quickstart` (docs/robustness.md, ## quickstart).

The quickstart composes and checks its own options and every later stage's config (grasps,
generate, train) before its first stage renders the preview. One case per field group here
(tests/hupbench/verbs/test_quickstart_config.py has the others, as unit tests), the stages' lists and
the output folder. Every case here must therefore fail
at once: one line `hupbench quickstart: error: ...` naming the option and what was expected
(argparse's usage errors exit 2, the rest 1), no traceback, no stage started (no "[1/8] preview"
line) and nothing written under out_dir.
"""

from pathlib import Path

import pytest

from helpers.faults import run_in_namespace
from helpers.cli import assert_clean_error, run_cli  # noqa: E402  (tests/ is on sys.path)



def _write(path: Path, data: bytes) -> Path:
    path.write_bytes(data)
    return path


# id -> make(tmp) -> (arguments after out_dir, needles)
CASES = {
    # malformed overrides and options
    "override-without-equals": lambda t: (["fast"], ["key=value", "fast"]),
    "override-unknown-key": lambda t: (["camera.colour=red"], ["camera.colour", "not in the config"]),
    "override-unknown-top-key": lambda t: (["colour=red"], ["colour", "not in the config"]),
    "override-bad-syntax": lambda t: (["camera.width=[1"], ["camera.width=[1", "key=value"]),
    "option-unknown": lambda t: (["--fastest"], ["unrecognized arguments", "--fastest"]),
    # the quickstart's own options
    "stop-after-unknown": lambda t: (["stop_after=deploy"], ["stop_after", "deploy", "preview, grasps"]),
    # the preview camera
    "camera-width-zero": lambda t: (["camera.width=0"], ["camera", "width", "from 1 to 4096"]),
    # the preview view
    "view-distance-zero": lambda t: (["view.distance_m=0"], ["view", "distance_m", "positive"]),
    # rendering
    "render-platform-unknown": lambda t: (["render.platform=vulkan"], ["render.platform", "vulkan"]),
    # the later stages' overrides (lists of key=value), checked as their own verbs check them
    "stage-list-unquoted": lambda t: (["grasps=[generate.n_select=0]"], ["grasps=[generate.n_select=0]", "key=value",
                                                                        "list element with '=' in it is quoted"]),
    "stage-list-half-quoted": lambda t: (["train=['model=hupnet_seg',threads=2]"], ["threads=", "is quoted"]),
    "grasps-n-select-zero": lambda t: (["grasps=['generate.n_select=0']"], ["grasps stage", "n_select", "whole number >= 1"]),
    "grasps-unknown-key": lambda t: (["grasps=['generate.colour=1']"], ["grasps stage", "generate.colour", "conf/grasps.yaml"]),
    "grasps-threads-huge": lambda t: (["grasps=['threads=100000']"], ["grasps stage", "threads", "100000"]),
    "grasps-sheet-tile-zero": lambda t: (["grasps=['sheet.tile_px=0']"], ["grasps stage", "sheet.tile_px", "32 to 4096"]),
    "dataset-width-zero": lambda t: (["dataset=['dataset.width=0']"], ["dataset stage", "dataset.width", "from 16 to 8192"]),
    "dataset-workers-zero": lambda t: (["dataset=['workers=0']"], ["dataset stage", "workers", ">= 1"]),
    "dataset-splits-negative": lambda t: (["dataset=['dataset.splits={train:3,val:-1,test:0}']"], ["dataset stage", "splits", ">= 0"]),
    "train-max-steps-zero": lambda t: (["train=['train.max_steps=0']"], ["train stage", "conf/quickstart.yaml's train list", "train.max_steps", "whole number", "got 0"]),
    "train-lr-nan": lambda t: (["train=['optim.optimizer.lr=nan']"], ["train stage", "optim.optimizer.lr", "nan"]),
    "train-model-unknown": lambda t: (["train=['model=nope']"], ["train stage", "model/nope"]),
    "train-unknown-key": lambda t: (["train=['train.colour=1']"], ["train stage", "train.colour", "conf/train.yaml"]),
    "fast-stage-list-bad": lambda t: (["--fast", "fast_overrides.train=['train.max_steps=-1']"],
                                      ["train stage", "fast_overrides.train list", "train.max_steps", "whole number", "got -1"]),
    "fast-with-stage-list": lambda t: (["--fast", "grasps=['generate.n_select=2']"],
                                       ["grasps", "not used by the fast quickstart", "fast_overrides.grasps"]),
    # the output folder
    "out-dir-is-a-file": lambda t: ([f"out_dir={_write(t / 'file', b'x')}"], ["out_dir", "file", "not a folder"]),
    "out-dir-under-a-file": lambda t: ([f"out_dir={_write(t / 'file', b'x') / 'qs'}"], ["out_dir", "file is a file"]),
    "out-dir-empty": lambda t: (["out_dir="], ["out_dir", "folder path"]),
}


def _files(folder: Path) -> dict:
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in folder.rglob("*") if p.is_file()}


@pytest.mark.matrix
@pytest.mark.parametrize("case", list(CASES))
def test_matrix_quickstart(case, tmp_path, capsys):
    arguments, needles = CASES[case](tmp_path)
    before = _files(tmp_path)
    answer = run_cli(capsys, "quickstart", f"out_dir={tmp_path / 'qs'}", *arguments)
    line = assert_clean_error(answer, *needles, prefix="hupbench quickstart: error:")
    assert answer.rc == (2 if case == "option-unknown" else 1), answer
    if case == "override-bad-syntax":   # no list element to quote: no word of quoting
        assert "quoted" not in line, line
    # no stage started, nothing written or changed under out_dir (nor beside it)
    assert "[1/" not in answer.out, answer
    assert not (tmp_path / "qs").exists()
    assert _files(tmp_path) == before


@pytest.mark.matrix
def test_matrix_quickstart_read_only_out_dir(tmp_path):
    """out_dir on a read-only file system, refused before the preview (root writes through file modes,
    so a read-only bind mount in a private mount namespace; skipped where one cannot be made)."""
    mount = tmp_path / "ro"
    mount.mkdir()
    answer = run_in_namespace(["quickstart", "--fast", f"out_dir={mount / 'qs'}"], read_only=(mount,), timeout=120)
    assert_clean_error(answer, mount / "qs", "read-only file system", prefix="hupbench quickstart: error:")
    assert answer.rc == 1
    assert "[1/" not in answer.out, answer.out