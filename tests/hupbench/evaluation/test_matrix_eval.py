"""The bad-input matrix of ``hupbench eval`` (docs/robustness.md, section eval).

Every case gives one line ``hupbench eval: error: ...`` (argparse's own ``error:`` line for an option it
refuses) naming the file or the option and what was expected, a non-zero exit, no traceback, and no
results JSON and no temporary file. The options' own checks (``UNIT_CASES``) are unit cases of
:class:`EvalOptions`: the same line, without running the verb.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import onnx
import pytest

from helpers.cli import CliAnswer, assert_clean_error, assert_nothing_complete, run_cli
from helpers.answers import assert_refusal
from helpers.two_writers import finish, start_writing

from hupbench.evaluation.evaluate import EvalOptions
from helpers.damage import CHECKPOINT_CASES, DATASET_CASES, damage_checkpoint, damage_dataset
from helpers.faults import dead_pid, full_disk_script, parse_full_disk, private_mount, run_killed_then_again
from helpers.models import checkpoint_with_other_K, make_checkpoint


def edited_onnx(src: Path, dst: Path, **props: str) -> Path:
    """A copy of an exported ONNX file with some hupbench metadata values replaced."""
    proto = onnx.load(str(src))
    for entry in proto.metadata_props:
        if entry.key in props:
            entry.value = props[entry.key]
    onnx.save(proto, str(dst))
    return dst


def constant_onnx(src: Path, dst: Path, n_keypoints: int, size: int) -> Path:
    """A valid ONNX model with the hupbench metadata of ``src`` whose graph predicts ``n_keypoints`` constant
    points from (batch, 3, size, size) images: another model's graph under this model's metadata."""
    from onnx import TensorProto, helper, numpy_helper

    n = n_keypoints
    inits = [numpy_helper.from_array(np.array([1, 2, 3], np.int64), "axes"),
             numpy_helper.from_array(np.array([-1, 1, 1], np.int64), "shape"),
             numpy_helper.from_array(np.zeros((1, n, 2), np.float32), "c2"),
             numpy_helper.from_array(np.full((1, n, 3), 0.5, np.float32), "c3")]
    nodes = [helper.make_node("ReduceMean", ["image", "axes"], ["m"], keepdims=1),
             helper.make_node("Reshape", ["m", "shape"], ["m3"]),
             helper.make_node("Add", ["m3", "c2"], ["points2d"]),
             helper.make_node("Add", ["m3", "c3"], ["points3d"])]
    graph = helper.make_graph(
        nodes, "constant", [helper.make_tensor_value_info("image", TensorProto.FLOAT, ["batch", 3, size, size])],
        [helper.make_tensor_value_info("points2d", TensorProto.FLOAT, ["batch", n, 2]),
         helper.make_tensor_value_info("points3d", TensorProto.FLOAT, ["batch", n, 3])], inits)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)])
    for entry in onnx.load(str(src), load_external_data=False).metadata_props:
        model.metadata_props.add(key=entry.key, value=entry.value)
    onnx.save(model, str(dst))
    return dst


def onnx_case(case: str, src: Path, tmp_path: Path) -> tuple[Path, tuple[str, ...]]:
    path = tmp_path / f"{case}.onnx"
    if case == "onnx-missing":
        return path, (path.name, "does not exist")
    if case == "onnx-empty":
        path.write_bytes(b"")
        return path, (path.name, "empty file")
    if case == "onnx-truncated":
        data = src.read_bytes()
        path.write_bytes(data[: len(data) // 2])
        return path, (path.name, "not a readable ONNX model")
    if case == "onnx-random-bytes":
        path.write_bytes(np.random.default_rng(3).integers(0, 256, 50_000, dtype=np.uint8).tobytes())
        return path, (path.name, "not a readable ONNX model")
    if case == "onnx-foreign":
        from onnx import TensorProto, helper

        graph = helper.make_graph([helper.make_node("Identity", ["x"], ["y"])], "g",
                                  [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1])],
                                  [helper.make_tensor_value_info("y", TensorProto.FLOAT, [1])])
        onnx.save(helper.make_model(graph), str(path))
        return path, (path.name, "not a hupbench ONNX export")
    if case == "onnx-input-size-disagrees":
        edited_onnx(src, path, **{"hupbench.input_size": "128"})
        return path, (path.name, "input_size 128", "64")
    if case == "onnx-metadata-bad-json":
        edited_onnx(src, path, **{"hupbench.K_input": "[[1, 2"})
        return path, (path.name, "hupbench.K_input")
    if case == "onnx-graph-21-keypoints":
        constant_onnx(src, path, 21, 64)
        return path, (path.name, "points3d", "29")
    raise KeyError(case)


def other_probe_dataset(src: Path, tmp_path: Path) -> Path:
    """A copy of a dataset whose manifest records a probe mesh of the user's (as ``hupbench generate
    probe.mesh=linear.stl`` writes it): the fits, which know only the procedural probe, must refuse it."""
    from helpers.damage import copy_dataset

    root = copy_dataset(src, tmp_path / "other_probe")
    manifest = json.loads((root / "manifest.json").read_text())
    manifest["probe"] = {"kind": "mesh", "path": "/data/probes/linear.stl", "unit": "m", "align": False,
                         "sha256": "0" * 64, "geometry_sha256": "0" * 64}
    (root / "manifest.json").write_text(json.dumps(manifest))
    return root


ONNX_CASES = ["onnx-missing", "onnx-empty", "onnx-truncated", "onnx-random-bytes", "onnx-foreign",
              "onnx-input-size-disagrees", "onnx-metadata-bad-json", "onnx-graph-21-keypoints"]

# argv after MODEL DATASET (OUT is the results path), what the error must name
OPTION_CASES = {
    "batch-size-zero": (["--batch-size", "0"], ("batch-size", "whole number >= 1")),
    "batch-size-negative": (["--batch-size", "-1"], ("batch-size", "whole number >= 1")),
    "batch-size-abc": (["--batch-size", "abc"], ("--batch-size", "whole number >= 1")),
    "threads-zero": (["--threads", "0"], ("threads", "whole number >= 1")),
    "split-dev": (["--split", "dev"], ("--split", "invalid choice: 'dev'")),
    "out-not-json": (["--out", "OUTDIR/results.txt"], ("--out", ".json")),
    "out-is-a-folder": (["--out", "OUTDIR/folder.json"], ("folder.json", "is a folder")),
    "run-name-disagrees": (["--run-name", "other"], ("other", "results file stem")),
    "run-name-empty": (["--run-name", ""], ("--run-name", "must be a run name", "got ''")),
    "out-stem-not-a-run-name": (["--out", "OUTDIR/-x.json"], ("--out", "-x.json", "must be a run name")),
    "threads-far-above-cores": (["--threads", "100000"], ("--threads", "100000", "CPU core")),
    "training-log-missing": (["--training-log", "logs/none.jsonl"], ("--training-log", "logs/none.jsonl",
                                                                     "is not a file")),
}

#: cases :class:`EvalOptions` refuses: case -> options(checkpoint, dataset, out folder), checked without the verb
#: (run-name-disagrees stays a CLI case: it wires --run-name)
UNIT_CASES = {
    "model-not-pt-or-onnx": lambda ckpt, dataset, out_dir: EvalOptions(out_dir / "notes.txt", dataset),
    "out-not-json": lambda ckpt, dataset, out_dir: EvalOptions(ckpt, dataset, out=out_dir / "results.txt"),
    "run-name-empty": lambda ckpt, dataset, out_dir: EvalOptions(ckpt, dataset, run_name=""),
    "training-log-missing": lambda ckpt, dataset, out_dir: EvalOptions(ckpt, dataset, out=out_dir / "r.json",
                                                                       training_log="logs/none.jsonl"),
}

CASES = ([f"model:{c}" for c in CHECKPOINT_CASES + ["ckpt-21-keypoints", "ckpt-K-not-its-cameras",
                                                      "model-not-pt-or-onnx"] + ONNX_CASES]
         + [f"dataset:{c}" for c in DATASET_CASES + ["other-probe-for-a-fitting-model"]]
         + [f"option:{c}" for c in OPTION_CASES]
         + ["output:out-read-only"])


@pytest.mark.matrix
@pytest.mark.parametrize("case", CASES, ids=[c.split(":", 1)[1] for c in CASES])
def test_matrix_eval(case, exported, tiny_dataset, tmp_path, capsys):
    ckpt, onnx_path = exported
    kind, name = case.split(":", 1)
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    out = out_dir / "r.json"
    model, dataset, options = ckpt, tiny_dataset, []
    if name in UNIT_CASES:
        needles = ("notes.txt", ".pt", ".onnx") if kind == "model" else OPTION_CASES[name][1]
        assert_refusal(lambda: UNIT_CASES[name](ckpt, tiny_dataset, out_dir), *needles, prog="hupbench eval")
        return
    if kind == "model":
        if name == "ckpt-21-keypoints":
            model, needles = make_checkpoint(tmp_path / "hand21.pt", tiny_dataset, n_keypoints=21), ("hand21.pt", "21 keypoints")
        elif name == "ckpt-K-not-its-cameras":  # the intrinsics buffer and the stored K_input disagree (x2)
            model = checkpoint_with_other_K(tmp_path / "other_K.pt", tiny_dataset)
            needles = ("other_K.pt", "intrinsics buffer", "is not the camera of its K_input")
        elif name.startswith("onnx"):
            model, needles = onnx_case(name, onnx_path, tmp_path)
        else:
            model, needles = damage_checkpoint(name, ckpt, tmp_path)
    elif kind == "dataset" and name == "other-probe-for-a-fitting-model":
        model, dataset = make_checkpoint(tmp_path / "fit.pt", tiny_dataset, input_channels=4, probe_fit="depth"), \
            other_probe_dataset(tiny_dataset, tmp_path)
        needles = ("manifest.json", "linear.stl", "probe fit", "knows only the default procedural probe")
    elif kind == "dataset":
        dataset, needles = damage_dataset(name, tiny_dataset, tmp_path, "test")
    elif kind == "option":
        options, needles = OPTION_CASES[name]
        options = [o.replace("OUTDIR", str(out_dir)) for o in options]
        if name == "out-is-a-folder":
            (out_dir / "folder.json").mkdir()
    if kind == "output":
        ro = tmp_path / "ro"
        rc, output = private_mount("ro", ro, f'"{sys.executable}" -m hupbench.cli eval "{ckpt}" "{tiny_dataset}" '
                                             f'--no-latency --out "{ro}/r.json"')
        answer, needles = CliAnswer(rc, "", output), ("r.json", "read-only")
    else:
        if "--out" not in options:
            options = [*options, "--out", str(out)]
        answer = run_cli(capsys, "eval", model, dataset, "--no-latency", *options)
    assert_clean_error(answer, *needles)
    assert_nothing_complete(tmp_path, "r.json", "results.txt")
    assert not [p for p in out_dir.rglob("*") if p.is_file()], "a failed eval wrote into its output folder"


# ----------------------------------------------------------------------------------------------
# faults: a full disk, SIGKILL then the same command






@pytest.mark.matrix
def test_fault_eval_disk_full(exported, tiny_dataset, tmp_path):
    """The results JSON on a full disk (measured before: a 0-byte temporary file was left): one line naming
    the device and the first file it could not write (the results' lock), exit 1, no temporary file, no lock
    and no results file."""
    ckpt, _ = exported
    disk = tmp_path / "disk"
    _, output = private_mount("size=8k", disk, full_disk_script(
        f'"{sys.executable}" -m hupbench.cli eval "{ckpt}" "{tiny_dataset}" --no-latency --out "{disk}/r.json"', disk))
    answer, tmp, files = parse_full_disk(output)
    assert_clean_error(answer, f"no space left on {disk} writing {disk}/r.json")
    assert answer.rc == 1 and not tmp and files == [f"{disk}/filler"], (tmp, files)




#: results fields that differ between two evaluations of one model on one dataset: when it ran, and timings
RERUN_FREE_FIELDS = ("created_utc", "latency_ms_per_image")


@pytest.mark.matrix
@pytest.mark.slow  # 57 s, the slowest of the default set; export's own kill-and-rerun (test_matrix_export.py) stays
def test_fault_eval_sigkill_then_rerun(exported, tiny_dataset, tmp_path, capsys):
    """SIGKILL at a seeded random point of a checkpoint eval while it times latency (its temporary ONNX file
    beside the results being written or timed), then the same command: the results equal an uninterrupted
    eval's but for created_utc and the latencies, and no temporary file is left."""
    import time

    ckpt, _ = exported
    (tmp_path / "ref").mkdir()
    argv = ["eval", str(ckpt), str(tiny_dataset), "--threads", "2"]
    start = time.perf_counter()
    assert run_cli(capsys, *argv, "--out", tmp_path / "ref" / "r.json").rc == 0
    took = time.perf_counter() - start
    out = tmp_path / "killed" / "r.json"
    out.parent.mkdir()
    # killed while the ONNX file timed for latency exists (the exporter is writing it, or the timings run)
    left = run_killed_then_again([sys.executable, "-m", "hupbench.cli", *argv, "--out", str(out)], tmp_path,
                                 seed=15, folder=out.parent, pattern=".r.json.tmp*.onnx", window_s=min(took / 4, 3.0))
    assert left and all(name.startswith((".r.json.tmp", ".r.json.lock")) for name in left), left
    reference = json.loads((tmp_path / "ref" / "r.json").read_text())
    again = json.loads(out.read_text())
    for field in RERUN_FREE_FIELDS:
        reference.pop(field), again.pop(field)
    assert again == reference
    assert sorted(p.name for p in out.parent.iterdir()) == ["r.json"]


@pytest.mark.matrix
def test_fault_eval_stale_tmp_removed(exported, tiny_dataset, tmp_path, capsys):
    """Temporary files of killed evaluations in the results folder (the results JSON, the ONNX file timed
    for latency) are removed by the next eval; a live writer's are kept."""
    import os


    ckpt, _ = exported
    out = tmp_path / "out" / "r.json"
    pid = dead_pid()
    stale = [out.with_name(f".r.json.tmp{pid}"), out.with_name(f".r.json.tmp{pid}.onnx")]
    live = out.with_name(f".other.json.tmp{os.getpid()}")
    for path in [*stale, live]:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(b"\0" * 1000)
    assert run_cli(capsys, "eval", ckpt, tiny_dataset, "--no-latency", "--out", out).rc == 0
    assert sorted(p.name for p in out.parent.iterdir()) == sorted([live.name, "r.json"])


@pytest.mark.matrix
@pytest.mark.slow  # 26 s here; predict's and train's two-runs cases keep the output lock in the default set, and CI
# under 20 minutes
def test_fault_eval_two_runs_at_once(exported, tiny_dataset, tmp_path, capsys):
    """A second eval writing the results file of a running one (measured before: both exited 0 and the
    later one's results replaced the other's): refused with one line naming the running one; the first
    completes."""
    from hupbench.evaluation.results import load_results

    ckpt, _ = exported
    out = tmp_path / "out" / "r.json"
    first = start_writing(["eval", ckpt, tiny_dataset, "--threads", "1", "--out", out], out.parent)
    try:
        answer = run_cli(capsys, "eval", ckpt, tiny_dataset, "--no-latency", "--out", out)
    finally:
        finish(first)
    assert_clean_error(answer, str(out), "in use by another eval run", f"pid {first.pid}")
    assert load_results(out)["latency_ms_per_image"]["onnxruntime"]["batch1"] is not None  # the first run's
    assert sorted(p.name for p in out.parent.iterdir()) == ["r.json"]


@pytest.mark.matrix
def test_matrix_eval_leaderboard_row_from_uncommitted_code(exported, tiny_dataset, tmp_path, capsys, monkeypatch):
    """--out leaderboard/results/NAME.json from a source tree whose package code has uncommitted changes (its
    git_commit would say "+dirty": a row nobody can reproduce): refused before the model runs, naming the changed
    files; the same eval from the committed tree writes the row."""
    import subprocess

    from hupbench import provenance

    ckpt, _ = exported
    tree = tmp_path / "tree"
    (tree / "hupbench").mkdir(parents=True)
    (tree / "hupbench" / "metrics.py").write_text("x = 1\n")
    git = ["git", "-c", "user.name=t", "-c", "user.email=t@example.org"]
    for argv in (["init", "-q"], ["add", "."], ["commit", "-q", "-m", "first"]):
        subprocess.run([*git, *argv], cwd=tree, check=True, capture_output=True)
    monkeypatch.setattr(provenance, "SOURCE_TREE", tree)
    (tree / "hupbench" / "metrics.py").write_text("x = 2\n")
    row = tmp_path / "leaderboard" / "results" / "tiny.json"
    answer = run_cli(capsys, "eval", ckpt, tiny_dataset, "--no-latency", "--out", row)
    assert_clean_error(answer, "leaderboard/results/tiny.json", "must be reproducible from its commit",
                       "hupbench/metrics.py", "commit them first")
    assert not row.parent.exists() or not any(row.parent.iterdir())
    subprocess.run([*git, "commit", "-q", "-am", "second"], cwd=tree, check=True, capture_output=True)
    assert run_cli(capsys, "eval", ckpt, tiny_dataset, "--no-latency", "--out", row).rc == 0
    assert row.is_file()
