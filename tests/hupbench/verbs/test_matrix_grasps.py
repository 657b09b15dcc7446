"""The bad-input matrix of `hupbench grasps` (docs/robustness.md, ## grasps).

Every case runs the CLI in this process on a small grasps config with one thing broken: one case per
field group (tests/hupbench/verbs/test_grasps_config.py has the others, as unit tests) and every file. The answer
must be one line `hupbench grasps: error: ...` naming the option or file and what was expected,
exit 1, no traceback, and nothing written: no grasps.npz, grasps.json, candidates.npz or contact
sheet, no temporary file (before the fixes a bad sheet option or out_dir was found only after the
refinement, with grasps.npz and grasps.json already written).
"""

from pathlib import Path

import numpy as np
import pytest

from helpers.faults import run_in_namespace
from helpers.cli import assert_clean_error, assert_nothing_complete, run_cli  # noqa: E402  (tests/ is on sys.path)

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
    from hupbench.datagen.grasps.cvae import SHIPPED_WEIGHTS

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


def _dense_probe(tmp: Path) -> Path:
    """A probe-sized ellipsoid of 81,920 triangles as STL: over the face budget (as a scan exported at full
    resolution)."""
    import trimesh

    mesh = trimesh.creation.icosphere(subdivisions=6)
    mesh.apply_scale([0.03, 0.02, 0.08])
    mesh.apply_translation([0.0, 0.0, -mesh.bounds[0, 2]])
    path = tmp / "dense.stl"
    mesh.export(path)
    return path


def _finished_dataset(tmp: Path) -> Path:
    """A folder with a manifest.json: a finished dataset, whose grasps.npz its frames were rendered from."""
    folder = tmp / "dataset"
    folder.mkdir()
    (folder / "manifest.json").write_text("{}")
    return folder


# id -> make(tmp) -> (overrides, needles); overrides come after SMALL and win
CASES = {
    # malformed overrides
    "override-without-equals": lambda t: (["threads"], ["key=value", "threads"]),
    "override-unknown-key": lambda t: (["generate.colour=red"], ["generate.colour", "not in the config"]),
    "override-unknown-top-key": lambda t: (["colour=red"], ["colour", "not in the config"]),
    "override-bad-syntax": lambda t: (["generate.theta_vol_deg=[[0,0,0]"], ["generate.theta_vol_deg", "key=value"]),
    "override-refine-weight-not-in-config": lambda t: (["refine.w_contact=-1.0"], ["refine.w_contact",
                                                                                  "not in the config"]),
    # one case per field group
    "threads-zero": lambda t: (["threads=0"], ["threads", "whole number from 1"]),
    "starts-per-theta-zero": lambda t: (["generate.starts_per_theta=0"], ["starts_per_theta", "whole number >= 1"]),
    "refine-iterations-negative": lambda t: (["refine.iterations=-5"], ["iterations", ">= 0"]),
    "sheet-tile-zero": lambda t: (["sheet.tile_px=0"], ["sheet.tile_px", "32 to 4096"]),
    # the probe
    "probe-mesh-over-the-face-budget": lambda t: ([f"probe.mesh={_dense_probe(t)}"],
                                                  ["probe.mesh", "dense.stl", "81,920 triangles", "20,000",
                                                   "simplify_quadric_decimation(face_count=20000)"]),
    # the clinic track's subjects and patients (+subjects=clinic)
    "subjects-hand-length-below-adult-sizes": lambda t: (["+subjects=clinic", "subjects.hand_length_mm=[100,220]"],
                                                         ["subjects", "hand_length_mm", "130", "230", "[100, 220]"]),
    "subjects-count-zero": lambda t: (["+subjects=clinic", "subjects.count=0"], ["subjects", "count", "got 0"]),
    "patient-radius-zero": lambda t: (["+subjects=clinic", "patient.radius_m=[0,0.2]"],
                                      ["patient", "radius_m", "from 0.1 to 0.5 m", "[0, 0.2]"]),
    # the output folder
    "out-dir-is-a-file": lambda t: ([f"out_dir={_write(t / 'file', b'x')}"], ["out_dir", "file", "not a folder"]),
    "out-dir-under-a-file": lambda t: ([f"out_dir={_write(t / 'file', b'x') / 'g'}"], ["out_dir", "file is a file"]),
    "out-dir-empty": lambda t: (["out_dir="], ["out_dir", "folder path"]),
    "out-dir-a-finished-dataset": lambda t: ([f"out_dir={_finished_dataset(t)}"], ["out_dir", "holds a finished dataset"]),
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
        import hupbench.datagen.grasps.cvae as cvae

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
    modes, so a read-only bind mount in a private mount namespace; skipped where one cannot be made)."""
    mount = tmp_path / "ro"
    mount.mkdir()
    answer = run_in_namespace(["grasps", f"out_dir={mount / 'g'}", *SMALL], read_only=(mount,), timeout=120)
    assert_clean_error(answer, mount / "g", "read-only file system", prefix="hupbench grasps: error:")
    assert answer.rc == 1
    # refused before the work: the refinement's progress lines never came
    assert "candidates refined" not in answer.out, answer.out


@pytest.mark.matrix
def test_matrix_grasps_second_run(tmp_path, capsys):
    """A second grasps run on a folder another live run writes is refused (the lock beside the folder)."""
    from hupbench.core.io import OutputLock

    out = tmp_path / "g"
    with OutputLock.for_file(out, "grasps"):  # the first run
        answer = run_cli(capsys, "grasps", f"out_dir={out}", *SMALL)
    assert_clean_error(answer, str(out), "in use by another grasps run", prefix="hupbench grasps: error:")
    assert not out.exists()
