"""The bad-input matrix of ``hupbench export`` (docs/robustness.md, section export).

Every case gives one line ``hupbench export: error: ...`` (argparse's own ``error:`` line for an option it
refuses) naming the file or the option and what was expected, a non-zero exit, no traceback, and no .onnx
file and no temporary file. One case is accepted on purpose: ``--out`` into a folder that does not exist
yet creates it, as every hupbench output does. The options' own checks (``UNIT_CASES``) are unit cases of
:class:`ExportOptions`: the same line, without running the verb.
"""

from __future__ import annotations

import os
import sys

import onnx
import pytest

from helpers.cli import CliAnswer, assert_clean_error, assert_nothing_complete, run_cli
from helpers.answers import assert_refusal
from helpers.two_writers import finish, start_writing

from hupbench.inference.export import ExportOptions
from helpers.damage import CHECKPOINT_CASES, damage_checkpoint, damage_dataset
from helpers.faults import dead_pid, full_disk_script, parse_full_disk, private_mount, run_killed_then_again
from helpers.models import checkpoint_with_other_K, make_checkpoint


# argv after CKPT (OUT is the output folder), what the error must name
OPTION_CASES = {
    "opset-5": (["--opset", "5"], ("opset", "18")),
    "opset-99": (["--opset", "99"], ("opset", "99")),
    "opset-abc": (["--opset", "abc"], ("--opset", "invalid int value")),
    "out-not-onnx": (["--out", "OUT/model.bin"], ("model.bin", ".onnx")),
    "out-is-a-folder": (["--out", "OUT/folder.onnx"], ("folder.onnx", "is a folder")),
    "dataset-missing": (["--dataset", "OUT/no_dataset"], ("no_dataset", "does not exist")),
    "run-name-up-two-folders": (["--run-name", "../../x"], ("--run-name", "must be a run name", "'../../x'")),
    "run-name-with-newline": (["--run-name", "a\nb"], ("--run-name", "must be a run name", "'a\\nb'")),
    "run-name-empty": (["--run-name", ""], ("--run-name", "must be a run name", "got ''")),
}
DATASET_CASES = ["dataset-empty-folder", "dataset-is-a-file", "manifest-bad-json", "annotations-truncated",
                 "annotations-flipped-byte", "annotations-21-keypoints", "rgb-undecodable", "rgb-tiny"]

#: cases :class:`ExportOptions` refuses: case -> options(checkpoint, onnx file, out folder), checked without the verb
#: (opset-99 stays a CLI case: it wires --opset)
UNIT_CASES = {
    "ckpt-is-onnx": lambda ckpt, onnx_path, out: ExportOptions(onnx_path),
    "opset-5": lambda ckpt, onnx_path, out: ExportOptions(ckpt, out / "model.onnx", opset=5),
    "out-not-onnx": lambda ckpt, onnx_path, out: ExportOptions(ckpt, out / "model.bin"),
    "run-name-with-newline": lambda ckpt, onnx_path, out: ExportOptions(ckpt, out / "model.onnx", run_name="a\nb"),
    "run-name-empty": lambda ckpt, onnx_path, out: ExportOptions(ckpt, out / "model.onnx", run_name=""),
}

CASES = ([f"checkpoint:{c}" for c in CHECKPOINT_CASES + ["ckpt-21-keypoints", "ckpt-K-not-its-cameras",
                                                         "ckpt-is-onnx", "ckpt-without-dataset", "ckpt-dataset-gone"]]
         + [f"option:{c}" for c in OPTION_CASES]
         + [f"dataset:{c}" for c in DATASET_CASES]
         + ["output:out-read-only", "output:out-missing-folder"])


@pytest.mark.matrix
@pytest.mark.parametrize("case", CASES, ids=[c.split(":", 1)[1] for c in CASES])
def test_matrix_export(case, exported, tiny_dataset, tmp_path, capsys):
    import torch

    ckpt, onnx_path = exported
    kind, name = case.split(":", 1)
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    model, options = ckpt, ["--out", str(out_dir / "model.onnx")]
    if name in UNIT_CASES:
        needles = (onnx_path.name, "(.pt)") if name == "ckpt-is-onnx" else OPTION_CASES[name][1]
        assert_refusal(lambda: UNIT_CASES[name](ckpt, onnx_path, out_dir), *needles, prog="hupbench export")
        return
    if kind == "checkpoint":
        if name == "ckpt-21-keypoints":
            model, needles = make_checkpoint(tmp_path / "hand21.pt", tiny_dataset, n_keypoints=21), ("hand21.pt", "21 keypoints")
        elif name == "ckpt-K-not-its-cameras":  # the intrinsics buffer and the stored K_input disagree (x2)
            model = checkpoint_with_other_K(tmp_path / "other_K.pt", tiny_dataset)
            needles = ("other_K.pt", "intrinsics buffer", "is not the camera of its K_input")
        elif name in ("ckpt-without-dataset", "ckpt-dataset-gone"):
            payload = torch.load(ckpt, map_location="cpu", weights_only=True)
            gone = tmp_path / "gone_dataset"
            payload["dataset"] = None if name == "ckpt-without-dataset" else {"path": str(gone)}
            model = tmp_path / f"{name}.pt"
            torch.save(payload, model)
            needles = ((model.name, "records no dataset", "--dataset") if name == "ckpt-without-dataset"
                       else ("gone_dataset", "does not exist", "--dataset"))
        else:
            model, needles = damage_checkpoint(name, ckpt, tmp_path)
    elif kind == "option":
        extra, needles = OPTION_CASES[name]
        extra = [o.replace("OUT", str(out_dir)) for o in extra]
        options = extra if "--out" in extra else [*options, *extra]
        if name == "out-is-a-folder":
            (out_dir / "folder.onnx").mkdir()
    elif kind == "dataset":
        dataset, needles = damage_dataset(name, tiny_dataset, tmp_path, "test")
        options = [*options, "--dataset", str(dataset)]
    if name == "out-read-only":
        ro = tmp_path / "ro"
        rc, output = private_mount("ro", ro, f'"{sys.executable}" -m hupbench.cli export "{ckpt}" --out "{ro}/m.onnx"')
        answer, needles = CliAnswer(rc, "", output), ("m.onnx", "read-only")
    elif name == "out-missing-folder":
        # accepted: the folder is made, as for every hupbench output
        out = out_dir / "new" / "deeper" / "model.onnx"
        answer = run_cli(capsys, "export", ckpt, "--out", out)
        assert answer.rc == 0, answer
        umask = os.umask(0o022)
        os.umask(umask)
        # readable as every other output (0644 under the usual umask), not tempfile.mkstemp's 0600
        assert onnx.load(str(out)).metadata_props and (out.stat().st_mode & 0o777) == 0o666 & ~umask
        assert not list(out_dir.rglob(".*.tmp*"))
        return
    else:
        answer = run_cli(capsys, "export", model, *options)
    assert_clean_error(answer, *needles)
    assert_nothing_complete(tmp_path, *(["*.onnx"] if name != "out-is-a-folder" else []))
    assert not [p for p in out_dir.rglob("*.onnx") if p.is_file()]



# ----------------------------------------------------------------------------------------------
# faults: a full disk, SIGKILL then the same command


@pytest.mark.matrix
def test_fault_export_disk_full(exported, tmp_path):
    """The ONNX file on a full disk: one line naming the device and the first file it could not write (the
    output's lock), exit 1, nothing left."""

    ckpt, _ = exported
    disk = tmp_path / "disk"
    _, output = private_mount("size=8k", disk, full_disk_script(
        f'"{sys.executable}" -m hupbench.cli export "{ckpt}" --out "{disk}/model.onnx"', disk))
    answer, tmp, files = parse_full_disk(output)
    assert_clean_error(answer, f"no space left on {disk} writing {disk}/model.onnx")
    assert answer.rc == 1 and not tmp and files == [f"{disk}/filler"], (tmp, files)


@pytest.mark.matrix
@pytest.mark.slow  # 31 s here; generate's, train's and the leaderboard's SIGKILL cases keep atomic writes after a
# kill in the default set, and CI under 20 minutes
def test_fault_export_sigkill_then_rerun(exported, tmp_path):
    """SIGKILL at a seeded random point of an export (its temporary file being written or checked for parity),
    then the same command: the same bytes as an uninterrupted export (its metadata has no time stamp), and
    no temporary file left."""

    ckpt, onnx_path = exported
    out = tmp_path / "out" / "model.onnx"
    out.parent.mkdir()
    argv = [sys.executable, "-m", "hupbench.cli", "export", str(ckpt), "--out", str(out)]
    # killed once the temporary file exists (being written, or its parity being checked)
    left = run_killed_then_again(argv, tmp_path, seed=15, folder=out.parent, pattern=".model.onnx.tmp*",
                                 window_s=0.15)
    assert left and all(name.startswith((".model.onnx.tmp", ".model.onnx.lock")) for name in left), left
    assert out.read_bytes() == onnx_path.read_bytes()
    assert sorted(p.name for p in out.parent.iterdir()) == ["model.onnx"]


@pytest.mark.matrix
def test_fault_export_stale_tmp_removed(exported, tmp_path, capsys):
    """Temporary files of killed exports in the output folder are removed by the next export; a live
    writer's are kept."""

    ckpt, onnx_path = exported
    out = tmp_path / "out" / "model.onnx"
    stale = out.with_name(f".model.onnx.tmp{dead_pid()}")
    live = out.with_name(f".other.onnx.tmp{os.getpid()}")
    for path in (stale, live):
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(b"\0" * 1000)
    assert run_cli(capsys, "export", ckpt, "--out", out).rc == 0
    assert sorted(p.name for p in out.parent.iterdir()) == sorted([live.name, "model.onnx"])
    assert out.read_bytes() == onnx_path.read_bytes()


@pytest.mark.matrix
@pytest.mark.slow  # 18 s here; predict's and train's two-runs cases keep the output lock in the default set, and CI
# under 20 minutes
def test_fault_export_two_runs_at_once(exported, tmp_path, capsys):
    """A second export to the .onnx file a running one writes (measured before: both exited 0, each renaming
    its own file over the other's): refused with one line naming the running one; the first completes."""
    ckpt, onnx_path = exported
    out = tmp_path / "out" / "model.onnx"
    first = start_writing(["export", ckpt, "--out", out, "--no-progress"], out.parent)
    try:
        answer = run_cli(capsys, "export", ckpt, "--out", out)
    finally:
        finish(first)
    assert_clean_error(answer, str(out), "in use by another export run", f"pid {first.pid}")
    assert out.read_bytes() == onnx_path.read_bytes()
    assert sorted(p.name for p in out.parent.iterdir()) == ["model.onnx"]
