"""Faults of `hupbench generate` (docs/robustness.md, ## generate): workers that die with their parent,
one run per output folder, SIGKILL at random points then the same command, a full disk."""

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from helpers.cli import assert_clean_error, run_cli  # noqa: E402  (tests/ is on sys.path)
from helpers.datasets import write_grasps  # noqa: E402  (tests/ is on sys.path)
from helpers import REPO

#: helpers.datasets.TINY_SPEC as `hupbench generate` overrides (64 px, 10 views, chunks of 10 frames)
TINY_OVERRIDES = ["dataset.splits={train:1,val:0,test:1}", "dataset.z_ego_m=[0.5]", "dataset.n_backgrounds=2",
                  "dataset.n_gloves=1", "dataset.sphere.r_circ_m=0.4", "dataset.sphere.exclude=[poles]",
                  "dataset.width=64", "dataset.height=64", "dataset.fx=120.0", "dataset.fy=120.0",
                  "dataset.cx=32.0", "dataset.cy=32.0", "progress=false"]


def generate_argv(out, grasps, *overrides):
    return [sys.executable, "-m", "hupbench.cli", "generate", f"out_dir={out}", f"grasps_path={grasps}",
            *TINY_OVERRIDES, *overrides]


def env():
    return {**os.environ, "PYTHONPATH": str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", "")}


def children(pid):
    """Pids whose parent is ``pid`` (from /proc)."""
    out = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            out.append(int(stat.parent.name))
    return out


def running(pid):
    """Alive and not a zombie."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def snapshot(folder):
    """{relative path: (size, mtime_ns)} of every file under ``folder``."""
    out = {}
    for p in Path(folder).rglob("*"):
        try:
            st = p.stat()
        except FileNotFoundError:
            continue
        if p.is_file():
            out[p.relative_to(folder).as_posix()] = (st.st_size, st.st_mtime_ns)
    return out


@pytest.fixture(scope="module")
def grasps(tmp_path_factory):
    return write_grasps(tmp_path_factory.mktemp("fault_grasps") / "grasps.npz", n=2)


def wait_for(predicate, timeout_s, what):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return
        time.sleep(0.02)
    raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")


@pytest.mark.matrix
@pytest.mark.slow  # 27 s here; test_die_with_parent_prctl_and_watchdog keeps both mechanisms in the default set, and
# CI under 20 minutes
def test_fault_generate_workers_die_with_parent(tmp_path, grasps, capsys):
    """SIGKILL of generate's main process: its worker processes exit within 2 s and write nothing after.
    While it runs, a second generate on its folder is refused, naming it."""
    out = tmp_path / "ds"
    # the default sphere (90 views): chunks of 90 frames, seconds each, so that the other worker is
    # mid-chunk when the first chunk lands (a worker used to finish its chunk, write it, then exit)
    proc = subprocess.Popen(generate_argv(out, grasps, "workers=2", "dataset.sphere.r_circ_m=0.15",
                                          "dataset.sphere.exclude=[elbow]"), env=env(),
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        wait_for(lambda: list(out.glob("*/.chunks/[!.]*.npz")), 180, "the first chunk")  # not a temporary file
        workers = children(proc.pid)
        assert len(workers) >= 2, workers  # two workers (and multiprocessing's resource tracker)
        answer = run_cli(capsys, *cli_argv(out, grasps))
        assert_clean_error(answer, str(out), f"pid {proc.pid}", socket.gethostname(), "in use")
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
        killed_at = time.monotonic()
        wait_for(lambda: not any(running(w) for w in workers), 2.0, f"workers {workers} to exit")
        print(f"workers gone {time.monotonic() - killed_at:.2f} s after the kill")
        before = snapshot(out)
        time.sleep(2.0)
        assert snapshot(out) == before, "files changed after the workers should have died"
        assert not (out / "manifest.json").exists()
    finally:
        if proc.poll() is None:
            proc.kill()
        for pid in children(proc.pid):
            os.kill(pid, signal.SIGKILL)


@pytest.mark.parametrize("platform", ["linux", "other"])
def test_die_with_parent_prctl_and_watchdog(tmp_path, platform):
    """A process that called die_with_parent(ppid) is gone soon after its parent is SIGKILLed, by the
    kernel's parent-death signal on Linux and by the watchdog thread elsewhere."""
    child_code = (f"import sys, time; sys.path.insert(0, {str(REPO)!r}); import os; "
                  "from hupbench.datagen.dataset.chunks import die_with_parent; "
                  f"sys.platform = {'linux' if platform == 'linux' else 'darwin'!r}; die_with_parent(os.getppid()); "
                  f"open({str(tmp_path / 'ready')!r}, 'w').close(); time.sleep(60)")
    parent_code = f"import subprocess, sys, time; subprocess.Popen([sys.executable, '-c', {child_code!r}]); time.sleep(60)"
    parent = subprocess.Popen([sys.executable, "-c", parent_code])
    try:
        wait_for(lambda: (tmp_path / "ready").exists() or parent.poll() is not None, 60, "the child")
        (child,) = children(parent.pid)
        os.kill(parent.pid, signal.SIGKILL)
        parent.wait()
        wait_for(lambda: not running(child), 2.0, "the child to exit")
    finally:
        if parent.poll() is None:
            parent.kill()


def hold_lock(folder, what="generate"):
    """A process holding an OutputLock on ``folder`` until killed (what a generate run holds)."""
    code = (f"import sys, time; sys.path.insert(0, {str(REPO)!r}); from hupbench.core.io import OutputLock; "
            f"OutputLock({str(folder)!r}, {what!r}).acquire(); print('held', flush=True); time.sleep(120)")
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "held"
    return proc


def cli_argv(out, grasps, *overrides):
    return ["generate", f"out_dir={out}", f"grasps_path={grasps}", *TINY_OVERRIDES, "workers=1", *overrides]


@pytest.mark.matrix
def test_fault_generate_second_run_on_a_folder(tmp_path, grasps, capsys):
    """A live run's lock refuses a second run (one line naming its pid and host); once the holder
    is killed, the same command takes the stale lock over and finishes."""
    out = tmp_path / "ds"
    holder = hold_lock(out)
    try:
        answer = run_cli(capsys, *cli_argv(out, grasps))
        line = assert_clean_error(answer, str(out), f"pid {holder.pid}", socket.gethostname(), "in use")
        assert line.startswith("hupbench generate: error:")
        assert sorted(p.name for p in out.iterdir()) == [".hupbench.lock"]  # nothing written by the refused run
    finally:
        holder.kill()
        holder.wait()
    answer = run_cli(capsys, *cli_argv(out, grasps))
    assert answer.rc == 0, answer
    assert f"took over the lock of a generate run that is gone (pid {holder.pid}" in answer.out
    assert "dataset complete" in answer.out and (out / "manifest.json").is_file()
    assert not (out / ".hupbench.lock").exists() and not list(out.rglob(".*.tmp*"))


@pytest.mark.matrix
def test_fault_generate_shards_and_locks(tmp_path, grasps, capsys):
    """Shards of one dataset run side by side (a lock each); an unsharded run is refused while a shard
    runs, and a shard while an unsharded run holds the folder; the last shard finishes the dataset."""
    out = tmp_path / "ds"
    holder = hold_lock(out / ".locks" / "shard-1-of-2", "generate shard 1/2")
    try:
        answer = run_cli(capsys, *cli_argv(out, grasps, "shard=0/2"))
        assert answer.rc == 0 and "partial (other shards pending)" in answer.out, answer
        answer = run_cli(capsys, *cli_argv(out, grasps))
        assert_clean_error(answer, "shard-1-of-2", f"pid {holder.pid}", "generate shard 1/2")
        answer = run_cli(capsys, *cli_argv(out, grasps, "shard=1/2"))
        assert_clean_error(answer, "shard-1-of-2", f"pid {holder.pid}")
    finally:
        holder.kill()
        holder.wait()
    unsharded = hold_lock(out)
    try:
        answer = run_cli(capsys, *cli_argv(out, grasps, "shard=1/2"))
        assert_clean_error(answer, str(out), f"pid {unsharded.pid}", "in use")
    finally:
        unsharded.kill()
        unsharded.wait()
    answer = run_cli(capsys, *cli_argv(out, grasps, "shard=1/2"))
    assert answer.rc == 0 and "dataset complete" in answer.out, answer
    assert not (out / ".locks").exists() and not (out / ".hupbench.lock").exists()
    assert not list(out.rglob(".*.tmp*"))


def dataset_files(root):
    """{relative path: bytes} of every file of a dataset folder."""
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(Path(root).rglob("*")) if p.is_file()}


def comparable_manifest(data: bytes) -> dict:
    """A manifest without what differs between two runs of one config: the out_dir, the time and the
    number of workers (which does not change a byte of the frames)."""
    manifest = json.loads(data)
    for key in ("out_dir", "workers"):
        manifest["config"].pop(key)
    manifest["config"]["_provenance"].pop("time_utc")
    return manifest


def assert_same_dataset(out, reference):
    """Every file of ``out`` has the bytes of ``reference``'s (the manifest up to out_dir, time and
    workers), and no scaffolding is left."""
    ours, theirs = dataset_files(out), dataset_files(reference)
    assert sorted(ours) == sorted(theirs), sorted(set(ours) ^ set(theirs))
    different = [name for name in ours if name != "manifest.json" and ours[name] != theirs[name]]
    assert not different, different
    assert comparable_manifest(ours["manifest.json"]) == comparable_manifest(theirs["manifest.json"])
    assert not list(Path(out).rglob(".*.tmp*")) and not (Path(out) / ".hupbench.lock").exists()


def kill(proc, until, poll_s=0.02):
    """SIGKILL ``proc`` when ``until()`` is true (or it ended by itself); wait for its children to exit.

    Returns:
        Whether it had finished by itself.
    """
    pids = set()
    while not until() and proc.poll() is None:
        pids.update(children(proc.pid))
        time.sleep(poll_s)
    finished = proc.poll() is not None
    proc.kill()   # SIGKILL; nothing when poll() has reaped it already (its pid may be gone: os.kill raised there)
    proc.wait()
    # a worker killed while it starts (importing) dies when its start-up ends, before rendering
    wait_for(lambda: not any(running(p) for p in pids), 30.0, f"the workers {sorted(pids)} to exit")
    return finished


@pytest.mark.matrix
@pytest.mark.slow  # 22 s; the default set kills and resumes generate in test_generate.py and test_clinic.py
def test_fault_generate_sigkill_once(tmp_path, grasps, capsys):
    """SIGKILL after a seeded random number of files written (any phase: start-up, chunks, annotations,
    manifest), then the same dataset again: the uninterrupted run's bytes, no temporary file."""
    reference, out = tmp_path / "reference", tmp_path / "ds"
    assert run_cli(capsys, *cli_argv(reference, grasps)).rc == 0
    n_files = len(dataset_files(reference)) + 4 + 2  # + the chunk marks, the progress file and the annotations
    target = int(np.random.default_rng(3).integers(0, n_files))
    proc = subprocess.Popen(generate_argv(out, grasps, "workers=2"), env=env(), stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    finished = kill(proc, lambda: len(snapshot(out)) > target if out.exists() else target < 0)
    assert not finished and not (out / "manifest.json").exists()
    answer = run_cli(capsys, *cli_argv(out, grasps))
    assert answer.rc == 0 and "dataset complete" in answer.out, answer
    assert_same_dataset(out, reference)


@pytest.mark.matrix
def test_fault_generate_killed_after_the_manifest(tmp_path, grasps, capsys):
    """A run killed between the manifest and the clean-up left chunk rows, the progress file and a
    temporary file: the same command removes them and the dataset is the uninterrupted run's."""
    reference, out = tmp_path / "reference", tmp_path / "ds"
    assert run_cli(capsys, *cli_argv(reference, grasps)).rc == 0
    shutil.copytree(reference, out)
    (out / "train" / ".chunks").mkdir()
    (out / "train" / ".chunks" / "00000.npz").write_bytes(b"rows")
    (out / ".progress.json").write_text("{}")
    (out / "test" / "rgb" / ".000020.jpg.tmp999999").write_bytes(b"half")
    answer = run_cli(capsys, *cli_argv(out, grasps))
    assert answer.rc == 0 and "dataset complete" in answer.out, answer
    # the manifest is the reference's copy: compare it as it is
    assert dataset_files(out) == dataset_files(reference)


def kill_and_resume(tmp_path, grasps, seed, kills, overrides=("workers=2",)):
    """Run the same `hupbench generate` command ``kills`` times, each SIGKILLed after a seeded delay
    drawn over an uninterrupted run's duration, then once to the end; compare with the uninterrupted run."""
    reference, out = tmp_path / "reference", tmp_path / "ds"
    start = time.monotonic()
    subprocess.run(generate_argv(reference, grasps, *overrides), env=env(), check=True, capture_output=True)
    duration = time.monotonic() - start
    rng = np.random.default_rng(seed)
    seen = []
    for delay in rng.uniform(0.2, duration, size=kills):
        proc = subprocess.Popen(generate_argv(out, grasps, *overrides), env=env(), stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL)
        deadline = time.monotonic() + delay
        finished = kill(proc, lambda: time.monotonic() >= deadline)
        seen.append({"delay_s": round(float(delay), 2), "finished": finished,
                     "manifest": (out / "manifest.json").exists(),
                     "tmp": sorted(p.name for p in out.rglob(".*.tmp*")) if out.exists() else []})
    final = subprocess.run(generate_argv(out, grasps, *overrides), env=env(), capture_output=True, text=True)
    assert final.returncode == 0, (final.stderr[-3000:], seen)
    assert "dataset complete" in final.stdout
    assert_same_dataset(out, reference)
    return seen


@pytest.mark.matrix
@pytest.mark.slow
def test_fault_generate_sigkill_random_points(tmp_path, grasps):
    """Four SIGKILLs in a row at seeded random points of the same command, then the command to its end."""
    print(kill_and_resume(tmp_path, grasps, seed=15, kills=4))


def in_small_tmpfs(mount, size, script):
    """Run a shell ``script`` with a ``size`` tmpfs on ``mount``, in a private mount namespace (root only).

    Returns:
        The CompletedProcess; the test is skipped where the namespace or the mount cannot be made.
    """
    if shutil.which("unshare") is None:
        pytest.skip("unshare(1) is not installed")
    mount.mkdir(parents=True, exist_ok=True)
    probe = subprocess.run(["unshare", "-m", "--propagation", "private", "sh", "-c",
                            f"mount -t tmpfs -o size={size} tmpfs {mount}"], capture_output=True, text=True)
    if probe.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs in a private mount namespace here (not root?): {probe.stderr.strip()}")
    return subprocess.run(["unshare", "-m", "--propagation", "private", "sh", "-c",
                           f"mount -t tmpfs -o size={size} tmpfs {mount} && {script}"],
                          capture_output=True, text=True, env=env(), timeout=600)


@pytest.mark.matrix
# two workers (34 s, beside one worker's 24 s) run with the slow tests: CI keeps under 20 minutes
@pytest.mark.parametrize("workers", [1, pytest.param(2, marks=pytest.mark.slow)])
def test_fault_generate_full_disk(tmp_path, grasps, workers):
    """A 96 KiB disk fills while the chunks are written: one line 'no space left on MOUNT writing FILE',
    exit 1, no manifest, no temporary file; with room (the same tmpfs made larger), the same command
    finishes the dataset."""
    import shlex

    mount = tmp_path / "small"
    argv = " ".join(shlex.quote(a) for a in generate_argv(mount / "ds", grasps, f"workers={workers}"))
    script = (f"{argv}; echo rc=$?; find {mount} -name '.*.tmp*' | sed 's/^/tmp: /'; "
              f"test -e {mount}/ds/manifest.json && echo 'manifest: yes'; "
              f"mount -o remount,size=64m {mount} && {argv} > /dev/null 2>&1; echo rc2=$?; "
              f"test -e {mount}/ds/manifest.json && echo 'manifest2: yes'; "
              f"find {mount} -name '.*.tmp*' | sed 's/^/tmp2: /'")
    proc = in_small_tmpfs(mount, "96k", script)
    assert proc.returncode == 0, proc.stderr[-3000:]
    lines = proc.stdout.splitlines()
    assert "rc=1" in lines, proc
    errors = [line for line in proc.stderr.splitlines() if "error:" in line]
    assert len(errors) == 1 and "Traceback" not in proc.stderr, proc.stderr[-3000:]
    assert errors[0].startswith(f"hupbench generate: error: no space left on {mount} writing {mount}/ds/"), errors
    assert not [line for line in lines if line.startswith(("tmp:", "manifest:"))], lines
    assert "rc2=0" in lines and "manifest2: yes" in lines, lines
    assert not [line for line in lines if line.startswith("tmp2:")], lines
