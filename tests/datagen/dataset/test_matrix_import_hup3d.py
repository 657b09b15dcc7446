"""The bad-input matrix of ``hupbench import-hup3d DIR OUT --probe-mesh PLY`` (docs/robustness.md).

Every case damages a copy of a published-layout folder (tests/helpers/hup3d.py: train/ with 2 frames, test/
with 3) and expects one ``hupbench import-hup3d: error: ...`` line naming the file, and OUT as it was: absent
or empty, nothing in it or beside it that looks like a dataset, so that the same command succeeds once the
input is mended.
"""

from __future__ import annotations

import pickle
import shutil
from pathlib import Path
from typing import Callable

import cv2
import numpy as np
import pytest
import trimesh
from helpers.cli import assert_clean_error, assert_nothing_complete, run_cli
from helpers.hup3d import write_published


@pytest.fixture(scope="module")
def published(tmp_path_factory):
    root = tmp_path_factory.mktemp("hup3d")
    write_published(root)
    return root


def _image(relative: str, make: Callable[[np.ndarray], np.ndarray]):
    def damage(src: Path) -> None:
        path = src / "HUP-3D" / relative
        assert cv2.imwrite(str(path), make(cv2.imread(str(path), cv2.IMREAD_UNCHANGED)))
    return damage


def _bytes(relative: str, data: bytes):
    def damage(src: Path) -> None:
        (src / "HUP-3D" / relative).write_bytes(data)
    return damage


def _probe_in_mm(src: Path) -> None:
    mesh = trimesh.load(src / "probe.ply", force="mesh", process=False)
    mesh.apply_scale(1000.0)
    mesh.export(src / "probe.ply")


#: case -> (damage of the source copy, what the error line names); the last frame (test 3) fails after
#: four frames were converted
CASES = {
    "last-frame-depth-16-bit": (_image("test/depth/img_depth_3.png", lambda im: im.astype(np.uint16) * 256),
                                ("img_depth_3.png", "8-bit single-channel")),
    "last-frame-rgb-truncated": (_bytes("test/rgb/img_rgb_3.jpg", b"\xff\xd8\xff"), ("img_rgb_3.jpg", "not a decodable")),
    "last-frame-segm-unknown-label": (_image("test/segm/img_segm_3.png", lambda im: np.where(im == 16, 42, im)),
                                      ("img_segm_3.png", "42")),
    "probe-mesh-in-millimetres": (_probe_in_mm, ("probe.ply", "in metres", "160 m long")),
}


def _source(published: Path, tmp_path: Path, case: str) -> Path:
    src = tmp_path / "src"
    shutil.copytree(published, src)
    CASES[case][0](src)
    return src


@pytest.mark.matrix
@pytest.mark.parametrize("out_exists", [False, True], ids=["new-out", "empty-out"])
@pytest.mark.parametrize("case", list(CASES))
def test_matrix_import_hup3d(published, tmp_path, capsys, case, out_exists):
    src = _source(published, tmp_path, case)
    out = tmp_path / "ds"
    if out_exists:
        out.mkdir()
    argv = ("import-hup3d", src / "HUP-3D", "--probe-mesh", src / "probe.ply", out)
    assert_clean_error(run_cli(capsys, *argv), *CASES[case][1])
    assert (sorted(out.iterdir()) == []) if out_exists else not out.exists()
    assert_nothing_complete(tmp_path, "manifest.json", "annotations.npz", "grasps.npz")
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []
    # mended, the same command succeeds: a failed run leaves nothing that blocks it
    shutil.rmtree(src)
    shutil.copytree(published, src)
    answer = run_cli(capsys, *argv)
    assert answer.rc == 0 and (out / "manifest.json").is_file(), answer


def _meta(number: int, edit):
    def damage(src: Path) -> None:
        path = src / "HUP-3D" / "test" / "meta" / f"img_meta_{number}.pkl"
        meta = pickle.loads(path.read_bytes())
        path.write_bytes(pickle.dumps(edit(meta)))
    return damage


def _short_pose(meta: dict) -> dict:
    return meta | {"pose": [0.1, 0.2]}


#: merged checks: one line for what two checks said before (meta pickles of the last frame)
MERGED = {
    "meta-not-a-dict": (_meta(3, lambda meta: [meta]), ("img_meta_3.pkl", "not a readable meta pickle of a dict",
                                                       "a pickled list")),
    "meta-not-a-pickle": (_bytes("test/meta/img_meta_3.pkl", b"not a pickle"),
                          ("img_meta_3.pkl", "not a readable meta pickle of a dict", "UnpicklingError")),
    "meta-pose-too-short": (_meta(3, _short_pose), ("img_meta_3.pkl", "pose must be finite numbers (at least 3", "(2,)")),
}


@pytest.mark.matrix
@pytest.mark.parametrize("case", list(MERGED))
def test_matrix_import_hup3d_meta(published, tmp_path, capsys, case):
    src = tmp_path / "src"
    shutil.copytree(published, src)
    MERGED[case][0](src)
    out = tmp_path / "ds"
    assert_clean_error(run_cli(capsys, "import-hup3d", src / "HUP-3D", "--probe-mesh", src / "probe.ply", out),
                       *MERGED[case][1])
    assert not out.exists()


@pytest.mark.matrix
def test_matrix_import_hup3d_folder_without_meta(published, tmp_path, capsys):
    """A folder that holds neither meta/ nor split folders with one: the line of an empty meta/ folder."""
    out = tmp_path / "ds"
    assert_clean_error(run_cli(capsys, "import-hup3d", published / "HUP-3D" / "test" / "rgb", "--probe-mesh",
                               published / "probe.ply", out),
                       "no img_meta_N.pkl files", "rgb/meta", "not the published HUP-3D layout")
    assert not out.exists()
