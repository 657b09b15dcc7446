"""What the verbs' matrix files do not cover: torch threads beyond the cores in train-grasp-sampler, and
Ctrl-C (one line and exit 130, the workers silent and gone)."""

import os
import signal
import subprocess
import sys
import threading
import time

import pytest

from hupbench.cli import main
from helpers import REPO
from helpers.faults import like_a_terminal, sigint_state

#: 2 orientations x 8 starts, a short refinement: seconds
SMALL_GRASPS = ["generate.theta_vol_deg=[[0,0,0],[0,0,180]]", "generate.starts_per_theta=8", "refine.iterations=50",
                "generate.short_refine_iterations=5", "generate.n_select=1", "sheet.tile_px=96", "threads=2"]
#: helpers.datasets.TINY_SPEC as overrides
TINY = ["dataset.splits={train:1,val:0,test:1}", "dataset.z_ego_m=[0.5]", "dataset.n_backgrounds=2",
        "dataset.n_gloves=1", "dataset.sphere.r_circ_m=0.4", "dataset.sphere.exclude=[poles]", "dataset.width=64",
        "dataset.height=64", "dataset.fx=120.0", "dataset.fy=120.0", "dataset.cx=32.0", "dataset.cy=32.0",
        "workers=1", "progress=false"]


def _cli(capsys, *argv):
    capsys.readouterr()
    rc = main([str(a) for a in argv])
    captured = capsys.readouterr()
    return rc, captured.out, captured.err


def test_train_grasp_sampler_bounds_its_threads_by_the_cores(tmp_path, capsys, monkeypatch):
    import hupbench.datagen.grasps.cvae_training as cvae_training

    def trained(*_, **__):
        raise AssertionError("the training started")

    monkeypatch.setattr(cvae_training, "train_sampler", trained)
    rc, _, err = _cli(capsys, "train-grasp-sampler", "threads=4096", f"out={tmp_path / 'w.npz'}")
    assert rc == 1 and "threads must be a whole number from 1 to" in err and "got 4096" in err, err


def _interrupt(argv, started, tmp_path, timeout=240):
    """Run ``hupbench ARGV`` in its own process group, send the group SIGINT (as a terminal's Ctrl-C does)
    once ``started(stdout so far)`` holds, and return (exit code, stderr) after every process of the group
    is gone."""
    # a crash would show its native stack here; the progress lines arrive as they are printed
    env = {**os.environ, "PYTHONPATH": str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""),
           "PYTHONFAULTHANDLER": "1", "PYTHONUNBUFFERED": "1"}
    stderr = tmp_path / "stderr.txt"
    with open(stderr, "w") as err_file:
        proc = subprocess.Popen([sys.executable, "-m", "hupbench.cli", *argv], stdout=subprocess.PIPE, stderr=err_file,
                                text=True, env=env, start_new_session=True, cwd=tmp_path,
                                preexec_fn=like_a_terminal)
    lines: list[str] = []
    threading.Thread(target=lambda: lines.extend(proc.stdout), daemon=True).start()
    deadline = time.monotonic() + timeout
    while not started("".join(lines)):
        assert proc.poll() is None, stderr.read_text()
        assert time.monotonic() < deadline, "the run never got to the point of the interrupt"
        time.sleep(0.2)
    state = f"SIGINT of the run: {sigint_state(proc.pid)}; of this test process: {sigint_state()}"
    os.killpg(proc.pid, signal.SIGINT)
    try:
        proc.wait(timeout=120)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        pytest.fail(f"the run did not end within 120 s of Ctrl-C ({state})")
    err = stderr.read_text()
    for _ in range(100):  # the workers follow their parent within seconds
        try:
            os.killpg(proc.pid, 0)
        except ProcessLookupError:
            break
        time.sleep(0.1)
    else:
        pytest.fail("worker processes outlived the interrupted run")
    return proc.returncode, err


def test_ctrl_c_of_generate_is_one_line_and_exit_130_with_its_workers_silent(tiny_grasps, tmp_path):
    out = tmp_path / "ds"
    # 2 grasps x 8 backgrounds x 2 gloves x 10 views at 256 px: long enough to be interrupted mid-way
    argv = ["generate", f"out_dir={out}", f"grasps_path={tiny_grasps}", *TINY, "workers=2", "dataset.width=256",
            "dataset.height=256", "dataset.fx=480.0", "dataset.fy=480.0", "dataset.cx=128.0", "dataset.cy=128.0",
            "dataset.n_backgrounds=8", "dataset.n_gloves=2"]
    rc, err = _interrupt(argv, lambda _: any((out / "train" / ".chunks").glob("*.npz")), tmp_path)
    assert (rc, err.strip()) == (130, "hupbench generate: interrupted"), err
    assert not (out / "manifest.json").exists() and not list(out.rglob(".*.tmp*"))


def test_ctrl_c_of_grasps_is_one_line_and_exit_130(tmp_path):
    out = tmp_path / "g"
    argv = ["grasps", f"out_dir={out}", *SMALL_GRASPS, "refine.iterations=100000", "generate.sampler=random"]
    rc, err = _interrupt(argv, lambda stdout: "generating 2 x 8 candidates" in stdout, tmp_path)
    assert (rc, err.strip()) == (130, "hupbench grasps: interrupted"), err
    assert not out.exists()
