"""Running a verb in this process and judging its answer (the bad-input matrix, docs/robustness.md)."""

import os
import subprocess

from helpers import REPO
from helpers.answers import record_answer, record_input


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


def run_with_stdout(argv: list[str], stdout: str, **kwargs) -> CliAnswer:
    """Run ``argv`` in a subprocess with its standard output on a full device (``"full"``: ``> /dev/full``) or
    on a pipe whose reader is gone (``"closed"``: ``| head -1`` once head has exited); its standard error
    captured. ``kwargs`` go to :func:`subprocess.run` (``cwd``, ``timeout``)."""
    read_end, write_end = os.pipe()
    os.close(read_end)
    env = {**os.environ, "PYTHONPATH": str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    with os.fdopen(write_end, "w") as pipe, open("/dev/full", "w") as full:
        done = subprocess.run(argv, stdout=full if stdout == "full" else pipe, stderr=subprocess.PIPE, text=True,
                              env=env, **kwargs)
    return CliAnswer(done.returncode, "", done.stderr)


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
