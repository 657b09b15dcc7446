"""The bad-input matrix of ``hupbench export-dataset DATASET --format F OUT`` (docs/robustness.md).

Each case runs the verb on a copy of the ``tiny_dataset`` fixture and expects one
``hupbench export-dataset: error: ...`` line naming the file or folder, exit 1, the dataset unchanged
and no export where OUT was asked for.
"""

from __future__ import annotations

import hashlib
import shutil
from pathlib import Path
from typing import Callable

import cv2
import numpy as np
import pytest
from helpers.cli import assert_clean_error, run_cli


def _tree_digest(root: Path) -> str:
    """One sha256 over every file's relative path and bytes under ``root``."""
    h = hashlib.sha256()
    for path in sorted(p for p in root.rglob("*") if p.is_file()):
        h.update(path.relative_to(root).as_posix().encode())
        h.update(path.read_bytes())
    return h.hexdigest()


def _earlier_export_holding(dataset: Path) -> tuple[Path, list[str]]:
    """OUT is a folder that holds an earlier export's record and, beside it, the dataset: --force."""
    out = dataset.parent
    (out / "hupbench_export.json").write_text("{}")
    return out, ["--force"]


def _the_dataset_itself(dataset: Path) -> tuple[Path, list[str]]:
    (dataset / "hupbench_export.json").write_text("{}")
    return dataset, ["--force"]


def _inside_the_dataset(dataset: Path) -> tuple[Path, list[str]]:
    return dataset / "export", []


def _masks_background(frames: tuple[int, ...]):
    def damage(dataset: Path) -> tuple[Path, list[str]]:
        for fid in frames:
            path = dataset / "train" / "seg" / f"{fid:06d}.png"
            image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
            assert cv2.imwrite(str(path), np.zeros_like(image))
        return dataset.parent / "out", []
    return damage


#: case -> (damage: the dataset copy -> (OUT, extra options), format, what the line names)
CASES: dict[str, tuple[Callable, str, tuple[str, ...]]] = {
    "force-into-a-folder-holding-the-dataset": (_earlier_export_holding, "bop", ("holds the dataset", "outside")),
    "force-into-the-dataset-itself": (_the_dataset_itself, "coco", ("is the dataset", "outside")),
    "out-inside-the-dataset": (_inside_the_dataset, "coco", ("lies inside the dataset",)),
    "bop-every-mask-background": (_masks_background(tuple(range(20))), "bop",
                                  ("train/seg/000000.png", "background everywhere")),
    "bop-one-mask-background": (_masks_background((7,)), "bop", ("train/seg/000007.png", "background everywhere")),
    "coco-one-mask-background": (_masks_background((7,)), "coco", ("train/seg/000007.png", "background everywhere")),
}


@pytest.mark.matrix
@pytest.mark.parametrize("case", list(CASES))
def test_matrix_export_dataset(tiny_dataset, tmp_path, capsys, case):
    dataset = tmp_path / "work" / "dataset"
    shutil.copytree(tiny_dataset, dataset)
    damage, fmt, needles = CASES[case]
    out, extra = damage(dataset)
    before = _tree_digest(dataset)
    assert_clean_error(run_cli(capsys, "export-dataset", dataset, "--format", fmt, out, *extra), *needles)
    assert _tree_digest(dataset) == before, "the export changed the dataset"
    assert not (out / "models").exists() and not (out / "annotations").exists()
    assert [p.name for p in dataset.parent.iterdir() if p.name.startswith(".")] == [], "a temporary folder was left"
