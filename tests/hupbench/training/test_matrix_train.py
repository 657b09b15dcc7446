"""The bad-input matrix of ``python train.py`` (docs/robustness.md, section train.py).

Every case gives one line ``train.py: error: ...`` naming the file or the field and what was expected,
exit code 1, no traceback, and nothing that looks complete (no summary.json, no temporary file).
Most cases run in this process through :func:`hupbench.verbs.train.task` (train.py's Hydra job) under
:func:`hupbench.error_lines.answered` (the one catch of train.py and hupbench train: the same answer their command
lines print); a few run ``python train.py`` or ``hupbench train`` itself, for Hydra's own errors (malformed
overrides), a read-only run folder (a read-only tmpfs in a private mount namespace) and standard output that is
full or closed. A bad value of one config field is a unit test of its node
(tests/hupbench/training/test_train_config.py); here one case per node checks that the command line reaches it.

The helpers that damage datasets and checkpoints are shared with test_matrix_eval and test_matrix_export.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from helpers.cli import CliAnswer, assert_clean_error, assert_nothing_complete, run_with_stdout
from helpers.training import REPO, TRAIN_PREFIX, tiny_cfg, tiny_overrides, train_answer, train_py
from helpers.damage import CHECKPOINT_CASES, DATASET_CASES, damage_checkpoint, damage_dataset
from helpers.faults import private_mount


# ----------------------------------------------------------------------------------------------
# training cases


@pytest.fixture(scope="module")
def trained(tiny_dataset, tmp_path_factory):
    """(last.pt of a finished 2-step run, the frame cache folder it used): the resume cases' config."""
    from hupbench.training.loop import run_train

    folder = tmp_path_factory.mktemp("trained")
    cache = folder / "cache"
    result = run_train(tiny_cfg(tiny_dataset, folder / "run", cache), log=lambda *_: None)
    return Path(result["checkpoint"]), cache


# (overrides, what the error must name): one case per config node, that a bad value on the command line reaches
# its node's check (each field's own cases: tests/hupbench/training/test_train_config.py), and the batch that
# only the dataset can refuse
OVERRIDE_CASES = {
    "batch-size-zero": (["data.batch_size=0"], ("data.batch_size", "whole number >= 1")),
    "batch-size-over-split": (["data.batch_size=64"], ("data.batch_size", "fewer than one batch of 64")),
    "epochs-zero": (["train.max_steps=null", "train.epochs=0"], ("train.epochs", "whole number from 1 to")),
    "lr-nan": (["optim.optimizer.lr=nan"], ("optim.optimizer.lr", "(0, 1]")),
    "input-size-tiny": (["data.reader.input_size=8"], ("data.reader.input_size", "16")),
    "loss-weight-negative": (["loss.w3d=-1"], ("loss.w3d", ">= 0")),
    "device-tpu": (["device=tpu"], ("device", "'cpu' or 'cuda'")),
    "backbone-unknown": (["model.backbone=resnet99"], ("resnet99",)),
    "channels-last-maybe": (["channels_last=maybe"], ("channels_last must be true or false", "'maybe'")),
    "progress-maybe": (["train.progress=maybe"], ("train.progress must be true or false", "'maybe'")),
}

# what stands in the way of the run's outputs on disk, made in the test's folder: each was a traceback
OUTPUT_CASES = {
    "run-dir-is-a-file": ("taken", "run_dir {run} is not a folder (a file of that name exists)"),
    "run-dir-too-long": ("r" * 300, "cannot write run_dir {run}: the path, or a name in it, is longer than the file "
                                    "system allows"),
    "tb-is-a-file": ("run/tb", "cannot write {run}/tb: it is a file; expected a folder"),
    "metrics-is-a-folder": ("run/metrics.jsonl/", "cannot write {run}/metrics.jsonl: it is a folder; expected a file"),
    "checkpoints-is-a-file": ("run/checkpoints", "cannot write {run}/checkpoints: it is a file; expected a folder"),
    "cache-dir-is-a-file": ("cache", "cannot write the frame cache {cache}: it is a file; expected a folder; set "
                                     "data.cache_dir to a writable folder"),
}


def output_fault(case: str, tmp_path: Path) -> tuple[Path, Path, str]:
    """(run folder, frame cache folder, the error line's text) of an OUTPUT_CASES case, its obstacle made."""
    made, line = OUTPUT_CASES[case]
    run_dir = tmp_path / ("taken" if case == "run-dir-is-a-file" else "r" * 300 if case == "run-dir-too-long" else "run")
    obstacle = tmp_path / made
    if made.endswith("/"):
        obstacle.mkdir(parents=True)
    elif case != "run-dir-too-long":
        obstacle.parent.mkdir(parents=True, exist_ok=True)
        obstacle.write_text("a file where the run writes")
    return run_dir, tmp_path / "cache", line.format(run=run_dir, cache=tmp_path / "cache")

CASES = ([f"dataset:{c}" for c in DATASET_CASES]
         + [f"resume:{c}" for c in CHECKPOINT_CASES]
         + ["resume:other-run-config", "resume:auto-last-truncated"]
         + [f"override:{c}" for c in OVERRIDE_CASES]
         + [f"output:{c}" for c in OUTPUT_CASES])


@pytest.mark.matrix
@pytest.mark.parametrize("case", CASES, ids=[c.split(":", 1)[1] for c in CASES])
def test_matrix_train(case, tiny_dataset, tmp_path, capsys, request):
    kind, name = case.split(":", 1)
    run_dir, cache = tmp_path / "run", tmp_path / "cache"
    if kind == "dataset":
        # the train split is damaged (the frame cache reads every image before the first step)
        root, needles = damage_dataset(name, tiny_dataset, tmp_path, "train")
        answer = train_answer(capsys, tiny_cfg(root, run_dir, cache))
    elif kind == "resume":
        good, cache = request.getfixturevalue("trained")
        if name == "other-run-config":
            path, needles = good, ("trained with another config", "data.batch_size")
            answer = train_answer(capsys, tiny_cfg(tiny_dataset, run_dir, cache, f"train.resume={path}",
                                                   "data.batch_size=2"))
        elif name == "auto-last-truncated":
            shutil.copytree(good.parent.parent, run_dir)
            last = run_dir / "checkpoints" / "last.pt"
            last.write_bytes(last.read_bytes()[:1000])
            (run_dir / "summary.json").unlink()
            needles = ("last.pt", "not a readable torch checkpoint")
            answer = train_answer(capsys, tiny_cfg(tiny_dataset, run_dir, cache, "train.max_steps=4"))
        else:
            path, needles = damage_checkpoint(name, good, tmp_path)
            answer = train_answer(capsys, tiny_cfg(tiny_dataset, run_dir, cache, f"train.resume={path}"))
    elif kind == "override":
        overrides, needles = OVERRIDE_CASES[name]
        answer = train_answer(capsys, tiny_cfg(tiny_dataset, run_dir, cache, *overrides))
    else:
        run_dir, cache, line = output_fault(name, tmp_path)
        needles = (line,)
        answer = train_answer(capsys, tiny_cfg(tiny_dataset, run_dir, cache, "train.tensorboard=true"))
    assert_clean_error(answer, *needles, prefix=TRAIN_PREFIX)
    assert answer.rc == 1
    assert_nothing_complete(tmp_path, "summary.json")


# ----------------------------------------------------------------------------------------------
# python train.py itself: Hydra's errors and OSError


CLI_CASES = {
    "override-without-equals": (["model"], ("'model'", "key=value")),
    "override-unknown-key": (["nosuch.key=1"], ("nosuch.key", "not in the config")),
    "override-unknown-group-option": (["model=hopenet_r99"], ("model/hopenet_r99", "hopenet")),
    "override-bad-value": (["data.batch_size=abc"], ("data.batch_size", "whole number")),
    # conf/train.yaml's model_id is ??? (each model config sets it): a model config without one
    "required-value-missing": (["model_id=???"], ("model_id is required", "???")),
    "dataset-missing": (["data.root=NOWHERE"], ("nowhere", "does not exist")),
    # the reference reader in a loader process reads an image only when a batch needs it; a separate
    # process also because a loader worker forked from a process that rendered (the tiny_dataset
    # fixture, in this one) hangs in cv2.setNumThreads: train.py always starts fresh
    "rgb-missing-in-worker": (["data.root=DAMAGED:rgb-missing", "data.pipeline=jpeg", "data.num_workers=1"],
                              ("000000.jpg", "does not exist")),
    "rgb-undecodable-in-worker": (["data.root=DAMAGED:rgb-undecodable", "data.pipeline=jpeg", "data.num_workers=1"],
                                  ("000000.jpg", "cannot decode")),
    "run-dir-read-only": (["data.root=DATASET"], ("run", "read-only")),
    # a dataset on a read-only mount: its default frame cache folder (DATASET/cache) cannot be made
    "dataset-read-only": (["data.root=RO/dataset", "data.cache_dir=null"], ("ro/dataset/cache", "data.cache_dir")),
}


@pytest.mark.matrix
@pytest.mark.parametrize("case", list(CLI_CASES))
def test_matrix_train_cli(case, tiny_dataset, tmp_path):
    argv, needles = CLI_CASES[case]
    common = ["model=hopenet_r10_128", "data.reader.input_size=64", "data.batch_size=4", "data.num_workers=0",
              "train.max_steps=1", "train.progress=false", "train.tensorboard=false", f"data.cache_dir={tmp_path}/cache"]
    argv = [a.replace("NOWHERE", str(tmp_path / "nowhere")).replace("DATASET", str(tiny_dataset)) for a in argv]
    for i, arg in enumerate(argv):
        if arg.startswith("data.root=DAMAGED:"):
            root, _ = damage_dataset(arg.split(":", 1)[1], tiny_dataset, tmp_path, "train")
            argv[i] = f"data.root={root}"
    if case == "run-dir-read-only":
        ro = tmp_path / "ro"
        args = " ".join(f"'{a}'" for a in [*common, f"run_dir={ro}/run", *argv])
        rc, output = private_mount("ro", ro, f'"{sys.executable}" train.py {args}')
        answer = CliAnswer(rc, "", output)
    elif case == "dataset-read-only":
        ro = tmp_path / "ro"
        args = " ".join(f"'{a.replace('RO', str(ro))}'" for a in [*common, f"run_dir={tmp_path}/run", *argv])
        rc, output = private_mount("size=8m", ro, f'cp -r "{tiny_dataset}" "$D/dataset" && rm -rf "$D/dataset/cache" '
                                                   f'&& mount -o remount,ro "$D" && "{sys.executable}" train.py {args}')
        answer = CliAnswer(rc, "", output)
    else:  # the case's overrides last: Hydra takes the last value of a key given twice
        answer = train_py(*common, f"run_dir={tmp_path}/run", *argv, cwd=tmp_path)
    assert_clean_error(answer, *needles, prefix=TRAIN_PREFIX)
    assert answer.rc == 1
    assert_nothing_complete(tmp_path, "summary.json")


@pytest.mark.matrix
@pytest.mark.parametrize("entry", ["train.py", "hupbench train"])
def test_matrix_train_output_fault_through_each_entry(entry, tiny_dataset, tmp_path):
    """A file where the run's tb/ folder goes, through ``python train.py`` and ``hupbench train`` alike: one line
    naming it (both end through hupbench.error_lines.answered)."""
    run_dir, cache, line = output_fault("tb-is-a-file", tmp_path)
    argv = ([sys.executable, str(REPO / "train.py")] if entry == "train.py" else
            [sys.executable, "-m", "hupbench.cli", "train"])
    done = subprocess.run([*argv, *tiny_overrides(tiny_dataset, run_dir, cache, "train.tensorboard=true")],
                          capture_output=True, text=True, cwd=tmp_path, timeout=600,
                          env={**os.environ, "PYTHONPATH": str(REPO)})
    prefix = "train.py: error:" if entry == "train.py" else "hupbench train: error:"
    assert_clean_error(CliAnswer(done.returncode, done.stdout, done.stderr), line, prefix=prefix)
    assert done.returncode == 1 and len(done.stderr.strip().splitlines()) == 1, done.stderr  # nothing of Hydra's
    assert_nothing_complete(tmp_path, "summary.json")


@pytest.mark.matrix
@pytest.mark.parametrize("stdout", ["full", "closed"])
def test_matrix_train_stdout_full_or_closed(stdout, tiny_dataset, tmp_path):
    """train.py's standard output on a full device (``> /dev/full``) is one line and exit 1; a reader that closed
    the pipe (``| head -1``) took what it wanted: the run finishes, writes its summary and exits 0. Each ended
    in a traceback (and a closed pipe in exit 1 after the work was done)."""
    answer = run_with_stdout([sys.executable, str(REPO / "train.py"),
                              *tiny_overrides(tiny_dataset, tmp_path / "run", tmp_path / "cache")],
                             stdout, cwd=tmp_path, timeout=600)
    if stdout == "closed":
        assert answer.rc == 0 and answer.err == "", answer.err
        assert (tmp_path / "run" / "summary.json").is_file()
        return
    assert_clean_error(answer, "cannot write to standard output", "No space left on device", prefix=TRAIN_PREFIX)
    assert answer.rc == 1
