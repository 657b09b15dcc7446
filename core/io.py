"""Safe file output: atomic writes, a clear full-disk error, stale temporary files, output locks.

Every file hupbench writes goes through :func:`atomic_output`: the data go to a temporary name in
the same folder (``.NAME.tmpPID[.ext]``), then one rename puts them in place. A killed process
leaves either the old file or the new one, never half of one under the final name; a failed write
(a full disk, a read-only folder) removes its temporary file and raises an :class:`OSError` whose
message names the file, and for a full disk the device: ``no space left on DEVICE writing FILE``.
:func:`clean_stale_tmp` removes what killed processes left behind.

:class:`OutputLock` gives one run at a time to an output folder (generate, training): a lock file
naming the holder's pid, host and command, held by an ``flock`` that the kernel drops when the
holder dies, so the lock of a killed run is taken over without asking.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import hashlib
import json
import os
import re
import shutil
import socket
import sys
import time
from pathlib import Path
from typing import Any, Callable, Iterator

import numpy as np

from hupbench.core.errors import (BadPathError, BadValueError, MissingFileError, NotWritableError, RunFailedError,
                                  UserError)

#: temporary names written by this module: ``.NAME.tmpPID`` or ``.STEM.tmpPID.npz``
TMP_PATTERN = re.compile(r"^\..+\.tmp(\d+)(\.[A-Za-z0-9]+)?$")
LOCK_NAME = ".hupbench.lock"


class DiskFullError(UserError, OSError):
    """ENOSPC while writing ``path``; the message names the device (its mount point) and the file."""

    def __init__(self, path: str | Path) -> None:
        path = Path(path)
        super().__init__(errno.ENOSPC, f"no space left on {mount_point(path)} writing {path}")
        self.filename = str(path)

    def __str__(self) -> str:
        return self.strerror


def file_sha256(path: str | Path) -> str:
    """Hex SHA-256 of a file's bytes."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def check_writable(path: str | Path, what: str, *, file: bool = False) -> Path:
    """``path`` can be written: a folder (or, with ``file``, a file) that exists or can be made, on a
    writable file system; nothing is created.

    Args:
        path: the output folder, or the output file with ``file=True``.
        what: how the user named it (``"out_dir"``, ``"--out"``), for the message.

    Returns:
        ``Path(path)``.

    Raises:
        BadValueError: ``path`` is empty (it would name the current folder) or not a path, a folder where a
            file belongs, or it (or a parent) is a file where a folder belongs. BadPathError: a name in it is
            longer than the file system allows. NotWritableError: the nearest existing folder is read-only or
            not writable.
    """
    if not isinstance(path, (str, os.PathLike)) or not str(path).strip():
        raise BadValueError(f"{what} must be a {'file' if file else 'folder'} path, got {path!r}")
    with writing(path, what) as path:  # Path.exists itself fails on a name longer than the file system allows
        if file and path.is_dir():
            raise BadValueError(f"{what} {path} is a folder; expected a file path")
        existing = path.parent if file else path
        while not existing.exists() and existing != existing.parent:
            existing = existing.parent
    if not existing.is_dir():
        where = f": {existing} is a file" if existing != path else " (a file of that name exists)"
        raise BadValueError(f"{what} {path} is not a folder{where}")
    if not os.access(existing, os.W_OK | os.X_OK):
        try:
            read_only = bool(os.statvfs(existing).f_flag & os.ST_RDONLY)
        except OSError:
            read_only = False
        why = "on a read-only file system" if read_only else "not writable (permission denied)"
        where = "" if existing == path else f" (its {'folder' if file and existing == path.parent else 'parent'} {existing})"
        raise NotWritableError(f"cannot write {what} {path}{where}: {why}")
    return path


def mount_point(path: str | Path) -> str:
    """The mount point holding ``path`` (or its nearest existing parent), e.g. ``/`` or ``/mnt/data``."""
    path = Path(os.path.abspath(path))
    while not path.exists() and path != path.parent:
        path = path.parent
    while not os.path.ismount(path) and path != path.parent:
        path = path.parent
    return str(path)


def tmp_path(path: str | Path, suffix: str = "") -> Path:
    """The temporary name of ``path`` for this process: ``.NAME.tmpPID`` + ``suffix``."""
    path = Path(path)
    return path.with_name(f".{path.name}.tmp{os.getpid()}{suffix}")


def _explain(exc: OSError, path: Path, what: str = "", fix: str = "") -> OSError:
    """The user error of an OSError met writing ``path``, naming ``path`` (as ``what`` when given, e.g.
    "out_dir") and ``fix`` (words on what to do): a full disk, a folder that may not be written, a file where a
    folder belongs or the reverse, a name too long. Any other OSError (a reader's, a missing input) is returned
    as it came."""
    name, fix = f"{what} {path}" if what else str(path), f"; {fix}" if fix else ""
    if exc.errno == errno.ENOSPC:
        return DiskFullError(path)
    if exc.errno in (errno.EACCES, errno.EPERM, errno.EROFS):
        return NotWritableError(exc.errno, f"cannot write {name}: {exc.strerror}{fix}")
    if exc.errno in (errno.ENOTDIR, errno.EEXIST):
        blocker = next((p for p in (path, *path.parents) if os.path.exists(p) and not os.path.isdir(p)), None)
        if blocker is not None:
            where = "it is a file; expected a folder" if blocker == path else f"{blocker} is a file, not a folder"
            return BadPathError(exc.errno, f"cannot write {name}: {where}{fix}")
    if exc.errno == errno.EISDIR:
        return BadPathError(exc.errno, f"cannot write {name}: it is a folder; expected a file{fix}")
    if exc.errno == errno.ENAMETOOLONG:
        return BadPathError(exc.errno, f"cannot write {name}: the path, or a name in it, is longer than the file "
                                       f"system allows{fix}")
    return exc


@contextlib.contextmanager
def writing(path: str | Path, what: str = "", fix: str = "") -> Iterator[Path]:
    """Run a block that writes ``path`` (a file, or a folder and what it holds) and yield ``Path(path)``; an
    OSError in it of the kinds :func:`atomic_output` names (a full disk, no permission, a file where a folder
    belongs, a name too long) is raised as the user error that names ``path`` (as ``what``) and ``fix``."""
    path = Path(path)
    try:
        yield path
    except OSError as exc:
        explained = _explain(exc, path, what, fix) if not isinstance(exc, UserError) else exc
        if explained is exc:
            raise
        raise explained from exc


@contextlib.contextmanager
def atomic_output(path: str | Path, suffix: str = "") -> Iterator[Path]:
    """Yield a temporary path to write ``path``'s content to; rename it into place on success.

    Creates the parent folders. On any error the temporary file is removed and an OSError is
    re-raised with a message naming ``path`` (:class:`DiskFullError` for a full disk).

    Args:
        path: the final file.
        suffix: appended to the temporary name, for writers that insist on an extension
            (``np.savez`` appends ``.npz`` to any other name).
    """
    path = Path(path)
    tmp = tmp_path(path, suffix)
    try:
        with writing(path):
            path.parent.mkdir(parents=True, exist_ok=True)
            yield tmp
            os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):  # never made (no folder for it, a name too long): the first error counts
            tmp.unlink()
        raise


@contextlib.contextmanager
def atomic_folder(path: str | Path) -> Iterator[Path]:
    """Yield a temporary folder beside ``path`` to build a folder's content in; on success it replaces
    ``path``, on any error it is removed.

    ``path`` must be absent, an empty folder, or a folder the caller has decided to replace (removed
    only once the new content is complete). A failed or interrupted build leaves ``path`` as it was
    and nothing beside it but, after a kill, a ``.NAME.tmpPID`` folder; an OSError is re-raised naming
    ``path`` (:class:`DiskFullError` for a full disk).
    """
    path = Path(path)
    stage = tmp_path(path)
    shutil.rmtree(stage, ignore_errors=True)
    try:
        with writing(path):  # a reader's error (a missing input file) passes as it came
            stage.mkdir(parents=True)
            yield stage
            if path.exists():
                shutil.rmtree(path)
            os.replace(stage, path)
    except BaseException:
        shutil.rmtree(stage, ignore_errors=True)
        raise


def write_with(path: str | Path, writer: Callable[[Path], object], suffix: str = "") -> Path:
    """Atomically write ``path`` with ``writer(tmp_path)`` (e.g. ``torch.save``); see :func:`atomic_output`.

    Some writers (``torch.save``) report a full disk as a RuntimeError; any error while the disk
    holding ``path`` has no free space left is reported as :class:`DiskFullError`.
    """
    path = Path(path)
    with atomic_output(path, suffix) as tmp:
        try:
            writer(tmp)
        except OSError:
            raise
        except Exception as exc:
            if _disk_full(tmp.parent):
                raise DiskFullError(path) from exc
            raise
    return path


def _disk_full(folder: Path) -> bool:
    try:
        stats = os.statvfs(folder)
    except OSError:
        return False
    return stats.f_bavail * stats.f_frsize < 64 * 1024


def encode_image(ext: str, image: np.ndarray, params: list[int] | None = None) -> bytes:
    """An image encoded by OpenCV (``ext`` ".png", ".jpg", ...; ``image`` in OpenCV's channel order), or a
    :class:`~hupbench.core.errors.RunFailedError` naming what could not be encoded."""
    import cv2

    ok, buf = cv2.imencode(ext, image, params or [])
    if not ok:
        raise RunFailedError(f"OpenCV could not encode a {image.shape} {image.dtype} image as {ext}")
    return buf.tobytes()


def write_bytes(path: str | Path, data: bytes) -> Path:
    """Write bytes atomically, creating parent folders."""
    return write_with(path, lambda tmp: tmp.write_bytes(data))


#: one encoder for every call: ``json.dumps(..., allow_nan=False)`` builds a new one each time, which was half of
#: compact_json's time on predict's records
_ENCODE = json.JSONEncoder(allow_nan=False).encode


def compact_json(value: Any, indent: int = 0) -> str:
    """Indented JSON (keys sorted) with every list of numbers on one line: one keypoint per line."""
    pad, inner = " " * indent, " " * (indent + 2)
    if isinstance(value, dict) and value:
        items = [f"{inner}{_ENCODE(str(k))}: {compact_json(v, indent + 2)}" for k, v in sorted(value.items())]
        return "{\n" + ",\n".join(items) + "\n" + pad + "}"
    if isinstance(value, (list, tuple)) and value:
        if all(v is None or isinstance(v, (int, float)) for v in value):
            return _ENCODE(list(value))   # "[a, b]", one call for the whole row
        return "[\n" + ",\n".join(inner + compact_json(v, indent + 2) for v in value) + "\n" + pad + "]"
    return _ENCODE(value)


def write_json(path: str | Path, data: dict) -> Path:
    """Write indented JSON atomically (numpy scalars and paths become plain values)."""
    return write_bytes(path, (json.dumps(data, indent=2, sort_keys=True, default=_plain) + "\n").encode())


def save_npz(path: str | Path, arrays: dict) -> Path:
    """``np.savez`` atomically."""
    return write_with(path, lambda tmp: np.savez(tmp, **arrays), suffix=".npz")


def _plain(value):
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    return str(value)


def pid_alive(pid: int) -> bool:
    """Whether a process with this pid runs on this machine (a zombie, dead but not reaped, does not)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, owned by someone else
        pass
    try:
        # /proc/PID/stat: "pid (comm) state ..."; comm may hold spaces and parentheses
        state = Path(f"/proc/{pid}/stat").read_text().rpartition(")")[2].split()[0]
    except (OSError, IndexError):
        return True  # no procfs (not Linux): the signal answer is all there is
    return state not in ("Z", "X")


def clean_stale_tmp(folder: str | Path, recursive: bool = True) -> list[Path]:
    """Remove the temporary files (:data:`TMP_PATTERN`) of processes that no longer run.

    A file whose pid is alive belongs to a running writer and is kept.

    Returns:
        The removed paths.
    """
    folder = Path(folder)
    if not folder.is_dir():
        return []
    removed = []
    candidates = folder.rglob(".*.tmp*") if recursive else folder.glob(".*.tmp*")
    for path in candidates:
        match = TMP_PATTERN.match(path.name)
        if match and path.is_file() and not pid_alive(int(match.group(1))):
            path.unlink(missing_ok=True)
            removed.append(path)
    return removed


class LockedError(UserError, RuntimeError):
    """Another live process holds the output folder's lock."""


class OutputLock:
    """One run at a time per output folder: ``FOLDER/.hupbench.lock``.

    The lock file holds the holder's pid, host, start time and command line (JSON). It is held by an
    exclusive ``flock``, which the kernel releases when the holder exits or is killed: a lock file
    left by a dead run is stale and is taken over (``taken_over`` names its old holder).

    Args:
        folder: the output folder (created if needed).
        what: the verb taking the lock, for the message ("generate", "training").
        name: the lock file's name in ``folder``; :meth:`for_file` locks one output file.

    Raises:
        LockedError: another live process holds the folder (the message names its pid and host).
    """

    def __init__(self, folder: str | Path, what: str, name: str = LOCK_NAME) -> None:
        self.folder = Path(folder)
        self.what = what
        self.path = self.folder / name
        self.target = self.folder
        self._fd: int | None = None
        self.taken_over: dict | None = None

    @classmethod
    def for_file(cls, path: str | Path, what: str) -> "OutputLock":
        """A lock on one output file: ``.NAME.lock`` beside it (two runs writing one results file)."""
        path = Path(path)
        lock = cls(path.parent, what, f".{path.name}.lock")
        lock.target = path
        return lock

    def holder(self) -> dict | None:
        """The recorded holder ({"pid", "host", "what", "since", "command"}) or None."""
        try:
            return json.loads(self.path.read_text())
        except (OSError, ValueError):
            return None

    def acquire(self) -> "OutputLock":
        for _ in range(100):
            fd = self._open_locked()
            # a holder that released between our open and our flock unlinked the file we locked
            try:
                same = os.fstat(fd).st_ino == os.stat(self.path).st_ino
            except FileNotFoundError:
                same = False
            if same:
                break
            os.close(fd)
        else:
            raise LockedError(f"could not take the lock {self.path}: it keeps being replaced")
        previous = self.holder()
        if previous and previous.get("pid") not in (None, os.getpid()):
            self.taken_over = previous
        record = {"pid": os.getpid(), "host": socket.gethostname(), "what": self.what,
                  "since": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), "command": " ".join(sys.argv)}
        data = (json.dumps(record, indent=2) + "\n").encode()
        with writing(self.target):  # the user knows the output, not its lock file
            try:
                os.ftruncate(fd, 0)
                os.pwrite(fd, data, 0)
            except OSError:
                self.path.unlink(missing_ok=True)  # an empty lock file would outlive the failed run
                os.close(fd)
                raise
        self._fd = fd
        return self

    def _open_locked(self) -> int:
        with writing(self.target):  # the user knows the output, not its lock file
            self.folder.mkdir(parents=True, exist_ok=True)
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            held = self.holder() or {}
            raise LockedError(
                f"{self.target} is in use by another {held.get('what', 'hupbench')} run (pid {held.get('pid', '?')} "
                f"on {held.get('host', '?')}, since {held.get('since', '?')}); wait for it to finish, stop it, "
                f"or choose another folder") from None
        return fd

    def release(self) -> None:
        """Remove the lock file and drop the lock (the file goes first: nobody sees it unlocked)."""
        if self._fd is None:
            return
        self.path.unlink(missing_ok=True)
        os.close(self._fd)
        self._fd = None

    def __enter__(self) -> "OutputLock":
        return self.acquire()

    def __exit__(self, *exc) -> None:
        self.release()


def _unique_keys(pairs: list[tuple[str, Any]]) -> dict:
    """A JSON object's key/value pairs as a dict, refusing a key named twice."""
    keys = [key for key, _ in pairs]
    twice = sorted({key for key in keys if keys.count(key) > 1})
    if twice:
        raise ValueError(f"an object names the key(s) {twice} twice (which value is meant?)")
    return dict(pairs)


def parse_json(data: bytes, where: str) -> Any:
    """UTF-8 JSON bytes as Python values, read strictly: a syntax error, an object that names a key twice and
    nesting deeper than the parser follows are one error starting with ``where`` (the file, or file:line)."""
    try:
        return json.loads(data.decode("utf-8"), object_pairs_hook=_unique_keys)
    except (ValueError, RecursionError) as exc:  # JSONDecodeError and UnicodeDecodeError are ValueErrors
        raise BadValueError(f"{where}: not valid JSON: {exc}") from None


def read_bytes(path: Path, what: str) -> bytes:
    """The bytes of the file ``path``; ``what`` names the kind of file in errors (``"results file"``)."""
    if path.exists() and not path.is_file():
        raise BadValueError(f"{path}: not a file (a {what} is one file)")
    if not path.is_file():
        raise MissingFileError(f"{what} not found: {path}")
    return path.read_bytes()
