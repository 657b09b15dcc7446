"""Fixtures shared across the test packages (plain helpers live in tests/helpers/)."""

import os

import pytest

from helpers import THREADS

os.environ["OMP_NUM_THREADS"] = str(THREADS)  # before anything loads torch: see helpers.THREADS

from helpers.datasets import TINY_SPEC, write_grasps  # noqa: E402  (after OMP_NUM_THREADS)


@pytest.fixture(scope="session")
def tiny_grasps(tmp_path_factory):
    return write_grasps(tmp_path_factory.mktemp("grasps") / "grasps.npz")


@pytest.fixture(scope="session")
def tiny_dataset(tmp_path_factory):
    """A finished 64 x 64 dataset with 20 frames in each of train, val and test (one grasp each). Read only."""
    from hupbench.datagen.dataset.spec import DatasetSpec
    from hupbench.datagen.dataset.writer import GenerateRun, generate

    grasps = write_grasps(tmp_path_factory.mktemp("grasps3") / "grasps.npz", n=3)
    root = tmp_path_factory.mktemp("tiny") / "dataset"
    spec = DatasetSpec(**(TINY_SPEC | {"splits": {"train": 1, "val": 1, "test": 1}}))
    generate(GenerateRun(spec, root, grasps, progress=False), {"test": "tiny_dataset"}, log=lambda *_: None)
    return root


@pytest.fixture(scope="session")
def exported(tmp_path_factory, tiny_dataset):
    """(checkpoint, onnx) of an untrained HOPE-Net on the tiny dataset, exported once per session. Read only."""
    from helpers.models import exported_model

    return exported_model(tmp_path_factory, tiny_dataset)


@pytest.fixture(scope="session")
def tiny_clinic(tmp_path_factory):
    """(dataset, grasps file) of a finished tiny clinic dataset (helpers.datasets.clinic_spec) of the first 4 shipped
    clinic grasps: 24 frames. Read only."""
    from helpers.datasets import CLINIC_SPLITS, generate_clinic
    from hupbench.datagen.dataset.grasps_file import CLINIC_GRASPS, first_grasps

    root = tmp_path_factory.mktemp("clinic")
    grasps = first_grasps(CLINIC_GRASPS, sum(CLINIC_SPLITS.values()), root / "grasps.npz")
    assert generate_clinic(root / "dataset", grasps)["complete"]
    return root / "dataset", grasps


@pytest.fixture(scope="session")
def tiny_clips(tmp_path_factory):
    """A finished 48 x 48 dataset of clips (helpers.datasets.sequence_spec) of the first 4 shipped clinic grasps:
    4 grasps x 2 clips x 11 frames = 88 frames. Read only."""
    from helpers.datasets import CLINIC_SPLITS, sequence_spec
    from hupbench.datagen.dataset.grasps_file import CLINIC_GRASPS, first_grasps
    from hupbench.datagen.dataset.writer import GenerateRun, generate

    root = tmp_path_factory.mktemp("clips")
    grasps = first_grasps(CLINIC_GRASPS, sum(CLINIC_SPLITS.values()), root / "grasps.npz")
    result = generate(GenerateRun(sequence_spec(), str(root / "dataset"), str(grasps), progress=False),
                      {"test": "tiny_clips"}, log=lambda *_: None)
    assert result["complete"]
    return root / "dataset"
