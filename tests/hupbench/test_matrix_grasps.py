"""The bad-input matrix of `hupbench grasps` (docs/robustness.md, ## grasps).

Every case runs the CLI in this process on a small grasps config with one thing broken. The answer
must be one line `hupbench grasps: error: ...` naming the option or file and what was expected,
exit 1, no traceback, and nothing written: no grasps.npz, grasps.json, candidates.npz or contact
sheet, no temporary file (before the fixes a bad sheet option or out_dir was found only after the
refinement, with grasps.npz and grasps.json already written).
"""

import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from conftest import assert_clean_error, assert_nothing_complete, run_cli  # noqa: E402  (tests/ is on sys.path)

REPO = Path(__file__).resolve().parents[2]
#: 2 orientations x 8 starts = 16 candidates, a short refinement: a case that slipped through would
#: still end in seconds
SMALL = ["generate.theta_vol_deg=[[0,0,0],[0,0,180]]", "generate.starts_per_theta=8", "refine.iterations=50",
         "generate.short_refine_iterations=5", "generate.n_select=1", "sheet.tile_px=96", "threads=2"]
OUTPUTS = ("grasps.npz", "grasps.json", "candidates.npz", "contact_sheet.png", "run.json")


def _write(path: Path, data: bytes) -> Path:
    path.write_bytes(data)
    return path


def _weights(tmp: Path, kind: str) -> Path:
    """A damaged copy of the shipped grasp-sampler weights."""
    from datagen.grasps.cvae import SHIPPED_WEIGHTS

    data = SHIPPED_WEIGHTS.read_bytes()
    path = tmp / "grasp_cvae.npz"
    if kind == "missing":
        return path
    if kind == "empty":
        return _write(path, b"")
    if kind == "truncated":
        return _write(path, data[: len(data) // 2])
    if kind == "random-bytes":
        return _write(path, np.random.default_rng(0).bytes(len(data)))
    if kind == "not-weights":
        np.savez(path, weights=np.zeros(3))
        return path
    raise ValueError(kind)


# id -> make(tmp) -> (overrides, needles); overrides come after SMALL and win
CASES = {
    # malformed overrides
    "override-without-equals": lambda t: (["threads"], ["key=value", "threads"]),
    "override-unknown-key": lambda t: (["generate.colour=red"], ["generate.colour", "not in the config"]),
    "override-unknown-top-key": lambda t: (["colour=red"], ["colour", "not in the config"]),
    "override-bad-syntax": lambda t: (["generate.theta_vol_deg=[[0,0,0]"], ["generate.theta_vol_deg", "key=value"]),
    "override-refine-weight-not-in-config": lambda t: (["refine.w_contact=-1.0"], ["refine.w_contact",
                                                                                  "not in the config"]),
    # threads (torch CPU threads)
    "threads-zero": lambda t: (["threads=0"], ["threads", "whole number from 1"]),
    "threads-negative": lambda t: (["threads=-2"], ["threads", "whole number from 1"]),
    "threads-word": lambda t: (["threads=two"], ["threads", "'two'"]),
    "threads-fraction": lambda t: (["threads=1.5"], ["threads", "1.5"]),
    "threads-nan": lambda t: (["threads=nan"], ["threads", "nan"]),
    "threads-huge": lambda t: (["threads=100000"], ["threads", "100000", "cpu core"]),
    # candidates per orientation
    "starts-per-theta-zero": lambda t: (["generate.starts_per_theta=0"], ["starts_per_theta", "whole number >= 1"]),
    "starts-per-theta-negative": lambda t: (["generate.starts_per_theta=-4"], ["starts_per_theta", "whole number >= 1"]),
    "starts-per-theta-word": lambda t: (["generate.starts_per_theta=many"], ["starts_per_theta", "'many'"]),
    "starts-per-theta-nan": lambda t: (["generate.starts_per_theta=nan"], ["starts_per_theta", "nan"]),
    "starts-per-theta-fraction": lambda t: (["generate.starts_per_theta=2.5"], ["starts_per_theta", "2.5"]),
    "starts-per-theta-huge": lambda t: (["generate.starts_per_theta=1000000000"],
                                        ["starts_per_theta", "4,096", "1,000,000,000"]),
    # how many grasps to keep
    "n-select-zero": lambda t: (["generate.n_select=0"], ["n_select", "whole number >= 1"]),
    "n-select-negative": lambda t: (["generate.n_select=-1"], ["n_select", "whole number >= 1"]),
    "n-select-word": lambda t: (["generate.n_select=five"], ["n_select", "'five'"]),
    "n-select-nan": lambda t: (["generate.n_select=nan"], ["n_select", "nan"]),
    "n-select-more-than-candidates": lambda t: (["generate.n_select=500"], ["n_select", "500", "16 candidates"]),
    # optimiser steps
    "short-refine-iterations-negative": lambda t: (["generate.short_refine_iterations=-1"],
                                                   ["short_refine_iterations", ">= 0"]),
    "short-refine-iterations-word": lambda t: (["generate.short_refine_iterations=ten"],
                                               ["short_refine_iterations", "'ten'"]),
    "short-refine-iterations-huge": lambda t: (["generate.short_refine_iterations=1000000000"],
                                               ["short_refine_iterations", "100,000"]),
    "refine-iterations-negative": lambda t: (["refine.iterations=-5"], ["iterations", ">= 0"]),
    "refine-iterations-word": lambda t: (["refine.iterations=lots"], ["iterations", "'lots'"]),
    "refine-iterations-nan": lambda t: (["refine.iterations=nan"], ["iterations", "nan"]),
    "refine-iterations-bool": lambda t: (["refine.iterations=true"], ["iterations", "true"]),
    "refine-iterations-huge": lambda t: (["refine.iterations=1000000000", "generate.sampler=random"],
                                         ["iterations", "100,000"]),
    # penalty weights and other refinement settings a user can add (+key=value)
    "refine-weight-negative": lambda t: (["+refine.w_contact=-1.0"], ["w_contact", ">= 0"]),
    "refine-weight-nan": lambda t: (["+refine.w_prior=nan"], ["w_prior", "finite"]),
    "refine-weight-inf": lambda t: (["+refine.w_penetration_end=inf"], ["w_penetration_end", "finite"]),
    "refine-weight-word": lambda t: (["+refine.w_self=heavy"], ["w_self", "'heavy'"]),
    "refine-lr-zero": lambda t: (["+refine.lr_joints=0.0"], ["lr_joints", "positive"]),
    "refine-clip-norm-nan": lambda t: (["+refine.clip_norm=nan"], ["clip_norm", "finite"]),
    "refine-min-contact-z-nan": lambda t: (["+refine.min_contact_z_m=nan"], ["min_contact_z_m", "finite"]),
    "refine-min-contact-z-word": lambda t: (["+refine.min_contact_z_m=low"], ["min_contact_z_m", "'low'"]),
    # seed
    "seed-negative": lambda t: (["generate.seed=-1"], ["seed", "-1"]),
    "seed-word": lambda t: (["generate.seed=abc"], ["seed", "'abc'"]),
    "seed-nan": lambda t: (["generate.seed=nan"], ["seed", "nan"]),
    "seed-fraction": lambda t: (["generate.seed=0.5"], ["seed", "0.5"]),
    "seed-huge": lambda t: (["generate.seed=100000000000000000000000"], ["seed", "4294967295"]),
    # probe orientations
    "theta-empty": lambda t: (["generate.theta_vol_deg=[]"], ["theta_vol_deg", "alpha, beta, gamma"]),
    "theta-two-angles": lambda t: (["generate.theta_vol_deg=[[0,0]]"], ["theta_vol_deg", "(1, 2)"]),
    "theta-word": lambda t: (["generate.theta_vol_deg=[[0,0,up]]"], ["theta_vol_deg", "'up'"]),
    "theta-nan": lambda t: (["generate.theta_vol_deg=[[0,0,nan]]"], ["theta_vol_deg", "finite"]),
    "theta-not-nested": lambda t: (["generate.theta_vol_deg=[0,0,0]"], ["theta_vol_deg", "list of"]),
    "theta-huge": lambda t: (["generate.theta_vol_deg=[[0,0,1e9]]"], ["theta_vol_deg", "[-360, 360]"]),
    "sampler-unknown": lambda t: (["generate.sampler=diffusion"], ["sampler", "diffusion"]),
    # pinned ids
    "pinned-ids-out-of-range": lambda t: (["generate.pinned_ids=[0,999]"], ["pinned_ids", "[999]", "0..15"]),
    "pinned-ids-negative": lambda t: (["generate.pinned_ids=[-1]"], ["pinned_ids", "[-1]", "0..15"]),
    "pinned-ids-empty": lambda t: (["generate.pinned_ids=[]"], ["pinned_ids", "non-empty"]),
    "pinned-ids-word": lambda t: (["generate.pinned_ids=[a]"], ["pinned_ids", "'a'"]),
    "pinned-ids-duplicate": lambda t: (["generate.pinned_ids=[1,1]"], ["pinned_ids", "unique"]),
    "pinned-ids-not-a-list": lambda t: (["generate.pinned_ids=3"], ["pinned_ids", "list"]),
    # the contact sheet
    "sheet-tile-zero": lambda t: (["sheet.tile_px=0"], ["sheet.tile_px", "32 to 4096"]),
    "sheet-tile-negative": lambda t: (["sheet.tile_px=-10"], ["sheet.tile_px", "32 to 4096"]),
    "sheet-tile-huge": lambda t: (["sheet.tile_px=100000"], ["sheet.tile_px", "100000"]),
    "sheet-tile-word": lambda t: (["sheet.tile_px=big"], ["sheet.tile_px", "'big'"]),
    "sheet-platform-unknown": lambda t: (["sheet.platform=vulkan"], ["sheet.platform", "vulkan"]),
    # the output folder
    "out-dir-is-a-file": lambda t: ([f"out_dir={_write(t / 'file', b'x')}"], ["out_dir", "file", "not a folder"]),
    "out-dir-under-a-file": lambda t: ([f"out_dir={_write(t / 'file', b'x') / 'g'}"], ["out_dir", "file is a file"]),
    "out-dir-empty": lambda t: (["out_dir="], ["out_dir", "folder path"]),
}

# the grasp sampler's weights (the package's datagen/grasps/weights/grasp_cvae.npz; a damaged installation)
WEIGHTS = {
    "sampler-weights-missing": ["grasp_cvae.npz", "missing", "train-grasp-sampler"],
    "sampler-weights-empty": ["grasp_cvae.npz", "empty (0 bytes)"],
    "sampler-weights-truncated": ["grasp_cvae.npz", "not a zip"],
    "sampler-weights-random-bytes": ["grasp_cvae.npz", "not a zip"],
    "sampler-weights-not-weights": ["grasp_cvae.npz", "not a grasp CVAE weights file"],
}


def _files(folder: Path) -> dict:
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in folder.rglob("*") if p.is_file()}


@pytest.mark.matrix
@pytest.mark.parametrize("case", [*CASES, *WEIGHTS])
def test_matrix_grasps(case, tmp_path, capsys, monkeypatch):
    if case in WEIGHTS:
        import datagen.grasps.cvae as cvae

        monkeypatch.setattr(cvae, "SHIPPED_WEIGHTS", _weights(tmp_path, case.removeprefix("sampler-weights-")))
        overrides, needles = [], WEIGHTS[case]
    else:
        overrides, needles = CASES[case](tmp_path)
    before = _files(tmp_path)
    answer = run_cli(capsys, "grasps", f"out_dir={tmp_path / 'g'}", *SMALL, *overrides)
    assert_clean_error(answer, *needles, prefix="hupbench grasps: error:")
    assert answer.rc == 1
    # nothing written: no output folder, no grasps or candidates file, no temporary file, nothing changed
    assert not (tmp_path / "g").exists()
    assert_nothing_complete(tmp_path, *OUTPUTS)
    assert _files(tmp_path) == before


@pytest.mark.matrix
def test_matrix_grasps_read_only_out_dir(tmp_path):
    """out_dir on a read-only file system, refused before the refinement (root writes through file
    modes, so a read-only tmpfs in a private mount namespace; skipped where one cannot be mounted)."""
    if shutil.which("unshare") is None:
        pytest.skip("unshare(1) is not installed")
    mount = tmp_path / "ro"
    mount.mkdir()
    probe = subprocess.run(["unshare", "-m", "--propagation", "private", "sh", "-c", f"mount -t tmpfs tmpfs {mount}"],
                           capture_output=True, text=True)
    if probe.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs in a private mount namespace here: {probe.stderr.strip()}")
    argv = [sys.executable, "-m", "hupbench.cli", "grasps", f"out_dir={mount / 'g'}", *SMALL]
    script = f"mount -t tmpfs -o ro,size=64k tmpfs {mount} && exec " + " ".join(f"'{a}'" for a in argv)
    env = {**os.environ, "PYTHONPATH": str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    proc = subprocess.run(["unshare", "-m", "--propagation", "private", "sh", "-c", script], capture_output=True,
                          text=True, env=env, timeout=120)
    assert proc.returncode == 1, proc
    errors = [line for line in proc.stderr.splitlines() if "error:" in line]
    assert len(errors) == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert errors[0].startswith("hupbench grasps: error:") and f"{mount / 'g'}" in errors[0], errors
    assert "read-only file system" in errors[0], errors
    # refused before the work: the refinement's progress lines never came
    assert "candidates refined" not in proc.stdout, proc.stdout
