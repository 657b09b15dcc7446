"""How a verb's end reaches the user: one catch for every entry point (imports no torch).

:func:`answered` runs a verb (``hupbench VERB``, ``python train.py``) and answers how it ended:

- a deliberate refusal (a :class:`hupbench.core.errors.UserError`, or Hydra's and OmegaConf's errors of a
  malformed override, an unknown key or config option): one line ``PROGRAM: error: TEXT`` on stderr, exit 1;
- Ctrl-C: one line ``PROGRAM: interrupted ...``, exit 130;
- standard output that cannot be written: a reader that closed the pipe (``hupbench verify DATASET | head -1``)
  took what it wanted, so the rest of the output is dropped, the verb finishes its work and exits with its own
  code; a full stdout (``> /dev/full``, a full disk behind the redirection) is one line on stderr and exit 1,
  since the report the user asked for is lost (files the verb wrote before stay);
- anything else is a bug and keeps its traceback.

``debug`` (``--debug``, ``HYDRA_FULL_ERROR=1`` for train.py) lets the traceback of a refusal through instead.
"""

from __future__ import annotations

import os
import re
import sys
from collections.abc import Callable

from hupbench.core.errors import UserError


class StdoutError(UserError, OSError):
    """Standard output could not be written (a full disk or device behind a redirection)."""


def answered(prog: str, work: Callable[[], int], debug: bool = False, interrupted: str = "interrupted",
             config: str = "conf/train.yaml", example: str = "model=hopenet") -> int:
    """``work()``'s exit code, or the answer to how it failed (the module's list), printed on stderr.

    Args:
        prog: the program as the user typed it, e.g. ``"hupbench eval"`` or ``"train.py"``.
        work: runs the verb and returns its exit code.
        debug: let a refusal and Ctrl-C through (their tracebacks) instead of answering them.
        interrupted: the words after ``PROG: `` on Ctrl-C.
        config, example: :func:`hydra_error_line`'s, for a malformed override or an unknown key.
    """
    from hydra.errors import HydraException
    from omegaconf.errors import OmegaConfBaseException

    stdout = sys.stdout
    sys.stdout = guard = _GuardedStdout(stdout)
    try:
        code = work()
        guard.flush()  # what print() kept in a buffer meets a full device here, inside the catch
        return code
    except KeyboardInterrupt:
        if debug:
            raise
        # the loader and generator workers, in the same process group, got the same SIGINT and end quietly
        print(f"{prog}: {interrupted}", file=sys.stderr)
        return 130
    except (UserError, HydraException, OmegaConfBaseException) as exc:
        if debug:
            raise
        hydra = isinstance(exc, (HydraException, OmegaConfBaseException))
        print(f"{prog}: error: {hydra_error_line(exc, config, example) if hydra else error_line(exc)}",
              file=sys.stderr)
        return 1
    finally:
        sys.stdout = stdout


class _GuardedStdout:
    """``sys.stdout`` while a verb runs: writes pass through to ``stream`` until it fails. A closed pipe then
    silences the rest (nothing raised: the verb's work goes on); any other failure (ENOSPC, EIO) raises
    :class:`StdoutError`. Either way the file descriptor is pointed at /dev/null, so that the interpreter's
    own flush at exit does not fail again with a traceback of its own."""

    def __init__(self, stream) -> None:
        self._stream = stream
        self._silent = False

    def write(self, text: str) -> int:
        if not self._silent:
            self._guarded(self._stream.write, text)
        return len(text)

    def flush(self) -> None:
        if not self._silent:
            self._guarded(self._stream.flush)

    def _guarded(self, call, *args) -> None:
        try:
            call(*args)
        except OSError as exc:
            self._silent = True
            try:
                devnull = os.open(os.devnull, os.O_WRONLY)
                os.dup2(devnull, self._stream.fileno())
                os.close(devnull)
            except (OSError, AttributeError, ValueError):  # a stream without a file descriptor
                pass
            if not isinstance(exc, BrokenPipeError):
                raise StdoutError(exc.errno, f"cannot write to standard output ({exc.strerror}): the report "
                                             "goes there; redirect it to a writable file") from exc

    def __getattr__(self, name: str):
        return getattr(self._stream, name)


def error_line(exc: BaseException) -> str:
    """The one line the user sees for ``exc``: of a DataLoader worker's exception, which torch re-raises with
    the worker's whole traceback in its message, the last line (the original message, naming the file); of
    an OSError, the text without its ``[Errno N]``, which means nothing to the user."""
    text = str(exc)
    if "Original Traceback" in text:
        last = [line for line in text.splitlines() if line.strip()][-1].strip()
        match = re.match(r"^[A-Za-z_][\w.]*: (.*)$", last)
        text = match.group(1) if match else last
    text = re.sub(r"^\[Errno \d+\] ", "", text)
    return " ".join(line.strip() for line in text.splitlines() if line.strip()) or type(exc).__name__


def hydra_error_line(exc: BaseException, config: str = "conf/train.yaml", example: str = "model=hopenet") -> str:
    """Hydra's or OmegaConf's multi-line report of a malformed override, an unknown key or config option as one
    line, naming the ``config`` file when a key is not in it and showing the override ``example`` when one
    cannot be parsed."""
    from hydra.errors import OverrideParseException

    lines = [line.strip() for line in str(exc).splitlines() if line.strip()]
    # drop Hydra's pointers (grammar link, config search path) and OmegaConf's key details
    for stop in ("See https://hydra.cc", "Config search path:"):
        lines = lines[: next((i for i, line in enumerate(lines) if line.startswith(stop)), len(lines))]
    text = " ".join(lines)
    if isinstance(exc, OverrideParseException):
        if exc.override and repr(exc.override) not in text:
            text = f"cannot parse override {exc.override!r}: {text}"
        # a list of overrides (the quickstart's stage lists) with an element (after '[' or ',') that holds '=' but
        # does not open with a quote
        unquoted = "=[" in (exc.override or "") and re.search(r"[\[,]\s*[^'\"\s\[\],][^'\",\]]*=", exc.override)
        quote = "; a list element with '=' in it is quoted: key=['a=1','b=2']" if unquoted else ""
        return f"{text} (overrides are key=value, e.g. {example}{quote})"
    key = re.search(r"Could not override '([^']+)'", text)
    if key and "is not in struct" in str(exc.__cause__ or ""):
        append = re.search(r"use (\+\S+)", text)
        return (f"cannot override {key.group(1)!r}: the key is not in the config ({config} and its groups "
                f"list the keys{f'; {append.group(1)} adds it as a new key' if append else ''})")
    missing = re.search(r"Missing mandatory value: ([\w.]+)", text)
    if missing:  # a required value (??? in the config) that no config or override set
        return (f"{missing.group(1)} is required ('???' in {config}) and nothing set it: give it as an override "
                f"({missing.group(1)}=VALUE) or in the config that should set it")
    return text
