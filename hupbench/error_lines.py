"""How an error reaches the user: one line, no traceback (imports no torch).

Every verb (``hupbench VERB``) and ``python train.py`` answers a bad input or a failed run with one
line, ``PROGRAM: error: TEXT``, and exit code 1; ``--debug`` (``HYDRA_FULL_ERROR=1`` for train.py)
lets the traceback through instead. A deliberate refusal raises a :class:`hupbench.core.errors.UserError`;
anything else is a bug and keeps its traceback.
"""

from __future__ import annotations

import re

from hupbench.core.errors import UserError

#: what a bad input or a fault raises (Hydra's and OmegaConf's errors are added where Hydra is imported)
USER_ERRORS = (UserError,)


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
        return f"{text} (overrides are key=value, e.g. {example})"
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
