"""Fixtures shared across the test packages."""

import numpy as np
import pytest

from datagen.geometry import axis_angle_to_matrix, matrix_to_axis_angle
from datagen.io import save_npz
from datagen.render.preview import handset_grasp
from datagen.dataset.sphere import SphereSpec
from helpers.answers import record_answer, record_input

# a tiny dataset: r_circ = 0.4 on r_sph = 0.8 gives two rings of 5 views (poles excluded: no view of so
# coarse a sphere is near the elbow, so the default exclusion would keep all 12), 64 x 64 images; the
# sphere axis and the look-at are the paper protocol's defaults
TINY_SPEC = dict(splits={"train": 1, "val": 0, "test": 1}, z_ego_m=(0.5,), n_backgrounds=2, n_gloves=1,
                 sphere=SphereSpec(r_circ_m=0.4, exclude=("poles",)), width=64, height=64, fx=120.0, fy=120.0,
                 cx=32.0, cy=32.0)


def write_grasps(path, n=2):
    """The hand-set grasp, turned about the probe axis n ways, as a grasps.npz."""
    g = handset_grasp()
    poses, trans = [], []
    for k in range(n):
        Rz = axis_angle_to_matrix(np.array([0.0, 0.0, k * np.pi / 2]))
        pose = g.hand_pose.copy()
        pose[:3] = matrix_to_axis_angle(Rz @ axis_angle_to_matrix(g.hand_pose[:3]))
        poses.append(pose)
        trans.append(Rz @ g.hand_trans)
    return save_npz(path, {"hand_pose": np.array(poses), "hand_trans": np.array(trans),
                           "grasp_id": np.arange(n, dtype=np.int64)})


def annotations(root, splits=("train", "test")):
    """{split: {array name: array}} of a finished dataset's annotation files."""
    out = {}
    for split in splits:
        with np.load(root / split / "annotations.npz") as data:
            out[split] = {k: data[k] for k in data.files}
    return out


@pytest.fixture(scope="session")
def tiny_grasps(tmp_path_factory):
    return write_grasps(tmp_path_factory.mktemp("grasps") / "grasps.npz")


@pytest.fixture(scope="session")
def tiny_dataset(tmp_path_factory):
    """A finished 64 x 64 dataset with 20 frames in each of train, val and test (one grasp each). Read only."""
    from datagen.dataset.spec import DatasetSpec
    from datagen.dataset.writer import generate

    grasps = write_grasps(tmp_path_factory.mktemp("grasps3") / "grasps.npz", n=3)
    root = tmp_path_factory.mktemp("tiny") / "dataset"
    spec = DatasetSpec(**(TINY_SPEC | {"splits": {"train": 1, "val": 1, "test": 1}}))
    generate(spec, root, grasps, {"test": "tiny_dataset"}, progress=False, log=lambda *_: None)
    return root


# --- the bad-input matrix (docs/robustness.md) ---------------------------------------------------------


class CliAnswer:
    """What a verb answered: exit code, standard output and standard error."""

    def __init__(self, rc: int, out: str, err: str) -> None:
        self.rc, self.out, self.err = rc, out, err

    def __repr__(self) -> str:
        return f"CliAnswer(rc={self.rc}, err={self.err[-2000:]!r}, out={self.out[-1000:]!r})"


def run_cli(capsys, *argv: str) -> CliAnswer:
    """Run ``hupbench ARGV`` in this process (no traceback may escape: an exception fails the test)."""
    from hupbench.cli import main

    capsys.readouterr()
    record_input(" ".join(["hupbench", *map(str, argv)]))
    try:
        rc = main([str(a) for a in argv])
    except SystemExit as exc:  # argparse's own usage errors exit 2
        rc = exc.code if isinstance(exc.code, int) else 1
    captured = capsys.readouterr()
    return CliAnswer(rc, captured.out, captured.err)


def assert_clean_error(answer: CliAnswer, *needles: str, prefix: str | None = None) -> str:
    """A matrix answer: non-zero exit, no traceback, exactly one error line naming every needle.

    Args:
        needles: what the error line must contain (a file name, a field name, what was expected),
            compared case-insensitively.
        prefix: how the error line starts (default ``hupbench VERB: error:`` or argparse's ``error:``).

    Returns:
        The error line.
    """
    assert answer.rc not in (0, None), f"exited 0 on bad input: {answer!r}"
    text = answer.err + answer.out
    assert "Traceback" not in text, f"a traceback reached the user: {answer!r}"
    errors = [line for line in answer.err.splitlines() if "error:" in line]
    assert len(errors) == 1, f"expected one error line, got {errors}: {answer!r}"
    line = errors[0]
    if prefix is not None:
        assert line.startswith(prefix), f"{line!r} does not start with {prefix!r}"
    for needle in needles:
        assert str(needle).lower() in line.lower(), f"the error {line!r} does not name {needle!r}"
    record_answer(line)
    return line


def assert_nothing_complete(folder, *names: str) -> None:
    """None of ``names`` (files a finished run writes, e.g. manifest.json) exists under ``folder``,
    and no temporary file is left there."""
    from pathlib import Path

    folder = Path(folder)
    if not folder.exists():
        return
    for name in names:
        found = list(folder.rglob(name))
        assert not found, f"a failed run left {found}, which looks complete"
    tmp = [p for p in folder.rglob(".*.tmp*")]
    assert not tmp, f"a failed run left temporary files {tmp}"
