"""The errors of a deliberate refusal: a bad input, a missing or damaged file, an output path that cannot be
written, a full disk, a held lock.

Each derives from :class:`UserError`, which the CLI and ``train.py`` answer with one line and exit code 1,
and from the builtin a caller would catch (``except ValueError`` still works). Anything else raised is a
bug and keeps its traceback.
"""

from __future__ import annotations


class UserError(Exception):
    """A refusal the user can act on; its message names what was wrong."""


class BadValueError(UserError, ValueError):
    """A value out of range, malformed or inconsistent with another."""


class BadTypeError(UserError, TypeError):
    """A value of the wrong kind (a string where a number belongs)."""


class MissingFileError(UserError, FileNotFoundError):
    """A file or folder the input names does not exist."""


class RunFailedError(UserError, RuntimeError):
    """A run that cannot go on: a missing system library, a diverged loss, an output that is not finite."""


class BadPathError(UserError, OSError):
    """An output path that cannot be made as given: a file where a folder belongs or the reverse, a name longer
    than the file system allows; says which."""

    def __str__(self) -> str:
        return self.strerror or super().__str__()


class NotWritableError(UserError, PermissionError):
    """A folder or file that may not be written (permissions, a read-only file system); says which."""

    def __str__(self) -> str:
        return self.strerror or super().__str__()
