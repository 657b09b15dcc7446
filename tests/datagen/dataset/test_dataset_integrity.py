"""A finished dataset checked against its files when generate runs on it again, and a camera that must see
the scene (verify's checks of the same holes are cases of tests/hupbench/verbs/test_matrix_verify.py)."""

import shutil

import numpy as np
import pytest

from hupbench.datagen.dataset.spec import DatasetSpec
from hupbench.datagen.dataset.writer import GenerateRun, generate
from hupbench.core.io import save_npz

from helpers.datasets import TINY_SPEC  # noqa: E402  (tests/ is on sys.path)

QUIET = lambda *_: None  # noqa: E731


def _files(root):
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.fixture
def dataset(tiny_dataset, tmp_path):
    """A copy of the session's tiny dataset (3 grasps, 20 frames per split, 64 px, one glove)."""
    root = tmp_path / "dataset"
    shutil.copytree(tiny_dataset, root)
    return root


def _again(root, **spec):
    """generate once more on ``root`` with the config it was made with (conftest's tiny_dataset)."""
    spec = DatasetSpec(**(TINY_SPEC | {"splits": {"train": 1, "val": 1, "test": 1}} | spec))
    return generate(GenerateRun(spec, root, root / "grasps.npz", progress=False), {"test": "tiny_dataset"}, log=QUIET)


def test_generate_renders_the_missing_image_files_of_a_finished_dataset_again(dataset):
    before = _files(dataset)
    (dataset / "train" / "rgb" / "000003.jpg").unlink()
    (dataset / "test" / "seg" / "000045.png").write_bytes(b"")
    result = _again(dataset)
    assert result["complete"] and result["frames_rendered"] == 20  # the two chunks of 10 frames
    assert _files(dataset) == before  # byte for byte, and no scaffolding left
    assert _again(dataset)["frames_rendered"] == 0


def test_generate_refuses_to_repair_a_finished_dataset_from_other_grasps(dataset, tmp_path):
    with np.load(dataset / "grasps.npz") as data:
        arrays = {k: data[k] for k in data.files}
    other = save_npz(tmp_path / "other.npz", {**arrays, "hand_trans": arrays["hand_trans"] + 0.01})
    shutil.copyfile(other, dataset / "grasps.npz")
    (dataset / "val" / "depth" / "000021.png").unlink()
    with pytest.raises(ValueError, match="grasps.npz is missing, differs from .* or is not the one its frames were rendered with"):
        _again(dataset)
    assert not (dataset / "val" / "depth" / "000021.png").exists()


def test_a_camera_that_cannot_see_the_scene_is_refused():
    """The camera aims at the look-at point, which lands at the principal point: outside the image every
    frame shows nothing (``dataset.cx=-5000`` rendered no foreground pixel)."""
    for field, value in (("cx", -5000.0), ("cy", 64.0)):
        with pytest.raises(ValueError, match=f"dataset.{field} must put the principal point inside the image"):
            DatasetSpec(**(TINY_SPEC | {field: value}))
    DatasetSpec(**(TINY_SPEC | {"cx": -0.5, "cy": 63.5}))  # the image's edge pixels
