"""The bad-input matrix of ``python train.py`` (docs/robustness.md, section train.py).

Every case gives one line ``train.py: error: ...`` naming the file or the field and what was expected,
exit code 1, no traceback, and nothing that looks complete (no summary.json, no temporary file).
Most cases run in this process through :func:`hupbench.training.loop.main` (train.py's body, the same answer
its command line prints); a few run ``python train.py`` itself, for Hydra's own errors (malformed
overrides) and for a read-only run folder (a read-only tmpfs in a private mount namespace). A bad value of one
config field is a unit test of its node (tests/hupbench/training/test_train_config.py); here one case per node
checks that the command line reaches it.

The helpers that damage datasets and checkpoints are shared with test_matrix_eval and test_matrix_export.
"""

from __future__ import annotations

import json
import os
import shutil
import struct
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
import torch

from conftest import CliAnswer, assert_clean_error, assert_nothing_complete
from helpers.training import REPO, TRAIN_PREFIX, tiny_cfg, train_answer, train_py


# ----------------------------------------------------------------------------------------------
# damage, shared with the eval and export matrices


def copy_dataset(src: Path, dst: Path) -> Path:
    """A writable copy of a dataset (without its frame cache)."""
    shutil.copytree(src, dst, ignore=shutil.ignore_patterns("cache"))
    return dst


def rewrite_annotations(root: Path, split: str, edit) -> Path:
    """Replace ``split``'s annotations.npz by ``edit(arrays)`` (a dict of arrays)."""
    path = root / split / "annotations.npz"
    with np.load(path) as data:
        arrays = {k: data[k] for k in data.files}
    np.savez(path, **edit(arrays))
    return path


def flip_member_byte(path: Path, member: str = "keypoints_3d_cam.npy") -> None:
    """Invert one byte inside the data of one array of an .npz (a bit rot that only the zip CRC sees)."""
    with zipfile.ZipFile(path) as z:
        info = z.getinfo(member)
    data = bytearray(path.read_bytes())
    name_len, extra_len = struct.unpack("<HH", data[info.header_offset + 26: info.header_offset + 30])
    start = info.header_offset + 30 + name_len + extra_len
    data[start + info.compress_size - 16] ^= 0xFF  # in the last values, past the .npy header
    path.write_bytes(bytes(data))


def first_frame(root: Path, split: str) -> Path:
    return sorted((root / split / "rgb").iterdir())[0]


def write_image(path: Path, width: int, height: int) -> None:
    import cv2

    assert cv2.imwrite(str(path), np.random.default_rng(0).integers(0, 255, (height, width, 3), dtype=np.uint8))


def damage_dataset(case: str, src: Path, tmp_path: Path, split: str) -> tuple[Path, tuple[str, ...]]:
    """(dataset folder, what the error must name) for a dataset case id; ``split`` is the one damaged."""
    if case == "dataset-missing":
        return tmp_path / "no_such_dataset", ("no_such_dataset", "does not exist")
    if case == "dataset-empty-folder":
        (tmp_path / "empty").mkdir()
        return tmp_path / "empty", ("manifest.json", "not a finished hupbench dataset")
    if case == "dataset-is-a-file":
        (tmp_path / "file.txt").write_text("not a dataset")
        return tmp_path / "file.txt", ("file.txt", "is a file")
    root = copy_dataset(src, tmp_path / "dataset")
    ann = root / split / "annotations.npz"
    rng = np.random.default_rng(1)
    if case == "manifest-bad-json":
        text = (root / "manifest.json").read_text()
        (root / "manifest.json").write_text(text[: len(text) // 2])
        return root, ("manifest.json", "not valid JSON")
    if case == "manifest-21-keypoints":
        manifest = json.loads((root / "manifest.json").read_text())
        manifest["keypoint_names"] = manifest["keypoint_names"][:21]
        (root / "manifest.json").write_text(json.dumps(manifest))
        return root, ("manifest.json", "21 keypoints", "29")
    if case == "annotations-missing":
        ann.unlink()
        return root, ("annotations.npz", "missing")
    if case == "annotations-empty":
        ann.write_bytes(b"")
        return root, ("annotations.npz", "damaged")
    if case == "annotations-truncated":
        data = ann.read_bytes()
        ann.write_bytes(data[: len(data) // 2])
        return root, ("annotations.npz", "damaged")
    if case == "annotations-random-bytes":
        ann.write_bytes(rng.integers(0, 256, ann.stat().st_size, dtype=np.uint8).tobytes())
        return root, ("annotations.npz", "damaged")
    if case == "annotations-flipped-byte":
        flip_member_byte(ann)
        return root, ("annotations.npz", "crc")
    if case == "annotations-row-short":
        rewrite_annotations(root, split, lambda a: {k: v[:-1] for k, v in a.items()})
        return root, ("annotations.npz", "rows as the manifest counts")
    if case == "annotations-21-keypoints":
        rewrite_annotations(root, split, lambda a: a | {"keypoints_3d_cam": a["keypoints_3d_cam"][:, :21],
                                                        "keypoints_2d": a["keypoints_2d"][:, :21],
                                                        "visible": a["visible"][:, :21]})
        return root, ("annotations.npz", "keypoints_3d_cam", "29, 3")
    if case == "annotations-nan":
        rewrite_annotations(root, split, lambda a: a | {"keypoints_3d_cam": np.where(
            np.arange(len(a["frame_id"]))[:, None, None] == 3, np.nan, a["keypoints_3d_cam"]).astype(np.float32)})
        return root, ("annotations.npz", "nan")
    frame = first_frame(root, split)
    if case == "rgb-missing":
        frame.unlink()
        return root, (frame.name, "does not exist")
    if case == "rgb-undecodable":
        frame.write_bytes(rng.integers(0, 256, 2000, dtype=np.uint8).tobytes())
        return root, (frame.name, "cannot decode")
    if case == "rgb-tiny":
        write_image(frame, 8, 8)
        return root, (frame.name, "8 x 8", "64 x 64")
    if case == "rgb-huge":
        write_image(frame, 1024, 1024)
        return root, (frame.name, "1024 x 1024", "64 x 64")
    if case == "rgb-not-square":
        write_image(frame, 64, 48)
        return root, (frame.name, "64 x 48", "64 x 64")
    raise KeyError(case)


DATASET_CASES = ["dataset-missing", "dataset-empty-folder", "dataset-is-a-file", "manifest-bad-json",
                 "manifest-21-keypoints", "annotations-missing", "annotations-empty", "annotations-truncated",
                 "annotations-random-bytes", "annotations-flipped-byte", "annotations-row-short",
                 "annotations-21-keypoints", "annotations-nan", "rgb-missing", "rgb-undecodable", "rgb-tiny",
                 "rgb-huge", "rgb-not-square"]


def damage_checkpoint(case: str, src: Path, tmp_path: Path) -> tuple[Path, tuple[str, ...]]:
    """(checkpoint path, what the error must name) for a checkpoint case id, from a good checkpoint ``src``."""
    path = tmp_path / f"{case}.pt"
    if case == "ckpt-missing":
        return path, (path.name, "does not exist")
    if case == "ckpt-empty":
        path.write_bytes(b"")
        return path, (path.name, "not a readable torch checkpoint")
    if case == "ckpt-truncated":
        data = src.read_bytes()
        path.write_bytes(data[: len(data) // 2])
        return path, (path.name, "not a readable torch checkpoint")
    if case == "ckpt-random-bytes":
        path.write_bytes(np.random.default_rng(2).integers(0, 256, 100_000, dtype=np.uint8).tobytes())
        return path, (path.name, "not a readable torch checkpoint")
    if case == "ckpt-not-hupbench":
        torch.save({"state_dict": {"w": torch.zeros(3)}}, path)
        return path, (path.name, "not a hupbench checkpoint")
    payload = torch.load(src, map_location="cpu", weights_only=True)
    if case == "ckpt-wrong-shapes":
        key = next(k for k, v in payload["model"].items() if v.ndim == 4)
        payload["model"][key] = torch.zeros(3, 3, 3, 3)
        torch.save(payload, path)
        return path, (path.name, key, "shape")
    if case == "ckpt-other-model-weights":
        # the weights of one model under the config of another (a hand-edited or mixed-up file)
        payload["model_config"] = {"name": "resnet_regressor", "backbone": "resnet10", "n_keypoints": 29}
        torch.save(payload, path)
        return path, (path.name, "resnet_regressor")
    if case == "ckpt-unknown-model":
        payload["model_config"] = payload["model_config"] | {"name": "hopenet9"}
        torch.save(payload, path)
        return path, (path.name, "'hopenet9'")
    if case == "ckpt-lacks-fields":
        del payload["K_input"]
        torch.save(payload, path)
        return path, (path.name, "lacks K_input")
    raise KeyError(case)


CHECKPOINT_CASES = ["ckpt-missing", "ckpt-empty", "ckpt-truncated", "ckpt-random-bytes", "ckpt-not-hupbench",
                    "ckpt-wrong-shapes", "ckpt-other-model-weights", "ckpt-unknown-model", "ckpt-lacks-fields"]


def private_mount(options: str, folder: Path, script: str, env: dict | None = None,
                  timeout: float = 600) -> tuple[int, str]:
    """Run the shell ``script`` with a fresh tmpfs (``mount -o OPTIONS``) on ``folder``, in a private mount
    namespace (the mount vanishes with the script). ``$D`` is the mount point. Skips the test where a mount
    namespace cannot be made (no unshare, not root).

    Returns:
        (exit code of the script, its stdout + stderr).
    """
    if shutil.which("unshare") is None:
        pytest.skip("unshare(1) is not installed: no private tmpfs for this fault")
    folder.mkdir(parents=True, exist_ok=True)
    wrapped = f'mount -t tmpfs -o {options} tmpfs "$D" || exit 97\n{script}'
    done = subprocess.run(["unshare", "-m", "--propagation", "private", "sh", "-c", wrapped],
                          capture_output=True, text=True, timeout=timeout, cwd=REPO,
                          env={**os.environ, "PYTHONPATH": str(REPO), "D": str(folder), **(env or {})})
    if done.returncode == 97 or "unshare failed" in done.stderr:
        pytest.skip(f"cannot mount a tmpfs in a private namespace here (not root?): {done.stderr.strip()[-300:]}")
    return done.returncode, done.stdout + done.stderr


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
    "epochs-zero": (["train.max_steps=null", "train.epochs=0"], ("train.epochs", "whole number >= 1")),
    "lr-nan": (["optim.optimizer.lr=nan"], ("optim.optimizer.lr", "(0, 1]")),
    "input-size-tiny": (["data.reader.input_size=8"], ("data.reader.input_size", "16")),
    "loss-weight-negative": (["loss.w3d=-1"], ("loss.w3d", ">= 0")),
    "device-tpu": (["device=tpu"], ("device", "'cpu' or 'cuda'")),
    "backbone-unknown": (["model.backbone=resnet99"], ("resnet99",)),
}

CASES = ([f"dataset:{c}" for c in DATASET_CASES]
         + [f"resume:{c}" for c in CHECKPOINT_CASES]
         + ["resume:other-run-config", "resume:auto-last-truncated"]
         + [f"override:{c}" for c in OVERRIDE_CASES]
         + ["output:run-dir-is-a-file"])


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
        (tmp_path / "taken").write_text("a file where the run folder should go")
        run_dir, needles = tmp_path / "taken", ("taken",)
        answer = train_answer(capsys, tiny_cfg(tiny_dataset, run_dir, cache))
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
