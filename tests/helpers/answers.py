"""The error lines the tests see, recorded for docs/robustness.md.

With ``HUPBENCH_RECORD_ANSWERS=FILE`` every answer a test asserts on is appended to FILE as
``{"test": node id, "answer": line}`` (``pytest -m matrix``): docs/robustness.md quotes those
recordings, never hand-copied text.
"""

from __future__ import annotations

import json
import os

import pytest


def _record(**fields: str) -> None:
    path = os.environ.get("HUPBENCH_RECORD_ANSWERS")
    if path:
        test = os.environ.get("PYTEST_CURRENT_TEST", "?").split(" ")[0]
        with open(path, "a", encoding="utf-8") as fh:
            fh.write(json.dumps({"test": test, **fields}) + "\n")


def record_answer(line: str) -> None:
    """Append the error line ``line`` to the recording, when one is being made."""
    _record(answer=line)


def record_input(command: str) -> None:
    """Append the command a case ran (the "input" of a new row of docs/robustness.md)."""
    _record(input=command)


def assert_refusal(call, *needles: str, prog: str, given: str | None = None) -> str:
    """``call()`` refuses with a :class:`hupbench.core.errors.UserError` whose line names every needle.

    The unit-test form of a matrix case: the line is the one the CLI prints for that error
    (``PROG: error: TEXT`` through :func:`hupbench.error_lines.error_line`), without running the verb.

    Args:
        call: a callable that must raise.
        needles: what the line must contain, compared case-insensitively.
        prog: the program prefix users see, e.g. ``"hupbench generate"`` or ``"train.py"``.
        given: the bad input in the user's words (``"dataset.width=0"``), for the doc's input column.

    Returns:
        The error line.
    """
    from hupbench.core.errors import UserError
    from hupbench.error_lines import error_line

    with pytest.raises(UserError) as info:
        call()
    line = f"{prog}: error: {error_line(info.value)}"
    for needle in needles:
        assert str(needle).lower() in line.lower(), f"the error {line!r} does not name {needle!r}"
    record_answer(line)
    if given is not None:
        record_input(given)
    return line
