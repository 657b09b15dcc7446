"""Dataset generation on Ray actors: same bytes as the local launcher, resumable, robust to a dying actor."""

import logging
import os
import re
import signal
import sys
import threading
import time

import numpy as np
import pytest

from hupbench.datagen.dataset.spec import DatasetSpec
from hupbench.datagen.dataset.writer import GenerateRun, generate
from hupbench.datagen.dataset.ray_launcher import RAY_MISSING, RayOptions
from hupbench.datagen.dataset.verify import verify
from hupbench.cli import main
from hupbench.config import compose
from hupbench.verbs.generate import run_generate

from helpers.datasets import TINY_SPEC as TINY, annotations, write_grasps  # noqa: E402  (tests/ is on sys.path)

#: one grasp, 2 chunks of 10 frames: the smallest dataset that gives two actors a chunk each
ONE_GRASP = {"splits": {"train": 1, "val": 0, "test": 0}}
#: 4 backgrounds: 8 chunks of 10 frames, enough to kill an actor while chunks are queued on it
FOUR_BACKGROUNDS = {"n_backgrounds": 4}


def run(out, grasps, launcher, spec=(), log=lambda *_: None, **job):
    spec = DatasetSpec(**{**TINY, **dict(spec)})
    return generate(GenerateRun(spec, out, grasps, progress=False, launcher=launcher, **job), {"test": "ray"}, log=log)


def files(root):
    """{relative path: bytes} of every file of a finished dataset."""
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def ray_runtime():
    """One private Ray runtime for the module (start-up takes seconds); the launcher reuses it."""
    ray = pytest.importorskip("ray")
    ray.init(address="local", num_cpus=2, include_dashboard=False, logging_level=logging.ERROR,
             log_to_driver=False, object_store_memory=128 * 1024**2)
    yield
    ray.shutdown()


@pytest.fixture(scope="module")
def local_reference(tmp_path_factory):
    root = tmp_path_factory.mktemp("ray_ref")
    grasps = write_grasps(root / "grasps_in.npz", n=1)
    run(root / "local", grasps, "local", spec=ONE_GRASP)
    return root, grasps


def test_missing_ray_fails_before_rendering_with_install_hint(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "ray", None)  # makes `import ray` raise ImportError
    out = tmp_path / "ds"
    with pytest.raises(RuntimeError, match=re.escape(RAY_MISSING)):
        run_generate(compose("generate", [f"out_dir={out}", "launcher=ray"]), log=lambda *_: None)
    assert not out.exists()  # no grasps synthesised, nothing rendered
    assert main(["generate", f"out_dir={out}", "launcher=ray"]) == 1
    assert capsys.readouterr().err.strip() == f"hupbench generate: error: {RAY_MISSING}"
    with pytest.raises(RuntimeError, match=re.escape(RAY_MISSING)):
        run(tmp_path / "direct", write_grasps(tmp_path / "g.npz"), "ray")


@pytest.mark.parametrize("override, message", [
    ("launcher=slurm", "launcher must be one of \\('local', 'ray'\\), got 'slurm'"),
    ("ray.num_workers=0", "ray.num_workers must be a whole number >= 1 or null, got 0"),
    ("ray.cpus_per_worker=-1", "ray.cpus_per_worker must be a positive number, got -1"),
    ("ray.max_retries=-2", "ray.max_retries must be a whole number >= 0, got -2"),
    ("ray.actor_restarts=1.5", "ray.actor_restarts must be a whole number >= 0, got 1.5"),
])
def test_bad_launcher_config_fails_before_rendering(tmp_path, override, message):
    out = tmp_path / "ds"
    with pytest.raises(ValueError, match=message):
        run_generate(compose("generate", [f"out_dir={out}", override]), log=lambda *_: None)
    assert not (out / "grasps").exists() and not (out / "train").exists()


def test_ray_dataset_is_byte_identical_to_the_local_one(ray_runtime, local_reference):
    root, grasps = local_reference
    lines = []
    result = run(root / "ray", grasps, "ray", spec=ONE_GRASP, log=lines.append, ray=RayOptions(num_workers=2))
    assert result["complete"] and result["frames_rendered"] == 20 and result["counts"]["train"] == 20
    assert sum(line.startswith("ray actor ") for line in lines) == 2
    local, on_ray = files(root / "local"), files(root / "ray")
    assert sorted(local) == sorted(on_ray)
    assert {"train/annotations.npz", "train/rgb/000019.jpg", "train/depth/000019.png", "manifest.json"} <= set(local)
    assert [p for p in local if local[p] != on_ray[p]] == []  # annotations, images and manifest
    assert verify(root / "ray", workers=1, log=lambda *_: None)["ok"]


@pytest.mark.slow
def test_a_local_run_cut_short_is_completed_by_a_ray_run(ray_runtime, local_reference):
    root, grasps = local_reference
    out = root / "mixed"
    first = run(out, grasps, "local", spec=ONE_GRASP, shard="0/2")
    assert not first["complete"] and first["frames_rendered"] == 10
    second = run(out, grasps, "ray", spec=ONE_GRASP, ray=RayOptions(num_workers=1))
    assert second["complete"] and second["frames_rendered"] == 10  # only the missing chunk
    local, mixed = files(root / "local"), files(out)
    assert [p for p in local if local[p] != mixed.get(p)] == []


@pytest.mark.slow
@pytest.mark.parametrize("actor_restarts", [2, 0], ids=["ray_restarts_actor", "chunk_goes_to_fresh_actor"])
def test_killing_an_actor_mid_run_loses_and_duplicates_nothing(ray_runtime, tmp_path, actor_restarts):
    grasps = write_grasps(tmp_path / "grasps_in.npz")
    reference = run(tmp_path / "reference", grasps, "local", spec=FOUR_BACKGROUNDS)
    assert reference["frames_rendered"] == 80
    out, lines, outcome = tmp_path / "killed", [], {}

    def driver():
        outcome["result"] = run(out, grasps, "ray", spec=FOUR_BACKGROUNDS, log=lines.append,
                                ray=RayOptions(num_workers=2, actor_restarts=actor_restarts))

    thread = threading.Thread(target=driver)
    thread.start()
    deadline = time.time() + 240
    # kill one actor (SIGKILL, as the kernel's OOM killer would) once the first chunk is written,
    # while further chunks are queued on both actors
    while time.time() < deadline and not list(out.glob("*/.chunks/[!.]*.npz")):  # not a temporary file
        time.sleep(0.05)
    pids = [int(m.group(1)) for m in (re.match(r"ray actor \d+: pid (\d+)", line) for line in lines) if m]
    assert len(pids) == 2, lines
    os.kill(pids[0], signal.SIGKILL)
    thread.join(timeout=300)
    assert not thread.is_alive()
    result = outcome["result"]
    # without restarts the launcher itself replaces the actor and hands its chunks on
    assert any(line.startswith("ray actor 0 died") for line in lines) == (actor_restarts == 0), lines
    # every chunk written exactly once: 80 frames, not fewer (lost) and not more (rendered twice)
    assert result["complete"] and result["frames_rendered"] == 80
    assert result["counts"] == {"train": 40, "val": 0, "test": 40}
    assert verify(out, workers=1, log=lambda *_: None)["ok"]
    a, b = annotations(tmp_path / "reference"), annotations(out)
    for split in a:
        for key in a[split]:
            np.testing.assert_array_equal(a[split][key], b[split][key], err_msg=key)
    ref_files, killed_files = files(tmp_path / "reference"), files(out)
    assert [p for p in ref_files if ref_files[p] != killed_files.get(p)] == []
    assert not list(out.glob("*/*/.*.tmp*"))
