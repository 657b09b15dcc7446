"""The bad-input and fault matrix of ``hupbench leaderboard`` (docs/robustness.md, section leaderboard).

Every broken input is an error: one line naming the file (and line or field), exit 1, and the
README.md and plots left exactly as they were. A bad results file is not skipped with a warning,
because the table is committed: a row that silently disappears from it is a wrong leaderboard that
nobody notices. Files that are not ``*.json`` results (notes, temporary files of a killed eval) are
not results and are ignored; temporary files of a killed leaderboard run are removed.
"""

from __future__ import annotations

import hashlib
import json
import os
import random
import shlex
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from helpers.cli import CliAnswer, assert_clean_error, run_cli

from hupbench.evaluation.leaderboard import run_leaderboard
from hupbench.evaluation.results import write_results
from helpers import REPO
from helpers.faults import run_in_namespace
from helpers.leaderboard import COMMITTED, OUTPUTS, measured, write_log

pytestmark = pytest.mark.matrix


@pytest.fixture(scope="module")
def built_board(tmp_path_factory) -> Path:
    """The committed paper rows and two measured rows with training logs, built once."""
    root = tmp_path_factory.mktemp("board") / "leaderboard"
    (root / "results").mkdir(parents=True)
    for path in sorted((COMMITTED / "results").glob("*.json")):
        if json.loads(path.read_text())["kind"] == "reported":
            shutil.copy(path, root / "results" / path.name)
    for row in (measured("fast_small", "HOPE-Net (ResNet-10, 64 px)", 30.0, 25.0, 43.125, 2.0, 5.0, 1500.0),
                measured("slow_big", "HOPE-Net (ResNet-50, 224 px)", 10.456, 8.0, 16.9, 80.0, 150.0, 20 * 3600.0)):
        write_results(root / "results" / f"{row['run_name']}.json", row)
        write_log(root / row["training"]["log"], row["training"]["wall_s"], row["metrics"]["mpjpe_mm"]["all"])
    run_leaderboard(root)
    return root


@pytest.fixture
def board(built_board, tmp_path) -> Path:
    copy = tmp_path / "leaderboard"
    shutil.copytree(built_board, copy)
    return copy


def outputs(root: Path) -> dict[str, bytes]:
    return {name: (root / name).read_bytes() for name in OUTPUTS if (root / name).exists()}


def _edit(name: str, change):
    """A damage that loads results/NAME.json, changes the dict, and writes it back as JSON."""
    def damage(root: Path) -> None:
        path = root / "results" / f"{name}.json"
        data = json.loads(path.read_text())
        change(data)
        path.write_text(json.dumps(data))
    return damage


def _set(path: tuple, value):
    def change(data):
        for key in path[:-1]:
            data = data[key]
        data[path[-1]] = value
    return change


def _write(relative: str, data: bytes):
    return lambda root: (root / relative).write_bytes(data)


def _text(relative: str, change):
    return lambda root: (root / relative).write_text(change((root / relative).read_text()))


def _log_lines(change):
    def damage(root: Path) -> None:
        path = root / "logs" / "slow_big.jsonl"
        path.write_text("".join(line + "\n" for line in change(path.read_text().splitlines())))
    return damage


def _twice(lines: list[str]) -> list[str]:
    """Every line written twice, as by two trainings appending to one log."""
    return [line for line in lines for _ in range(2)]


def _as_case_twin(root: Path) -> None:
    data = json.loads((root / "results" / "slow_big.json").read_text())
    data["run_name"] = "Slow_Big"
    (root / "results" / "Slow_Big.json").write_text(json.dumps(data))


# case id -> (damage(root) -> None, the --dir to give (relative to root's parent, None = root), needles)
ERRORS = {
    "dir-missing": (None, "nowhere", ("nowhere", "does not exist")),
    "dir-is-a-file": (lambda root: (root.parent / "board.txt").write_text("x"), "board.txt", ("board.txt", "not a folder")),
    "dir-without-results": (lambda root: shutil.rmtree(root / "results"), None, ("results", "no results/ folder")),
    "results-without-json-files": (lambda root: [p.unlink() for p in (root / "results").glob("*.json")], None,
                                   ("no results files",)),
    "results-empty-file": (_write("results/slow_big.json", b""), None, ("slow_big.json", "empty file")),
    "results-bad-json": (_write("results/slow_big.json", b'{"schema_version": 2, "kind": "meas'), None,
                         ("slow_big.json", "not valid JSON")),
    "results-random-bytes": (_write("results/slow_big.json", random.Random(3).randbytes(2000)), None,
                             ("slow_big.json", "not valid JSON")),
    "results-entry-is-a-folder": (lambda root: (root / "results" / "odd.json").mkdir(), None,
                                  ("odd.json", "not a file")),
    "results-wrong-schema-version": (_edit("slow_big", _set(("schema_version",), 7)), None,
                                     ("slow_big.json", "schema_version", "7")),
    "results-missing-field": (_edit("slow_big", lambda d: d["metrics"]["mpjpe_mm"].pop("hand")), None,
                              ("slow_big.json", "missing key", "hand")),
    "results-unknown-field": (_edit("slow_big", _set(("metrics", "mpjpe_cm"), 1.0)), None,
                              ("slow_big.json", "unknown key", "mpjpe_cm")),
    "results-negative-mpjpe": (_edit("slow_big", _set(("metrics", "mpjpe_mm", "all"), -3.0)), None,
                               ("slow_big.json", "['mpjpe_mm']['all']", ">= 0", "-3.0")),
    "results-nan-mpjpe": (_edit("slow_big", _set(("metrics", "mpjpe_mm", "hand"), float("nan"))), None,
                          ("slow_big.json", "['mpjpe_mm']['hand']", "finite", "nan")),
    "results-infinite-latency": (_edit("slow_big", _set(("latency_ms_per_image", "onnxruntime", "batch1"),
                                                        float("inf"))), None, ("slow_big.json", "batch1", "finite")),
    "results-negative-training-time": (_edit("slow_big", _set(("training", "wall_s"), -60.0)), None,
                                       ("slow_big.json", "['training']['wall_s']", ">= 0")),
    "results-auc-above-one": (_edit("slow_big", _set(("metrics", "pck_auc_0_50mm"), 81.2)), None,
                              ("slow_big.json", "pck_auc_0_50mm", "[0, 1]")),
    "results-two-files-one-run-name": (lambda root: shutil.copy(root / "results" / "slow_big.json",
                                                                root / "results" / "slow_big_copy.json"), None,
                                       ("slow_big_copy.json", "file stem", "slow_big")),
    "results-run-names-differ-only-in-case": (_as_case_twin, None, ("Slow_Big.json", "slow_big.json", "case")),
    "log-missing": (lambda root: (root / "logs" / "slow_big.jsonl").unlink(), None,
                    ("results/slow_big.json", "logs/slow_big.jsonl", "not found")),
    "log-empty": (_write("logs/slow_big.jsonl", b""), None, ("slow_big.jsonl", "no validation lines")),
    "log-truncated": (lambda root: (root / "logs" / "slow_big.jsonl").write_bytes(
        (root / "logs" / "slow_big.jsonl").read_bytes()[:-40]), None, ("slow_big.jsonl:6", "not valid JSON")),
    "log-random-bytes": (_write("logs/slow_big.jsonl", random.Random(4).randbytes(3000)), None,
                         ("slow_big.jsonl", "UTF-8")),
    "log-duplicated-steps": (_log_lines(_twice), None, ("slow_big.jsonl:2", "step 0", "twice")),
    "log-nan-validation-error": (_log_lines(lambda lines: lines[:3] + [lines[3].replace(
        '"all": ', '"all": NaN, "was": ', 1)] + lines[4:]), None, ("slow_big.jsonl:4", "finite")),
    # the reader believes nothing a row says that its other fields contradict, or that no measurement can be
    "results-all-contradicts-hand-and-probe": (
        _edit("slow_big", lambda d: d["metrics"]["mpjpe_mm"].update(all=1.0, hand=500.0, probe=900.0)), None,
        ("slow_big.json", "['mpjpe_mm']['all']", "keypoint-weighted mean", "610.34", "got 1.0")),
    "results-mpjpe-1e308": (_edit("slow_big", _set(("metrics", "mpjpe_mm", "probe"), 1e308)), None,
                            ("slow_big.json", "['mpjpe_mm']['probe']", "at most 1e+09 mm", "1e+308")),
    "results-latency-1e308": (_edit("slow_big", _set(("latency_ms_per_image", "onnxruntime", "batch1"), 1e308)), None,
                              ("slow_big.json", "['batch1']", "at most 1e+06 ms")),
    "results-duplicate-key": (_text("results/slow_big.json", lambda text: text.replace(
        '"kind": "measured"', '"kind": "reported", "kind": "measured"', 1)), None,
        ("slow_big.json", "not valid JSON", "['kind']", "twice")),
    "results-garbage-created-utc": (_edit("slow_big", _set(("created_utc",), "last tuesday, probably")), None,
                                    ("slow_big.json", "['created_utc']", "UTC time", "last tuesday")),
    "results-deeply-nested": (_write("results/slow_big.json", b"[" * 100_000 + b"]" * 100_000), None,
                              ("slow_big.json", "not valid JSON", "recursion depth")),
    "log-step-a-string": (_log_lines(lambda lines: [lines[0].replace('"step": 0', '"step": "0"', 1)] + lines[1:]), None,
                          ("slow_big.jsonl:1", "'step'", "whole number", "'0'")),
    "log-steps-backwards": (_log_lines(lambda lines: lines[:1] + lines[1:][::-1]), None,
                            ("slow_big.jsonl:3", "'val' step 40 comes after step 50")),
}


@pytest.mark.parametrize("case", list(ERRORS))
def test_matrix_leaderboard(case, board, capsys):
    damage, dir_name, needles = ERRORS[case]
    before = outputs(board)
    if damage is not None:
        damage(board)
    target = board if dir_name is None else board.parent / dir_name
    answer = run_cli(capsys, "leaderboard", "--dir", target)
    line = assert_clean_error(answer, *needles)
    assert line.startswith("hupbench leaderboard: error:")
    assert outputs(board) == before, "a refused rebuild changed the leaderboard"
    assert not [p for p in board.rglob(".*.tmp*")], "a refused rebuild left temporary files"


@pytest.mark.parametrize("case", ["folder-read-only"])
def test_matrix_leaderboard_read_only(case, board):
    before = outputs(board)
    answer = run_in_namespace(["leaderboard", "--dir", board], read_only=(board,))
    assert_clean_error(answer, "cannot write", str(board), "read-only")
    assert outputs(board) == before


@pytest.mark.parametrize("case", ["other-files-in-results", "stale-temporary-files"])
def test_matrix_leaderboard_ignored(case, board, capsys):
    """Not results: notes and a killed eval's temporary file in results/ are ignored; temporary files a killed
    leaderboard run left are removed. The rebuild gives the same bytes."""
    before = outputs(board)
    if case == "other-files-in-results":
        extra = [board / "results" / "NOTES.md", board / "results" / ".slow_big.json.tmp999999"]
        for path in extra:
            path.write_text("{not results")
    else:
        stale = [board / f".{name}.tmp999999" for name in OUTPUTS]
        for path in stale:
            path.write_bytes(b"half a file")
    answer = run_cli(capsys, "leaderboard", "--dir", board)
    assert answer.rc == 0 and not answer.err, answer
    assert outputs(board) == before
    if case == "other-files-in-results":
        assert all(path.exists() for path in extra)  # not the leaderboard's files: left alone
    else:
        assert not any(path.exists() for path in stale)


# ------------------------------------------------------------------ faults


def _tree_digest(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


def test_fault_leaderboard_sigkill(built_board, tmp_path):
    """SIGKILL at random points of a rebuild (the first run has no outputs yet), then the same command:
    the outputs are complete and identical to an uninterrupted build, and no temporary file is left."""
    reference = _tree_digest(built_board)
    board = tmp_path / "leaderboard"
    shutil.copytree(built_board, board)
    for name in OUTPUTS:
        (board / name).unlink()
    command = [sys.executable, "-m", "hupbench.cli", "leaderboard", "--dir", str(board)]
    env = os.environ | {"PYTHONPATH": str(REPO)}
    start = time.perf_counter()
    subprocess.run(command, check=True, env=env, cwd=REPO, capture_output=True, timeout=300)
    full_s = time.perf_counter() - start
    rng = random.Random(15)
    killed = 0
    for _ in range(6):
        proc = subprocess.Popen(command, env=env, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        time.sleep(rng.uniform(0.2, 0.8) * full_s)
        if proc.poll() is None:
            proc.send_signal(signal.SIGKILL)
            killed += 1
        proc.wait(timeout=60)
    assert killed >= 3, f"only {killed} of 6 runs were still running when the kill came (a full run takes {full_s:.1f} s)"
    # a kill between a temporary file's write and its rename, made certain: what a killed writer leaves
    for name in OUTPUTS:
        (board / f".{name}.tmp999999").write_bytes(b"half")
    proc = subprocess.run(command, env=env, cwd=REPO, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert _tree_digest(board) == reference
    assert not list(board.rglob(".*.tmp*"))


def test_fault_leaderboard_plot_path_is_a_folder(board):
    """A folder where the latency plot belongs, and a changed results file (measured before: the rebuild
    renamed the new training plot into place beside the old README, then never ended): one line naming the
    folder, exit 1, the old README and training plot unchanged, no temporary file."""
    before = {name: (board / name).read_bytes() for name in OUTPUTS if name != "mpjpe_vs_latency.png"}
    results = board / "results" / "slow_big.json"
    results.write_text(results.read_text().replace('"HOPE-Net (ResNet-50, 224 px)"', '"Renamed"'))
    (board / "mpjpe_vs_latency.png").unlink()
    (board / "mpjpe_vs_latency.png").mkdir()
    command = [sys.executable, "-m", "hupbench.cli", "leaderboard", "--dir", str(board)]
    try:
        proc = subprocess.run(command, env=os.environ | {"PYTHONPATH": str(REPO)}, cwd=REPO, capture_output=True,
                              text=True, timeout=120)
    except subprocess.TimeoutExpired:
        pytest.fail("hupbench leaderboard did not end within 120 s with a folder in a plot's place")
    assert_clean_error(CliAnswer(proc.returncode, proc.stdout, proc.stderr), "mpjpe_vs_latency.png", "is a folder")
    assert {name: (board / name).read_bytes() for name in before} == before
    assert not list(board.rglob(".*.tmp*"))


def test_fault_leaderboard_disk_full(built_board, tmp_path):
    """No room for the new files: one line naming the disk and a file, exit 1, the old README and plots
    unchanged (all three are renamed into place only once all three are written), no temporary file."""
    board = tmp_path / "leaderboard"
    (tmp_path / "renamed.json").write_text(
        (built_board / "results" / "slow_big.json").read_text().replace('"HOPE-Net (ResNet-50, 224 px)"', '"Renamed"'))
    digests, listing = tmp_path / "digests.txt", tmp_path / "listing.txt"
    # room for the old files and a little more, not for a second copy of the two plots
    size_kb = sum(p.stat().st_size for p in built_board.rglob("*") if p.is_file()) // 1024 + 40
    q = shlex.quote
    answer = run_in_namespace(
        ["leaderboard", "--dir", board], tmpfs=(board, size_kb), listing=listing,
        setup=f"cp -a {q(str(built_board))}/. {q(str(board))}/ && cp {q(str(tmp_path))}/renamed.json "
              f"{q(str(board / 'results' / 'slow_big.json'))}",
        after=f"cd {q(str(board))} && sha256sum {' '.join(OUTPUTS)} > {q(str(digests))}")
    assert_clean_error(answer, "no space left on", str(board))
    expected = {name: hashlib.sha256((built_board / name).read_bytes()).hexdigest() for name in OUTPUTS}
    found = {line.split()[1]: line.split()[0] for line in digests.read_text().splitlines()}
    assert found == expected, "a failed rebuild changed the old outputs"
    assert not [row for row in listing.read_text().splitlines() if ".tmp" in row]
