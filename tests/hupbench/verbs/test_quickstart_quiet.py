"""The fast quickstart run once in a fresh interpreter: every stage (preview, grasps, dataset, verify, train, eval,
ONNX export, predict) writes what it promises, and the output is quiet: no Python warning, no library chatter a user
cannot act on.

Warnings that mean nothing to the user are filtered at their source, only there (e.g. the ONNX
exporter's in hupbench/inference/export.py); this test runs the whole pipeline in a fresh interpreter with
PYTHONWARNINGS unset, so a new one anywhere shows up. Measured on a 2-core CPU machine: 33 s and 40 s
(export 9 s, dataset 11 s, train 6 s, grasps 5 s), 117 s while another process loaded both cores; so
it runs in the default suite (the slow mark is for tests over a minute on an idle machine).
"""

import json
import os
import re
import subprocess
import sys

import cv2
import pytest

from helpers import REPO


#: what a warning looks like on a console: Python's "file:line: XWarning: text" and its source line,
#: torch's TracerWarning, the ONNX exporter's registry messages, C++ warnings of torch ("[W ...]",
#: glog's "W0312 12:00:00") and onnxruntime ("[W:onnxruntime:...]")
WARNING_PATTERNS = [
    re.compile(r"\b[A-Z]\w*Warning\b"),
    re.compile(r"warnings\.warn"),
    re.compile(r"torchvision is not installed"),
    re.compile(r"LeafSpec"),
    re.compile(r"^\[W[ :]"),
    re.compile(r"^W\d{4} \d\d:\d\d:\d\d"),
    re.compile(r"^WARNING\b"),
]


def warning_lines(text: str) -> list[str]:
    """The lines of ``text`` (progress bars split at their carriage returns) that look like a warning."""
    lines = re.split(r"[\r\n]+", text)
    return [line for line in lines if any(p.search(line) for p in WARNING_PATTERNS)]


def test_warning_lines_are_recognised():
    """The detector finds each kind of warning the suite has met, and not the quickstart's own lines."""
    seen = [
        "/usr/lib/python3/site-packages/torch/onnx/_internal/exporter/_registration.py:107: UserWarning: x",
        "  warnings.warn(",
        "torchvision is not installed. Skipping torchvision::roi_pool",
        "/x/torch/utils/_pytree.py:1: FutureWarning: isinstance(treespec, LeafSpec) is deprecated",
        "model.py:12: TracerWarning: Converting a tensor to a Python boolean might cause the trace to be incorrect",
        "[W socket.cpp:663] [c10d] The client socket has failed to connect",
        "W0312 10:11:12.123000 140 torch/_export/x.py:1] something",
        "[W:onnxruntime:, graph.cc:1] Removing initializer",
        "WARNING:root:something",
    ]
    assert warning_lines("\n".join(seen)) == seen
    ours = ("[5/8] train: hopenet_r10_128, 10 steps of 4\r rendering:  33%|###3      | 12/36 [00:19<00:38]\n"
            "  ONNX vs PyTorch: max 3D difference 5.96e-05 mm\nhupbench quickstart finished in 1.9 min")
    assert warning_lines(ours) == []


@pytest.fixture(scope="module")
def fast_run(tmp_path_factory):
    """(out_dir, the finished process) of `hupbench quickstart fast=true` in a fresh interpreter, run once for the
    tests of this file (the whole pipeline takes 30-120 s)."""
    out_dir = tmp_path_factory.mktemp("quickstart")
    env = {k: v for k, v in os.environ.items() if k != "PYTHONWARNINGS"}
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    proc = subprocess.run([sys.executable, "-m", "hupbench.cli", "quickstart", "fast=true", f"out_dir={out_dir}"],
                          capture_output=True, text=True, env=env, timeout=900, cwd=out_dir)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return out_dir, proc


def test_fast_quickstart_prints_no_warning(fast_run):
    _, proc = fast_run
    assert "hupbench quickstart finished in" in proc.stdout and "[8/8] predict" in proc.stdout, proc.stdout
    found = warning_lines(proc.stdout) + warning_lines(proc.stderr)
    assert not found, "warnings reached the user:\n" + "\n".join(found)


def test_fast_quickstart_runs_every_stage(fast_run):
    """hupbench quickstart --fast: grasps -> dataset -> verify -> train -> eval -> export -> predict, with a summary."""
    tmp_path, proc = fast_run
    out = proc.stdout
    for stage in ("[2/8] grasps", "[4/8] verify", "[5/8] train", "[8/8] predict"):
        assert stage in out
    assert "hupbench quickstart finished in" in out and "test MPJPE: all" in out
    work = tmp_path / "fast"
    results = json.loads((work / "results" / "quickstart.json").read_text())
    # the test split: one grasp x the r_circ 0.4 sphere's 12 views (the paper protocol keeps the poles)
    assert results["dataset"]["frames"] == 12 and results["metrics"]["mpjpe_mm"]["all"] > 0
    predictions = json.loads((work / "predict" / "predictions.json").read_text())
    record = predictions["images"][0]
    assert len(record["keypoints_3d_m"]) == 29
    assert cv2.imread(str(next((work / "predict").glob("*_overlay.png")))).shape[:2] == (64, 64)
    assert (work / "model.onnx").is_file() and (work / "run" / "summary.json").is_file()
    # the summary lists every picture it made, and they exist
    for picture in (tmp_path / "preview.png", work / "grasps" / "contact_sheet.png",
                    *(work / "results" / "figures" / n for n in ("samples.png", "worst.png", "pck.png"))):
        assert picture.is_file() and str(picture) in out, picture
    assert "1 grasp to train on, 1 to validate on, 1 held out for the test" in out
    assert f"tensorboard --logdir {work / 'run' / 'tb'}" in out and "\nnext:\n" in out
    record = json.loads((tmp_path / "run.json").read_text())
    assert set(record["stages"]) == {"preview", "grasps", "dataset", "verify", "train", "eval", "export", "predict"}
