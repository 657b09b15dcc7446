"""The top-level `hupbench` command: bad input (docs/robustness.md, ## hupbench (CLI)), --version,
--debug, each verb's --help, and a standard output that is full or closed (hupbench.error_lines.answered).

Bad input to the command itself is argparse's business: a usage line on stderr, then one line
`hupbench: error: ...` naming what was wrong and what was expected, exit 2, no traceback.
"""

import os
import re
import subprocess
import sys

import pytest

from helpers.cli import assert_clean_error, run_cli, run_with_stdout  # noqa: E402  (tests/ is on sys.path)
from hupbench import __version__
from hupbench.cli import VERBS
from helpers import REPO


# id -> (argv, needles)
CASES = {
    # before: the help on stdout and exit 2, with no line saying what was wrong
    "no-verb": ([], ["a verb is required", *VERBS]),
    "unknown-verb": (["frobnicate"], ["invalid choice: 'frobnicate'", *VERBS]),
    "misspelt-verb": (["generat", "out_dir=x"], ["invalid choice: 'generat'", "generate"]),
    "unknown-option": (["--frobnicate"], ["unrecognized arguments", "--frobnicate"]),
    "unknown-option-of-verb": (["grasps", "--frobnicate"], ["unrecognized arguments", "--frobnicate"]),
}


@pytest.mark.matrix
@pytest.mark.parametrize("case", list(CASES))
def test_matrix_cli(case, capsys):
    argv, needles = CASES[case]
    answer = run_cli(capsys, *argv)
    # a verb's own options are its parser's: the error names the verb
    prefix = "hupbench grasps: error:" if case == "unknown-option-of-verb" else "hupbench: error:"
    assert_clean_error(answer, *needles, prefix=prefix)
    assert answer.rc == 2, answer
    # argparse's usage line (or, without a verb, the whole help) says how to call the command
    assert "usage: hupbench" in answer.err + answer.out, answer


def test_no_verb_prints_the_verbs_on_stdout(capsys):
    answer = run_cli(capsys)
    assert answer.rc == 2
    listed = re.findall(r"^    (\S+)", answer.out, flags=re.M)
    assert listed == list(VERBS), answer.out


def test_version(capsys):
    answer = run_cli(capsys, "--version")
    assert answer.rc == 0 and answer.err == ""
    assert answer.out.strip() == f"hupbench {__version__}"
    assert re.fullmatch(r"\d+\.\d+\.\d+", __version__), __version__


# after the verb (8.5 s) runs with the slow tests: the same flag, parsed by the same code (CI keeps under 20 minutes)
@pytest.mark.parametrize("where", ["before-the-verb", pytest.param("after-the-verb", marks=pytest.mark.slow)])
def test_debug_shows_the_traceback(tmp_path, where):
    """--debug, before or after the verb, lets the traceback of a bad input through; without it, one line."""
    env = {**os.environ, "PYTHONPATH": str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    argv = [sys.executable, "-m", "hupbench.cli", "grasps", f"out_dir={tmp_path / 'g'}", "threads=0"]
    plain = subprocess.run(argv, capture_output=True, text=True, env=env, timeout=120)
    at = 3 if where == "before-the-verb" else 4
    debug = subprocess.run([*argv[:at], "--debug", *argv[at:]], capture_output=True, text=True, env=env, timeout=120)
    assert plain.returncode == 1 and "Traceback" not in plain.stderr, plain.stderr
    assert plain.stderr.strip().startswith("hupbench grasps: error: threads must be a whole number"), plain.stderr
    assert debug.returncode == 1, debug
    assert "Traceback (most recent call last)" in debug.stderr, debug.stderr
    assert debug.stderr.strip().splitlines()[-1].startswith("hupbench.core.errors.BadValueError: threads must be a whole number"), debug.stderr
    assert not (tmp_path / "g").exists()


@pytest.mark.parametrize("verb", list(VERBS))
def test_verb_help(verb, capsys):
    answer = run_cli(capsys, verb, "--help")
    assert answer.rc == 0, answer
    assert answer.out.startswith(f"usage: hupbench {verb}"), answer.out[:300]
    assert "--help" in answer.out and answer.err == ""


@pytest.mark.matrix
@pytest.mark.parametrize("stdout", ["full", "closed"])
def test_matrix_cli_stdout_full_or_closed(stdout, tiny_dataset, tmp_path):
    """A verb's report on a full standard output (``> /dev/full``) is one line and exit 1: the report the user
    asked for is lost. A reader that closed the pipe early (``| head -1``) took what it wanted: the verb finishes
    and exits with its own code, 0 for a dataset that passes. Both ended in a traceback (measured before:
    ``OSError: [Errno 28] No space left on device`` from verify's first line; ``BrokenPipeError`` and exit 1
    after verify had passed)."""
    answer = run_with_stdout([sys.executable, "-m", "hupbench.cli", "verify", str(tiny_dataset), "--workers", "1"],
                             stdout, timeout=300)
    if stdout == "closed":
        assert answer.rc == 0 and answer.err == "", answer.err
        return
    assert_clean_error(answer, "cannot write to standard output", "No space left on device",
                       prefix="hupbench verify: error:")
    assert answer.rc == 1
