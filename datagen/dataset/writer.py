"""Dataset generation: Algorithm 1 of HUP-3D, written to the dataset contract of DESIGN.md.

Frames are the product grasps x z_ego x backgrounds x gloves x viewpoints.
The frame index is the mixed-radix number of that tuple, viewpoints fastest:

    i = (((grasp * n_z + z) * n_bg + bg) * n_glove + glove) * n_view + view

and frame ``i`` is a pure function of (config, i): its camera comes from the
sphere, its lamp from a generator seeded with (seed, i). Frames are rendered
in chunks of one (grasp, z_ego, background) block (n_glove x n_view frames
sharing the meshes); a chunk's image files are written atomically, then its
annotation rows, also atomically: a chunk whose rows exist is done, any
other is rendered again on resume (overwriting, never duplicating).
``shard=k/n`` renders only the chunks ``c`` with ``c % n == k``. Chunks are
rendered by :class:`datagen.dataset.chunks.ChunkRenderer`, in local worker processes or on Ray actors
(:mod:`datagen.dataset.ray_launcher`), and written by :func:`datagen.dataset.chunks.write_chunk`. When every
chunk is done the rows are merged into ``<split>/annotations.npz`` and
``manifest.json`` is written last.

Convention:
    Annotations are in the OpenCV camera frame, metres; 2D in pixels of the
    stored image. World = probe frame.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import multiprocessing
import os
import shutil
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Iterator

import numpy as np

from datagen.dataset.contract import ANNOTATION_DTYPES, DEPTH_SCALE_M, SCHEMA_VERSION, SPLITS
from datagen.dataset.grasps_file import GraspSet
from datagen.dataset.ray_launcher import RayOptions, check_launcher
from datagen.dataset.floors import DEFINITION as FLOORS_DEFINITION, split_floors
from datagen.dataset.spec import (DatasetSpec, GENERATOR_VERSION, Layout, chunk_plan, protocol, split_of_grasps,
                                  split_of_views, view_directions_arm)
from datagen.dataset.sphere import viewpoints
from datagen.io import TMP_PATTERN, DiskFullError, LockedError, OutputLock, save_npz, write_json, write_with
from datagen.processes import check_workers as check_processes
from datagen.render.renderer import SEG_LABELS
from datagen.render.scene import ARM_RGB, GLOVE_RGB
from datagen.render import gl
from datagen import keypoints as kp
from datagen.input_checks import check_int
from datagen.dataset.chunks import (
    ChunkOutput,
    _WorkerDiskFull,
    _chunk_path,
    _render_chunk,
    _render_chunk_in_worker,
    _worker_init,
    write_chunk,
)
from datagen.errors import BadTypeError, BadValueError


@dataclass(frozen=True)
class SplitPlan:
    """Which grasps (indices into the grasps file) and views (positions in the sphere's view list) each
    split holds; a frame is in the split that holds both its grasp and its view."""

    grasps: dict[str, list[int]]
    views: dict[str, list[int]]


def config_hash(resolved: dict) -> str:
    """sha256 of the resolved config with the keys that do not change frames removed."""
    keep = {k: v for k, v in resolved.items()
            if k not in ("workers", "shard", "out_dir", "progress", "launcher", "ray", "_provenance")}
    return hashlib.sha256(json.dumps(keep, sort_keys=True, default=str).encode()).hexdigest()


def check_output_dir(out_dir: Path) -> None:
    """Fail early (before rendering) if the output folder cannot be written."""
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise BadValueError(f"out_dir {out_dir} is a file, not a folder")
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
        probe_file = out_dir / f".write_test.tmp{os.getpid()}"  # a temporary name: a killed run's is cleaned
        probe_file.write_bytes(b"")
        probe_file.unlink()
    except OSError as exc:
        raise BadValueError(f"output path {out_dir} is not writable: {exc.strerror or exc}") from exc


def parse_shard(shard: str | None) -> tuple[int, int]:
    """"k/n" -> (k, n) with 0 <= k < n; None -> (0, 1)."""
    if shard in (None, "", "0/1"):
        return 0, 1
    try:
        k, n = (int(x) for x in str(shard).split("/"))
    except ValueError as exc:
        raise BadValueError(f"shard must look like k/n (e.g. 0/4), got {shard!r}") from exc
    if not (n >= 1 and 0 <= k < n):
        raise BadValueError(f"shard {shard!r}: need 0 <= k < n")
    return k, n


LOCKS_DIR = ".locks"


def shard_lock_folder(out_dir: Path, k: int, n: int) -> Path:
    """Where shard ``k/n`` of a dataset keeps its lock (an unsharded run locks ``out_dir`` itself)."""
    return Path(out_dir) / LOCKS_DIR / f"shard-{k}-of-{n}"


@contextlib.contextmanager
def run_lock(out_dir: Path, shard: str | None = None) -> Iterator[OutputLock]:
    """Hold the output folder for one generate run (see :class:`datagen.io.OutputLock`).

    An unsharded run holds ``out_dir`` itself and refuses to start while a shard run is live there.
    Shard ``k/n`` holds its own lock, so that several machines can render the shards of one dataset
    into one (shared) folder at once, and refuses to start while an unsharded run holds the folder;
    the shard that finds every chunk done takes the folder's lock to write the annotations and the
    manifest.

    Raises:
        LockedError: another live run holds what this one needs; the message names its pid and host.
    """
    out_dir = Path(out_dir)
    k, n = parse_shard(shard)
    if n == 1:
        with OutputLock(out_dir, "generate") as lock:
            for folder in sorted((out_dir / LOCKS_DIR).glob("shard-*")):
                with OutputLock(folder, "generate"):  # a live shard's lock raises; a dead one's is removed
                    pass
            yield lock
    else:
        with OutputLock(shard_lock_folder(out_dir, k, n), f"generate shard {k}/{n}") as lock:
            with OutputLock(out_dir, "generate"):  # an unsharded run on the folder raises
                pass
            yield lock
    if (out_dir / "manifest.json").is_file():
        _remove_lock_folders(out_dir)


def _remove_lock_folders(out_dir: Path) -> None:
    """Remove the empty shard-lock folders of a finished dataset (a live shard's stays)."""
    for folder in sorted((out_dir / LOCKS_DIR).glob("shard-*")):
        with contextlib.suppress(OSError):
            folder.rmdir()
    with contextlib.suppress(OSError):
        (out_dir / LOCKS_DIR).rmdir()


def _remove_all_tmp(out_dir: Path) -> list[Path]:
    """Remove every temporary file (:data:`datagen.io.TMP_PATTERN`) under ``out_dir``.

    Only called while this run holds the folder and no worker of it is running: every such file
    is then the remains of a killed writer, whatever its pid (a pid can be reused, or belong to
    another machine sharing the folder).
    """
    removed = []
    for path in out_dir.rglob(".*.tmp*"):
        if TMP_PATTERN.match(path.name) and path.is_file():
            path.unlink(missing_ok=True)
            removed.append(path)
    return removed


def _remove_tmp_of(out_dir: Path, pids: set[int] | None) -> None:
    """After a failed run: remove the temporary files of ``pids`` (None: all of them, for a run that
    holds the whole folder). The write that failed removed its own; the workers stopped with it
    may have been in the middle of one."""
    for path in out_dir.rglob(".*.tmp*"):
        match = TMP_PATTERN.match(path.name)
        if match and (pids is None or int(match.group(1)) in pids):
            path.unlink(missing_ok=True)


def _file_digest(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def check_workers(workers, launcher: str = "local") -> None:
    """Refuse a worker count that is not a whole number >= 1, or, for the local launcher, more processes
    than :func:`datagen.processes.check_workers` allows (Ray actors may live on other machines)."""
    if launcher == "local":
        check_processes(workers)
    else:
        check_int(workers, "workers", low=1)


def generate(spec: DatasetSpec, out_dir: Path, grasps_path: Path, resolved_config: dict,
             backgrounds_dir: str | None = None, workers: int = 1, shard: str | None = None,
             platform: str | None = None, progress: bool = True, log=print, launcher: str = "local",
             ray: RayOptions | None = None, lock: OutputLock | None = None) -> dict:
    """Render (or resume) a dataset. See the module docstring for the layout and the guarantees.

    Everything is checked before anything is written; then the run holds the output folder
    (:func:`run_lock`) until it returns, removes the temporary files of killed runs, and renders
    what is missing.

    Args:
        launcher: "local" renders in ``workers`` processes on this machine; "ray" on Ray actors
            (:mod:`datagen.dataset.ray_launcher`, options in ``ray``). Both write the same files.
        ray: :class:`datagen.dataset.ray_launcher.RayOptions` (None: the defaults, a private runtime
            with ``workers`` actors).
        lock: the lock of this run when the caller already holds it (``with run_lock(out_dir,
            shard) as lock``); None takes it here.

    Returns:
        dict with "out_dir", "frames_total", "frames_rendered" (this run), "seconds",
        "complete" (manifest written) and "counts" per split.

    Raises:
        LockedError: another live generate run holds the folder (or this shard).
    """
    from datagen.assets.backgrounds import BackgroundSet
    check_launcher(launcher)
    if ray is not None and not isinstance(ray, RayOptions):
        raise BadTypeError(f"ray must be a RayOptions or None, got {type(ray).__name__}")
    if not isinstance(spec, DatasetSpec):
        raise BadTypeError(f"spec must be a DatasetSpec, got {type(spec).__name__}")
    out_dir = Path(out_dir)
    k, n = parse_shard(shard)
    check_workers(workers, launcher)
    if platform is not None and platform not in gl.PLATFORMS:
        raise BadValueError(f"render.platform must be one of {', '.join(gl.PLATFORMS)} or null (automatic), "
                         f"got {platform!r}")
    if not isinstance(progress, bool):
        raise BadValueError(f"progress must be true or false, got {progress!r}")
    backgrounds = BackgroundSet.from_dir(backgrounds_dir) if backgrounds_dir else BackgroundSet.builtin()
    if len(backgrounds) < spec.n_backgrounds:
        raise BadValueError(f"dataset.n_backgrounds={spec.n_backgrounds} but the background set holds only "
                         f"{len(backgrounds)} image(s)" + (f" ({backgrounds_dir})" if backgrounds_dir else ""))
    check_output_dir(out_dir)
    grasps = GraspSet(grasps_path)
    view_ids, _ = viewpoints(spec.sphere)
    layout = Layout(len(grasps), len(spec.z_ego_m), spec.n_backgrounds, spec.n_gloves, len(view_ids))
    splits = SplitPlan(split_of_grasps(spec, len(grasps)), split_of_views(spec, len(view_ids)))
    chash = config_hash(resolved_config)
    with contextlib.ExitStack() as stack:
        if lock is None:
            lock = stack.enter_context(run_lock(out_dir, shard))
        elif lock.folder.resolve() != (out_dir if n == 1 else shard_lock_folder(out_dir, k, n)).resolve():
            raise BadValueError(f"the lock given holds {lock.folder}, not this run's folder {out_dir} (shard {k}/{n})")
        if lock.taken_over:
            log(f"took over the lock of a generate run that is gone (pid {lock.taken_over.get('pid')} on "
                f"{lock.taken_over.get('host')})")
        result = _generate_locked(spec, out_dir, Path(grasps_path), grasps, splits, layout, chash, resolved_config,
                                  backgrounds, backgrounds_dir, workers, k, n, platform, progress, log, launcher,
                                  ray, stack)
    return result


def _start_or_resume(out_dir: Path, grasps_path: Path, layout: Layout, chash: str) -> None:
    """Record a new run's config hash in ``.progress.json``, or check that a partial dataset here was
    started with this config and these grasps; copy the grasps into the dataset."""
    progress_file = out_dir / ".progress.json"
    if progress_file.is_file():
        try:
            started = json.loads(progress_file.read_text())
        except ValueError as exc:
            raise BadValueError(f"{progress_file} is not valid JSON ({exc}); delete it to start the dataset "
                             "again") from None
        if not isinstance(started, dict) or started.get("config_hash") != chash:
            raise BadValueError(f"{out_dir} holds a partial dataset started with another config; "
                             "resume it with the same config or choose a new out_dir")
        copied = out_dir / "grasps.npz"
        if copied.is_file() and copied.resolve() != grasps_path.resolve() \
                and _file_digest(copied) != _file_digest(grasps_path):
            raise BadValueError(f"{out_dir} holds a partial dataset started with other grasps than {grasps_path} "
                             "(its grasps.npz differs); resume it with the same grasps or choose a new out_dir")
    else:
        write_json(progress_file, {"config_hash": chash, "layout": asdict(layout)})
    if not (out_dir / "grasps.npz").is_file() or grasps_path.resolve() != (out_dir / "grasps.npz").resolve():
        write_with(out_dir / "grasps.npz", lambda tmp: shutil.copyfile(grasps_path, tmp))


def _generate_locked(spec, out_dir, grasps_path, grasps, splits, layout, chash, resolved_config, backgrounds,
                     backgrounds_dir, workers, k, n, platform, progress, log, launcher, ray, stack) -> dict:
    """The part of :func:`generate` that runs while it holds the folder (or its shard)."""
    if n == 1:
        # no other run is live here (the lock): whatever temporary files lie around are a killed run's.
        # A shard leaves them to the finishing run, since other shards may be writing theirs
        _remove_all_tmp(out_dir)
    manifest_file = out_dir / "manifest.json"
    if manifest_file.is_file():
        return _finished(out_dir, layout, chash)
    _start_or_resume(out_dir, grasps_path, layout, chash)

    chunks = chunk_plan(layout, splits.grasps, splits.views)
    todo = [c for c in range(len(chunks)) if c % n == k and not _chunk_path(out_dir, chunks[c][0], c).is_file()]
    start = time.perf_counter()
    rendered = 0
    if todo:
        n_frames = sum(len(chunks[c][1]) for c in todo)
        log(f"rendering {n_frames} frames ({len(todo)} chunks) with "
            + (f"{workers} worker(s)" if launcher == "local" else "Ray") + (f", shard {k}/{n}" if n > 1 else ""))
        for split in SPLITS:
            for m in spec.modalities:
                (out_dir / split / m).mkdir(parents=True, exist_ok=True)
            (out_dir / split / ".chunks").mkdir(parents=True, exist_ok=True)
        jobs = [(c, str(out_dir), *chunks[c], layout) for c in todo]
        init = (spec, str(out_dir / "grasps.npz"), backgrounds_dir, platform)
        bar = _progress(n_frames, progress, "rendering")
        writers = {os.getpid()}
        try:
            if launcher == "ray":
                from datagen.dataset.ray_launcher import render_chunks

                def on_chunk(output: ChunkOutput) -> None:
                    nonlocal rendered
                    count = write_chunk(out_dir, output, spec.rgb_format)
                    rendered += count
                    bar.update(count)

                render_chunks("datagen.dataset.chunks:ChunkRenderer", [(c, *chunks[c]) for c in todo], layout,
                              spec, (out_dir / "grasps.npz").read_bytes(), backgrounds_dir, platform,
                              ray or RayOptions(), workers, on_chunk, log=log)
            elif workers == 1:
                _worker_init(*init)
                for _, count in map(_render_chunk, jobs):
                    rendered += count
                    bar.update(count)
            else:
                ctx = multiprocessing.get_context("spawn")
                with ctx.Pool(min(workers, len(jobs)), initializer=_worker_init, initargs=(*init, os.getpid())) as pool:
                    writers.update(p.pid for p in multiprocessing.active_children())
                    try:
                        for _, count in pool.imap_unordered(_render_chunk_in_worker, jobs):
                            rendered += count
                            bar.update(count)
                    except _WorkerDiskFull as exc:
                        raise DiskFullError(exc.args[0]) from None
                    finally:
                        writers.update(p.pid for p in multiprocessing.active_children())
                # leaving the pool stopped its workers (SIGTERM), maybe in the middle of a file
        except BaseException:
            _remove_tmp_of(out_dir, None if n == 1 else writers)
            raise
        finally:
            bar.close()
    seconds = time.perf_counter() - start
    partial = {"out_dir": str(out_dir), "frames_total": layout.size, "frames_rendered": rendered,
               "seconds": seconds, "complete": False, "counts": {}}
    if n > 1:
        # the shards that find every chunk done race to finish the dataset: one at a time, and once
        try:
            stack.enter_context(OutputLock(out_dir, "generate"))
        except LockedError as exc:
            log(f"not finishing the dataset: {exc}")
            return partial
        if manifest_file.is_file():
            return {**_finished(out_dir, layout, chash), "frames_rendered": rendered, "seconds": seconds}
    missing = [c for c in range(len(chunks)) if not _chunk_path(out_dir, chunks[c][0], c).is_file()]
    if missing:
        log(f"{len(missing)} chunks still missing (other shards); the manifest is written when all are done")
        return partial
    counts = _finalise(out_dir, spec, layout, splits, chunks, resolved_config, chash, backgrounds, grasps)
    return {"out_dir": str(out_dir), "frames_total": layout.size, "frames_rendered": rendered, "seconds": seconds,
            "complete": True, "counts": counts}


def _finished(out_dir: Path, layout: Layout, chash: str) -> dict:
    """The answer for a folder whose manifest exists: done if it is this config's dataset."""
    from datagen.dataset.contract import read_manifest

    manifest = read_manifest(out_dir)
    if manifest.get("config_hash") != chash:
        raise BadValueError(f"{out_dir} holds a finished dataset made with another config; choose a new out_dir")
    _remove_scaffolding(out_dir)
    return {"out_dir": str(out_dir), "frames_total": layout.size, "frames_rendered": 0, "seconds": 0.0,
            "complete": True, "counts": manifest["counts"]}


def _progress(total: int, enabled: bool, desc: str | None = None, unit: str = "frame"):
    from tqdm import tqdm

    return tqdm(total=total, unit=unit, desc=desc, disable=not enabled, smoothing=0.1, dynamic_ncols=True)


def _finalise(out_dir, spec, layout, splits, chunks, resolved_config, chash, backgrounds, grasps) -> dict:
    """Merge the chunk rows per split, then write the manifest (last)."""
    counts, merged_splits = {}, {}
    for split in SPLITS:
        parts = []
        for c in (c for c, (chunk_split, _) in enumerate(chunks) if chunk_split == split):
            with np.load(_chunk_path(out_dir, split, c)) as data:
                parts.append({key: data[key] for key in data.files})
        merged = {key: np.concatenate([p[key] for p in parts]) for key in ANNOTATION_DTYPES} if parts else \
            {key: np.zeros((0,), dtype=dt) for key, dt in ANNOTATION_DTYPES.items()}
        counts[split] = int(len(merged["frame_id"]))
        merged_splits[split] = merged
        if counts[split]:
            save_npz(out_dir / split / "annotations.npz", merged)
    view_ids, angles = viewpoints(spec.sphere)
    floors = split_floors(merged_splits) if counts["train"] else {}
    manifest = {
        "schema_version": SCHEMA_VERSION,
        "generator": {"name": "hupbench.datagen", "version": GENERATOR_VERSION,
                      "git_commit": resolved_config.get("_provenance", {}).get("git_commit", "unknown")},
        "config": resolved_config,
        "config_hash": chash,
        "counts": counts,
        "grasp_ids": {split: [int(grasps.grasp_id[g]) for g in gs] for split, gs in splits.grasps.items()},
        "grasp_indices": splits.grasps,
        "grasp_theta_vol_deg": {str(int(i)): (None if e is None else [float(v) for v in e])
                                for i, e in zip(grasps.grasp_id, grasps.probe_euler_deg)},
        "layout": {"order": ["grasp", "z_ego", "background", "glove", "view"], "shape": list(layout.shape),
                   "index": "i = (((grasp * n_z + z) * n_bg + bg) * n_glove + glove) * n_view + view",
                   "chunk_size": layout.chunk_size},
        "image_size": [spec.width, spec.height],
        "K": spec.intrinsics.K.tolist(),
        "modalities": list(spec.modalities),
        "rgb_format": spec.rgb_format,
        "keypoint_names": list(kp.KEYPOINT_NAMES),
        "skeleton_edges": [list(e) for e in kp.SKELETON_EDGES],
        "seg_labels": SEG_LABELS,
        "depth_scale_m": DEPTH_SCALE_M,
        "z_ego_m": list(spec.z_ego_m),
        "viewpoints": {"ids": view_ids.tolist(), "theta_rad": angles[:, 0].tolist(), "phi_rad": angles[:, 1].tolist(),
                       "sphere": asdict(spec.sphere),
                       # target -> camera per view in the arm frame (hand -> elbow, dorsal, thumb side):
                       # the same for every grasp, whichever way the sphere is attached
                       "direction_arm": view_directions_arm(spec.sphere, angles).round(12).tolist(),
                       "split_view_ids": {split: view_ids[positions].tolist() for split, positions in splits.views.items()}},
        "protocol": protocol(spec),
        "split_floors": {"definition": FLOORS_DEFINITION, "splits": floors},
        "backgrounds": {"names": list(backgrounds.names[: spec.n_backgrounds]),
                        "fingerprint": backgrounds.fingerprint()},
        "gloves_rgb": [list(c) for c in GLOVE_RGB[: spec.n_gloves]],
        "arm_rgb": list(ARM_RGB),
    }
    write_json(out_dir / "manifest.json", manifest)
    _remove_scaffolding(out_dir)
    return counts


def _remove_scaffolding(out_dir: Path) -> None:
    """The manifest is the completion mark; the chunk rows, the progress file and temporary files
    left by killed runs are scaffolding. Also called on a finished folder: a run killed between the
    manifest and this leaves some behind."""
    for split in SPLITS:
        shutil.rmtree(out_dir / split / ".chunks", ignore_errors=True)
    _remove_all_tmp(out_dir)
    (out_dir / ".progress.json").unlink(missing_ok=True)
