"""hupbench.core.io: atomic writes, the full-disk message and other paths that cannot be written, stale temporary
files and the output lock."""

import errno
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time

import numpy as np
import pytest

from hupbench.core import io


def test_atomic_write_leaves_old_file_on_failure(tmp_path):
    target = tmp_path / "sub" / "a.json"
    io.write_json(target, {"x": 1})
    assert json.loads(target.read_text()) == {"x": 1}

    def broken(tmp):
        tmp.write_bytes(b"half")
        raise RuntimeError("writer died")

    with pytest.raises(RuntimeError, match="writer died"):
        io.write_with(target, broken)
    assert json.loads(target.read_text()) == {"x": 1}, "a failed write replaced the old file"
    assert [p.name for p in target.parent.iterdir()] == ["a.json"], "the temporary file was left behind"
    io.save_npz(tmp_path / "b.npz", {"a": np.arange(3)})
    with np.load(tmp_path / "b.npz") as data:
        np.testing.assert_array_equal(data["a"], np.arange(3))


def test_enospc_names_device_and_file(tmp_path):
    def full(tmp):
        tmp.write_bytes(b"x")
        raise OSError(errno.ENOSPC, "No space left on device")

    target = tmp_path / "big.bin"
    with pytest.raises(io.DiskFullError) as info:
        io.write_with(target, full)
    assert str(info.value) == f"no space left on {io.mount_point(tmp_path)} writing {target}"
    assert info.value.errno == errno.ENOSPC and not list(tmp_path.iterdir())


def test_full_tmpfs_gives_the_message(tmp_path):
    """A real full disk: a 64 KiB tmpfs in a private mount namespace (root only)."""
    if shutil.which("unshare") is None or os.geteuid() != 0:
        pytest.skip("needs root and unshare to mount a small tmpfs")
    mnt = tmp_path / "mnt"
    mnt.mkdir()
    code = ("import sys; from hupbench.core import io\n"
            "try:\n    io.write_bytes(sys.argv[1] + '/x.bin', b'0' * 1_000_000)\n"
            "except OSError as e:\n    print(e)\n")
    proc = subprocess.run(["unshare", "-m", "--propagation", "private", "sh", "-c",
                           f"mount -t tmpfs -o size=64k tmpfs {mnt} && {sys.executable} -c \"$0\" {mnt} && ls -A {mnt}",
                           code], capture_output=True, text=True, timeout=60, cwd=os.getcwd(),
                          env={**os.environ, "PYTHONPATH": os.getcwd()})
    if "mount:" in proc.stderr or proc.returncode != 0 and "permission" in proc.stderr.lower():
        pytest.skip(f"cannot mount a tmpfs here: {proc.stderr.strip()}")
    lines = proc.stdout.strip().splitlines()
    assert lines == [f"no space left on {mnt} writing {mnt}/x.bin"], proc.stdout + proc.stderr


def _dead_pid() -> int:
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


def test_clean_stale_tmp_removes_only_dead_writers(tmp_path):
    dead = _dead_pid()
    (tmp_path / "d").mkdir()
    stale = [tmp_path / f".a.json.tmp{dead}", tmp_path / "d" / f".b.tmp{dead}.npz"]
    live = tmp_path / f".c.json.tmp{os.getpid()}"
    other = tmp_path / ".hidden.tmpfile"  # not our pattern
    for p in (*stale, live, other):
        p.write_bytes(b"x")
    removed = io.clean_stale_tmp(tmp_path)
    assert sorted(removed) == sorted(stale)
    assert live.exists() and other.exists()


def test_zombie_counts_as_dead():
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    time.sleep(0.5)  # exited, not yet reaped: a zombie
    try:
        assert not io.pid_alive(proc.pid)
    finally:
        proc.wait()
    assert io.pid_alive(os.getpid())


def test_output_lock_refuses_a_second_holder_and_names_it(tmp_path):
    with io.OutputLock(tmp_path, "generate") as lock:
        held = json.loads(lock.path.read_text())
        assert held["pid"] == os.getpid() and held["host"] == socket.gethostname() and held["what"] == "generate"
        with pytest.raises(io.LockedError, match=rf"in use by another generate run \(pid {os.getpid()} on "
                                                 rf"{socket.gethostname()}"):
            io.OutputLock(tmp_path, "training").acquire()
    assert not lock.path.exists()
    io.OutputLock(tmp_path, "training").acquire().release()


def test_killed_holder_lock_is_taken_over(tmp_path):
    code = ("import sys, time; from hupbench.core import io\n"
            "io.OutputLock(sys.argv[1], 'training').acquire(); print('locked', flush=True); time.sleep(60)\n")
    proc = subprocess.Popen([sys.executable, "-c", code, str(tmp_path)], stdout=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONPATH": os.getcwd()})
    try:
        assert proc.stdout.readline().strip() == "locked"
        with pytest.raises(io.LockedError, match=f"pid {proc.pid}"):
            io.OutputLock(tmp_path, "training").acquire()
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
    finally:
        proc.kill()
    lock = io.OutputLock(tmp_path, "training").acquire()
    try:
        assert lock.taken_over is not None and lock.taken_over["pid"] == proc.pid
        assert json.loads(lock.path.read_text())["pid"] == os.getpid()
    finally:
        lock.release()


def test_file_sha256_is_hashlib_of_the_bytes(tmp_path):
    import hashlib

    data = os.urandom(3 << 20)  # more than one read block
    (tmp_path / "f").write_bytes(data)
    assert io.file_sha256(tmp_path / "f") == hashlib.sha256(data).hexdigest()


def test_check_writable_names_the_problem(tmp_path):
    (tmp_path / "file").write_text("x")
    assert io.check_writable(tmp_path / "new" / "deeper", "out_dir") == tmp_path / "new" / "deeper"
    assert not (tmp_path / "new").exists(), "a check created a folder"
    with pytest.raises(io.BadValueError, match=r"out_dir .*file is not a folder \(a file of that name exists\)"):
        io.check_writable(tmp_path / "file", "out_dir")
    with pytest.raises(io.BadValueError, match=r"out_dir .*file/sub is not a folder: .*file is a file"):
        io.check_writable(tmp_path / "file" / "sub", "out_dir")
    with pytest.raises(io.BadValueError, match=r"--out .* is a folder; expected a file path"):
        io.check_writable(tmp_path, "--out", file=True)
    assert io.check_writable(tmp_path / "a" / "m.onnx", "--out", file=True) == tmp_path / "a" / "m.onnx"


def test_check_writable_refuses_a_read_only_mount(tmp_path):
    """A read-only bind mount in a private mount namespace (root only): the message says why."""
    if shutil.which("unshare") is None or os.geteuid() != 0:
        pytest.skip("needs root and unshare for a private read-only mount")
    (tmp_path / "ro").mkdir()
    script = (f"mount --bind {tmp_path / 'ro'} {tmp_path / 'ro'} && mount -o remount,bind,ro {tmp_path / 'ro'} && "
              f"{sys.executable} -c \"from hupbench.core import io; io.check_writable('{tmp_path / 'ro' / 'g'}', 'out_dir')\"")
    proc = subprocess.run(["unshare", "-m", "sh", "-c", script], capture_output=True, text=True,
                          env={**os.environ, "PYTHONPATH": os.getcwd()})
    assert proc.returncode != 0
    assert f"cannot write out_dir {tmp_path / 'ro' / 'g'} (its parent {tmp_path / 'ro'}): on a read-only file system" \
        in proc.stderr, proc.stderr


def test_file_lock_refuses_a_second_writer_of_one_file(tmp_path):
    target = tmp_path / "results.json"
    with io.OutputLock.for_file(target, "eval"):
        with pytest.raises(io.LockedError, match=r"results.json is in use by another eval run \(pid \d+"):
            io.OutputLock.for_file(target, "eval").acquire()
        with io.OutputLock.for_file(tmp_path / "other.json", "eval"):
            pass  # another file of the same folder is free
    assert sorted(p.name for p in tmp_path.iterdir()) == [], "the lock file was left behind"


@pytest.mark.parametrize("target, message", [
    ("file/sub/a.json", "cannot write {d}/file/sub/a.json: {d}/file is a file, not a folder"),
    ("folder", "cannot write {d}/folder: it is a folder; expected a file"),
    ("n" * 300 + "/a.json", "cannot write {d}/" + "n" * 300 + "/a.json: the path, or a name in it, is longer than "
                            "the file system allows"),
])
def test_a_path_that_cannot_be_written_is_named(tmp_path, target, message):
    """A file where a folder belongs, a folder where the file belongs, a name over the file system's 255 bytes:
    one user error naming the path (each was an OSError without it, or with only its errno), no temporary file."""
    (tmp_path / "file").write_text("x")
    (tmp_path / "folder").mkdir()
    with pytest.raises(io.BadPathError) as info:
        io.write_json(tmp_path / target, {})
    assert str(info.value) == message.format(d=tmp_path)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file", "folder"]


def test_check_writable_names_a_path_too_long(tmp_path):
    with pytest.raises(io.BadPathError, match=rf"^cannot write out_dir {tmp_path}/nnn+: the path, or a name in it, is "
                                              "longer than the file system allows$"):
        io.check_writable(tmp_path / ("n" * 300), "out_dir")


def test_writing_names_the_path_and_the_fix_and_lets_other_errors_through(tmp_path):
    (tmp_path / "file").write_text("x")
    with pytest.raises(io.BadPathError, match=r"^cannot write the cache .*/file/c: .*/file is a file, not a folder; "
                                              r"set cache_dir$"):
        with io.writing(tmp_path / "file" / "c", "the cache", fix="set cache_dir") as folder:
            folder.mkdir(parents=True)
    with pytest.raises(FileNotFoundError) as info:  # a reader's error is not the output's
        with io.writing(tmp_path / "out"):
            (tmp_path / "missing").read_text()
    assert type(info.value) is FileNotFoundError


def test_the_lock_of_a_folder_that_is_a_file_names_the_folder(tmp_path):
    (tmp_path / "run").write_text("x")
    with pytest.raises(io.BadPathError, match=r"^cannot write .*/run: it is a file; expected a folder$"):
        io.OutputLock(tmp_path / "run", "training").acquire()


def test_atomic_folder_replaces_only_a_complete_build(tmp_path):
    """A build that fails leaves the folder it would replace as it was and no stage beside it; one that
    completes replaces it whole."""
    out = tmp_path / "out"
    out.mkdir()
    (out / "old.txt").write_text("old")
    with pytest.raises(KeyError):
        with io.atomic_folder(out) as stage:
            (stage / "new.txt").write_text("half")
            raise KeyError("a frame failed")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]
    assert sorted(p.name for p in out.iterdir()) == ["old.txt"]
    with io.atomic_folder(out) as stage:
        assert stage.parent == tmp_path and stage != out
        (stage / "new.txt").write_text("whole")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]
    assert [(p.name, p.read_text()) for p in out.iterdir()] == [("new.txt", "whole")]


def test_atomic_folder_names_a_file_in_its_way(tmp_path):
    (tmp_path / "out").write_text("a file")
    with pytest.raises(io.BadPathError, match=r"^cannot write .*/out: it is a file; expected a folder$"):
        with io.atomic_folder(tmp_path / "out") as stage:
            (stage / "a.txt").write_text("x")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"] and (tmp_path / "out").read_text() == "a file"
