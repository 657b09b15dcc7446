"""Dataset generation: Algorithm 1 of HUP-3D, written to the dataset contract (:mod:`hupbench.core.contract`).

Frames are the product grasps x z_ego x backgrounds x gloves x viewpoints.
The frame index is the mixed-radix number of that tuple, viewpoints fastest:

    i = (((grasp * n_z + z) * n_bg + bg) * n_glove + glove) * n_view + view

and frame ``i`` is a pure function of (config, grasps, i): its camera comes from the sphere (on the clinic track the
grasp's head cameras), its lamp from a generator seeded with (seed, i). Frames are rendered in chunks of one (grasp,
z_ego, background) block (n_glove x n_view frames sharing the meshes); a chunk's image files are written atomically,
then its annotation rows, also atomically: a chunk whose rows exist is done, any other is rendered again on resume
(overwriting, never duplicating). ``shard=k/n`` renders only the chunks ``c`` with ``c % n == k``. Chunks are
rendered by :class:`hupbench.datagen.dataset.chunks.ChunkRenderer`, in local worker processes or on Ray actors
(:mod:`hupbench.datagen.dataset.ray_launcher`), and written by :func:`hupbench.datagen.dataset.chunks.write_chunk`.
When every chunk is done the rows are merged into ``<split>/annotations.npz`` and ``manifest.json`` is written last
(with the sha256 of the dataset's copy of its grasps, ``grasps_sha256``). Run again on a finished dataset, generate
renders the chunks whose image files are missing or empty once more, from the grasps the annotations were rendered
from.

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
from dataclasses import InitVar, asdict, dataclass, field
from pathlib import Path
from typing import Iterator

import numpy as np

from hupbench.datagen.assets.backgrounds import BackgroundSet
from hupbench.datagen.assets.probe_mesh import ProbeSource
from hupbench.core.contract import (CLINIC, DEPTH_SCALE_M, SCHEMA_VERSION, SEQUENCE, SPLITS, annotation_fields,
                                      frame_path, read_annotations, read_manifest, seg_labels)
from hupbench.datagen.dataset.grasps_file import (CLINIC_GRASPS, DEFAULT_GRASPS, GraspSet, read_grasps,
                                                  read_grasps_probe_record, rendered_with, subjects_record)
from hupbench.datagen.dataset.clinic import check_clinic_grasps
from hupbench.datagen.dataset.ray_launcher import RayOptions, check_launcher
from hupbench.datagen.dataset.floors import definition as floors_definition, split_floors
from hupbench.datagen.dataset.spec import (DatasetSpec, GENERATOR_VERSION, cameras_record, frame_plan, layout_record,
                                           protocol, sequence_record, split_of_grasps)
from hupbench.core.io import (TMP_PATTERN, DiskFullError, LockedError, OutputLock, check_writable, file_sha256, save_npz,
                        write_json, write_with)
from hupbench.core.processes import check_workers, workers_ignore_ctrl_c
from hupbench.datagen.render.scene import ARM_RGB, GLOVE_RGB
from hupbench.datagen.render import gl
from hupbench.core import keypoints as kp
from hupbench.core.input_checks import check_int
from hupbench.core.errors import BadValueError
from hupbench.datagen.dataset.chunks import (ChunkOutput, _WorkerDiskFull, _chunk_path, _render_chunk,
                                             _render_chunk_in_worker, _worker_init, read_clip_record, write_chunk)

#: the keys of a generate config that do not change a frame (left out of its hash)
RUN_ONLY_KEYS = ("workers", "shard", "out_dir", "progress", "launcher", "ray", "_provenance", "_target_")


@dataclass(frozen=True)
class RenderJob:
    """Where a dataset's frames are rendered and from which background photographs.

    Attributes:
        workers: local worker processes (at most :data:`hupbench.core.processes.MAX_WORKERS_PER_CORE` x the
            cores), or Ray actors on a private runtime.
        launcher: "local" or "ray" (:mod:`hupbench.datagen.dataset.ray_launcher`, settings in ``ray``); both write
            the same files.
        shard: "k/n" renders only the chunks ``c`` with ``c % n == k``; None renders all.
        platform: "egl", "osmesa" or None (automatic), see :mod:`hupbench.datagen.render.gl`.
        backgrounds_dir: a folder of background photographs, None for the built-in ones.
        k, n: the parsed shard.
    """

    workers: int = 1
    launcher: str = "local"
    shard: str | None = None
    ray: RayOptions = RayOptions()
    platform: str | None = None
    backgrounds_dir: str | None = None
    k: int = field(init=False)
    n: int = field(init=False)

    def __post_init__(self) -> None:
        k, n = parse_shard(self.shard)
        object.__setattr__(self, "k", k)
        object.__setattr__(self, "n", n)
        check_launcher(self.launcher)
        if self.launcher == "local":
            check_workers(self.workers)
        else:  # Ray actors may live on other machines: only local processes are bounded by the cores here
            check_int(self.workers, "workers", low=1)
        check_platform(self.platform, "render.platform")


def check_platform(platform, what: str) -> str | None:
    """``platform`` when it names an offscreen GL platform (:data:`hupbench.datagen.render.gl.PLATFORMS`) or is None
    (automatic); ``what`` is the config key, e.g. ``"sheet.platform"``."""
    if platform is not None and platform not in gl.PLATFORMS:
        raise BadValueError(f"{what} must be one of {', '.join(gl.PLATFORMS)} or null (automatic), got {platform!r}")
    return platform


@dataclass(frozen=True)
class GenerateRun:
    """``conf/generate.yaml``: the dataset, its grasps and folder, and how its frames are rendered; the
    writer (:func:`generate`), its worker processes and its Ray actors take it whole.

    Attributes:
        dataset: what the frames are. out_dir: the dataset folder.
        grasps_path: the grasps file to render; None renders the default grasps that ship with hupbench
            (:data:`hupbench.datagen.dataset.grasps_file.DEFAULT_GRASPS`, on the clinic track
            :data:`~hupbench.datagen.dataset.grasps_file.CLINIC_GRASPS`) for the procedural probe, and for a
            probe mesh makes grasps for it into ``out_dir/grasps`` first (``hupbench grasps``).
        progress: a progress bar on stderr.
        probe: which probe; the grasps file must have been made for it (checked by
            :func:`check_grasps_file` before rendering).
        job: built from the config's ``workers``, ``launcher``, ``shard``, ``ray``, ``render.platform`` and
            ``backgrounds.dir``.
    """

    dataset: DatasetSpec
    out_dir: str
    grasps_path: str | None = None
    progress: bool = True
    probe: ProbeSource = ProbeSource()
    workers: InitVar[int] = 1
    launcher: InitVar[str] = "local"
    shard: InitVar[str | None] = None
    ray: InitVar[RayOptions] = RayOptions()
    render: InitVar[dict] = None
    backgrounds: InitVar[dict] = None
    job: RenderJob = field(init=False)

    def __post_init__(self, workers, launcher, shard, ray, render, backgrounds) -> None:
        object.__setattr__(self, "job", RenderJob(workers, launcher, shard, ray, (render or {}).get("platform"),
                                                  (backgrounds or {}).get("dir")))
        if not isinstance(self.progress, bool):
            raise BadValueError(f"progress must be true or false, got {self.progress!r}")
        check_writable(self.out_dir, "out_dir")

    @property
    def makes_grasps(self) -> bool:
        """Whether the grasps are made for this run (a probe mesh and no ``grasps_path``)."""
        return self.grasps_path is None and self.probe.mesh is not None

    @property
    def grasps_file(self) -> Path:
        """The grasps file the frames are rendered from: ``grasps_path``, the shipped default grasps, or
        ``out_dir/grasps/grasps.npz`` where :attr:`makes_grasps`."""
        if self.grasps_path is not None:
            return Path(self.grasps_path)
        if self.makes_grasps:
            return Path(self.out_dir) / "grasps" / "grasps.npz"
        return CLINIC_GRASPS if self.dataset.track == CLINIC else DEFAULT_GRASPS


def check_grasps_file(run: GenerateRun) -> None:
    """The run's grasps file (:attr:`GenerateRun.grasps_file`) can be rendered: a grasps file
    (:func:`hupbench.datagen.dataset.grasps_file.read_grasps`) made for the probe the run names (the same file,
    unit and alignment; else one line saying which probe each is), holding the grasps ``dataset.splits``
    counts and, on the clinic track, their subjects and patients. Reads the file's arrays and probe record only
    (building the probe takes seconds, and this runs before the folder's lock is asked for)."""
    path = run.grasps_file
    arrays = read_grasps(path)
    if run.dataset.track == CLINIC:
        check_clinic_grasps(arrays, path)
    split_of_grasps(run.dataset, len(arrays["grasp_id"]))
    record = read_grasps_probe_record(path)
    spec = run.probe.spec
    wanted = {"kind": "procedural"} if spec is None else spec.record()
    made = {k: v for k, v in record.items() if k in wanted}
    if made != wanted:
        def say(r: dict) -> str:
            return "the procedural probe" if r["kind"] == "procedural" else \
                f"probe.mesh={r['path']} (sha256 {r['sha256'][:12]}, unit {r['unit']}, align {r['align']})"
        raise BadValueError(f"grasps file {path} was made for {say(record)} but this run names {say(wanted)}: "
                            "pass the grasps' probe or make grasps for this one (`hupbench grasps probe.mesh=...`)")


def config_hash(resolved: dict) -> str:
    """sha256 (hex) of the resolved config without the keys that do not change a frame (:data:`RUN_ONLY_KEYS`)."""
    keep = {k: v for k, v in resolved.items() if k not in RUN_ONLY_KEYS}
    return hashlib.sha256(json.dumps(keep, sort_keys=True, default=str).encode()).hexdigest()


def parse_shard(shard: str | None) -> tuple[int, int]:
    """"k/n" -> (k, n) with 0 <= k < n; None -> (0, 1)."""
    if shard in (None, "", "0/1"):
        return 0, 1
    try:
        k, n = (int(part) for part in str(shard).split("/"))
    except ValueError:  # not two whole numbers
        k, n = -1, 0
    if not 0 <= k < n:
        raise BadValueError(f"shard must look like k/n with 0 <= k < n (e.g. 0/4), got {shard!r}")
    return k, n


LOCKS_DIR = ".locks"


def shard_lock_folder(out_dir: Path, k: int, n: int) -> Path:
    """Where shard ``k/n`` of a dataset keeps its lock (an unsharded run locks ``out_dir`` itself)."""
    return Path(out_dir) / LOCKS_DIR / f"shard-{k}-of-{n}"


@contextlib.contextmanager
def run_lock(out_dir: Path, shard: str | None = None) -> Iterator[OutputLock]:
    """Hold the output folder for one generate run (see :class:`hupbench.core.io.OutputLock`).

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
    """Remove every temporary file (:data:`hupbench.core.io.TMP_PATTERN`) under ``out_dir``.

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


def generate(run: GenerateRun, resolved_config: dict, log=print, lock: OutputLock | None = None) -> dict:
    """Render (or resume, or repair) the dataset of ``run``. See the module docstring for the layout and the
    guarantees.

    Everything is checked before anything is written; then the run holds the output folder
    (:func:`run_lock`) until it returns, removes the temporary files of killed runs, and renders
    what is missing: the chunks without rows of a partial dataset, or the chunks of a finished
    dataset whose image files are missing or empty (rendered again, byte for byte).

    Args:
        run: what the frames are, from which grasps file (:attr:`GenerateRun.grasps_file`, which must exist),
            into which folder, and how they are rendered.
        resolved_config: the resolved config, recorded in the manifest (its frame-changing keys hashed).
        log: receives progress lines.
        lock: the lock of this run when the caller already holds it (``with run_lock(out_dir,
            shard) as lock``); None takes it here.

    Returns:
        dict with "out_dir", "frames_total", "frames_rendered" (this run), "seconds",
        "complete" (manifest written) and "counts" per split.

    Raises:
        LockedError: another live generate run holds the folder (or this shard).
    """
    writer = DatasetWriter(run, resolved_config, log)
    job = run.job
    with contextlib.ExitStack() as stack:
        if lock is None:
            lock = stack.enter_context(run_lock(writer.out_dir, job.shard))
        held = writer.out_dir if job.n == 1 else shard_lock_folder(writer.out_dir, job.k, job.n)
        assert lock.folder.resolve() == held.resolve(), (lock.folder, held)
        if lock.taken_over:
            log(f"took over the lock of a generate run that is gone (pid {lock.taken_over.get('pid')} on "
                f"{lock.taken_over.get('host')})")
        return writer.write(stack)


class DatasetWriter:
    """Writes the dataset of one :class:`GenerateRun` while the run holds its folder (:func:`generate`).

    Args:
        run: the run. resolved_config: the resolved config, recorded in the manifest. log: progress lines.

    Attributes:
        run, resolved_config, log: as given. out_dir: ``run.out_dir`` as a path.
        backgrounds: the background set (``run.job.backgrounds_dir`` or the built-ins).
        grasps: the grasps rendered (:class:`hupbench.datagen.dataset.grasps_file.GraspSet` of
            ``run.grasps_file``). plan: the frames' :class:`hupbench.datagen.dataset.spec.FramePlan`.
        config_hash: :func:`config_hash` of ``resolved_config``.
    """

    def __init__(self, run: GenerateRun, resolved_config: dict, log=print) -> None:
        spec, job = run.dataset, run.job
        self.backgrounds = BackgroundSet.from_dir(job.backgrounds_dir) if job.backgrounds_dir else BackgroundSet.builtin()
        if len(self.backgrounds) < spec.n_backgrounds:
            raise BadValueError(f"dataset.n_backgrounds={spec.n_backgrounds} but the background set holds only "
                                f"{len(self.backgrounds)} image(s)"
                                + (f" ({job.backgrounds_dir})" if job.backgrounds_dir else ""))
        self.run, self.out_dir, self.resolved_config, self.log = run, Path(run.out_dir), resolved_config, log
        self.grasps = GraspSet(run.grasps_file)
        self.plan = frame_plan(spec, len(self.grasps))
        self.config_hash = config_hash(resolved_config)

    def write(self, stack: contextlib.ExitStack) -> dict:
        """Render what is missing and finish the dataset (:func:`generate`'s locked part); ``stack`` holds the
        folder's lock, and takes the unsharded lock when a shard finishes the dataset."""
        out_dir, job, chunks = self.out_dir, self.run.job, self.plan.chunks
        if job.n == 1:
            # no other run is live here (the lock): whatever temporary files lie around are a killed run's.
            # A shard leaves them to the finishing run, since other shards may be writing theirs
            _remove_all_tmp(out_dir)
        manifest_file = out_dir / "manifest.json"
        if manifest_file.is_file():
            return self._finished()
        self._start_or_resume()
        todo = [c for c in range(len(chunks)) if c % job.n == job.k and not _chunk_path(out_dir, chunks[c][0], c).is_file()]
        start = time.perf_counter()
        rendered = self._render(todo)
        seconds = time.perf_counter() - start
        partial = {"out_dir": str(out_dir), "frames_total": self.plan.layout.size, "frames_rendered": rendered,
                   "seconds": seconds, "complete": False, "counts": {}}
        if job.n > 1:
            # the shards that find every chunk done race to finish the dataset: one at a time, and once
            try:
                stack.enter_context(OutputLock(out_dir, "generate"))
            except LockedError as exc:
                self.log(f"not finishing the dataset: {exc}")
                return partial
            if manifest_file.is_file():
                return {**self._finished(), "frames_rendered": rendered, "seconds": seconds}
        missing = [c for c in range(len(chunks)) if not _chunk_path(out_dir, chunks[c][0], c).is_file()]
        if missing:
            self.log(f"{len(missing)} chunks still missing (other shards); the manifest is written when all are done")
            return partial
        return {**partial, "complete": True, "counts": self._finalise()}

    def _start_or_resume(self) -> None:
        """Record a new run's config hash in ``.progress.json``, or check that a partial dataset here was
        started with this config and these grasps; copy the grasps into the dataset."""
        out_dir, grasps_path = self.out_dir, self.run.grasps_file
        progress_file = out_dir / ".progress.json"
        copied = out_dir / "grasps.npz"
        if progress_file.is_file():
            try:
                started = json.loads(progress_file.read_text())
            except ValueError as exc:
                raise BadValueError(f"{progress_file} is not valid JSON ({exc}); delete it to start the dataset "
                                    "again") from None
            if not isinstance(started, dict) or started.get("config_hash") != self.config_hash:
                raise BadValueError(f"{out_dir} holds a partial dataset started with another config; "
                                    "resume it with the same config or choose a new out_dir")
            if copied.is_file() and copied.resolve() != grasps_path.resolve() \
                    and file_sha256(copied) != file_sha256(grasps_path):
                raise BadValueError(f"{out_dir} holds a partial dataset started with other grasps than {grasps_path} "
                                    "(its grasps.npz differs); resume it with the same grasps or choose a new out_dir")
        else:
            write_json(progress_file, {"config_hash": self.config_hash, "layout": asdict(self.plan.layout)})
        if not copied.is_file() or grasps_path.resolve() != copied.resolve():
            write_with(copied, lambda tmp: shutil.copyfile(grasps_path, tmp))

    def _render(self, todo: list[int]) -> int:
        """Render and write the chunks ``todo`` (indices into ``plan.chunks``); returns the frames written."""
        out_dir, run, chunks, layout = self.out_dir, self.run, self.plan.chunks, self.plan.layout
        job = run.job
        if not todo:
            return 0
        n_frames = sum(len(chunks[c][1]) for c in todo)
        self.log(f"rendering {n_frames} frames ({len(todo)} chunks) with "
                 + (f"{job.workers} worker(s)" if job.launcher == "local" else "Ray")
                 + (f", shard {job.k}/{job.n}" if job.n > 1 else ""))
        for split in SPLITS:
            for m in run.dataset.stored_modalities:
                (out_dir / split / m).mkdir(parents=True, exist_ok=True)
            (out_dir / split / ".chunks").mkdir(parents=True, exist_ok=True)
        jobs = [(c, str(out_dir), *chunks[c], layout) for c in todo]
        grasps = out_dir / "grasps.npz"  # the dataset's copy, which every worker renders from
        bar = _progress(n_frames, run.progress, "rendering")
        rendered = 0
        writers = {os.getpid()}
        try:
            if job.launcher == "ray":
                from hupbench.datagen.dataset.ray_launcher import render_chunks

                def on_chunk(output: ChunkOutput) -> None:
                    nonlocal rendered
                    count = write_chunk(out_dir, output, run.dataset.rgb_format)
                    rendered += count
                    bar.update(count)

                render_chunks("hupbench.datagen.dataset.chunks:ChunkRenderer", [(c, *chunks[c]) for c in todo], layout,
                              run, grasps.read_bytes(), on_chunk, self.log)
            elif job.workers == 1:
                _worker_init(run, str(grasps))
                for _, count in map(_render_chunk, jobs):
                    rendered += count
                    bar.update(count)
            else:
                ctx = multiprocessing.get_context("spawn")
                with workers_ignore_ctrl_c():
                    pool = ctx.Pool(min(job.workers, len(jobs)), initializer=_worker_init,
                                    initargs=(run, str(grasps), os.getpid()))
                with pool:
                    writers.update(p.pid for p in multiprocessing.active_children())
                    try:
                        # a clinic grasp's chunks go to one worker, which builds its hand and patient once
                        per_grasp = layout.n_z * layout.n_backgrounds if run.dataset.track == CLINIC else 1
                        for _, count in pool.imap_unordered(_render_chunk_in_worker, jobs, chunksize=per_grasp):
                            rendered += count
                            bar.update(count)
                    except _WorkerDiskFull as exc:
                        raise DiskFullError(exc.args[0]) from None
                    finally:
                        writers.update(p.pid for p in multiprocessing.active_children())
                # leaving the pool stopped its workers (SIGTERM), maybe in the middle of a file
        except BaseException:
            _remove_tmp_of(out_dir, None if job.n == 1 else writers)
            raise
        finally:
            bar.close()
        return rendered

    def _finished(self) -> dict:
        """The answer for a folder whose manifest exists: this config's dataset, with the image files of its
        frames (this shard's) that are missing or empty rendered again."""
        out_dir, job = self.out_dir, self.run.job
        manifest = read_manifest(out_dir)
        if manifest.get("config_hash") != self.config_hash:
            raise BadValueError(f"{out_dir} holds a finished dataset made with another config; choose a new out_dir")
        _remove_scaffolding(out_dir)
        lacking = [(c, path) for c, (split, frames) in enumerate(self.plan.chunks) if c % job.n == job.k
                   for path in self._frame_files(split, frames) if not _has_bytes(path)]
        rendered, start = 0, time.perf_counter()
        if lacking:
            if not self._rendered_from():
                raise BadValueError(f"{out_dir} holds a finished dataset whose grasps.npz is missing, differs from "
                                    f"{self.run.grasps_file} or is not the one its frames were rendered with, and "
                                    f"{len(lacking)} of its image files are missing or empty: generate it again into a "
                                    "new out_dir")
            todo = sorted({c for c, _ in lacking})
            self.log(f"the finished dataset lacks {len(lacking)} image file(s) (first "
                     f"{lacking[0][1].relative_to(out_dir)}): rendering their {len(todo)} chunk(s) again")
            rendered = self._render(todo)
            _remove_scaffolding(out_dir)
        return {"out_dir": str(out_dir), "frames_total": self.plan.layout.size, "frames_rendered": rendered,
                "seconds": time.perf_counter() - start, "complete": True, "counts": manifest["counts"]}

    def _rendered_from(self) -> bool:
        """The dataset's copy of the grasps is the grasps given and the one its annotations were rendered from
        (missing frames are rendered from it again)."""
        copied = self.out_dir / "grasps.npz"
        if not copied.is_file() or file_sha256(copied) != file_sha256(self.run.grasps_file):
            return False
        arrays, manifest = read_grasps(copied), read_manifest(self.out_dir)
        keys = ("grasp_index", "grasp_id", "hand_pose", "hand_trans") + (("clip_id", "time_s") if SEQUENCE in manifest
                                                                       else ())
        return all(rendered_with(arrays, read_annotations(self.out_dir, split, keys), manifest).all()
                   for split, count in manifest["counts"].items() if count)

    def _frame_files(self, split: str, frames: tuple[int, ...]) -> Iterator[Path]:
        spec = self.run.dataset
        for index in frames:
            for modality in spec.stored_modalities:
                yield frame_path(self.out_dir, split, modality, index, spec.rgb_format)

    def _finalise(self) -> dict:
        """Merge the chunk rows per split, then write the manifest (last); returns the frames per split."""
        out_dir, chunks = self.out_dir, self.plan.chunks
        spec = self.run.dataset
        counts, merged_splits, fields = {}, {}, annotation_fields(spec.track, spec.sequence)
        clips = []
        for split in SPLITS:
            parts = []
            for c in (c for c, (chunk_split, _) in enumerate(chunks) if chunk_split == split):
                with np.load(_chunk_path(out_dir, split, c)) as data:
                    parts.append({key: data[key] for key in fields})
                if spec.sequence:
                    clips.append({**read_clip_record(out_dir, split, c), "split": split})
            merged = {key: np.concatenate([p[key] for p in parts]) for key in fields} if parts else \
                {key: np.zeros((0,), dtype=dt) for key, (dt, _) in fields.items()}
            counts[split] = int(len(merged["frame_id"]))
            merged_splits[split] = merged
            if counts[split]:
                save_npz(out_dir / split / "annotations.npz", merged)
        floors = split_floors(merged_splits, self.run.dataset.track) if counts["train"] else {}
        write_json(out_dir / "manifest.json", self._manifest(counts, floors, sorted(clips, key=lambda r: r["clip_id"])))
        _remove_scaffolding(out_dir)
        return counts

    def _manifest(self, counts: dict[str, int], floors: dict, clips: list[dict]) -> dict:
        """The manifest of the finished dataset (the fields :func:`hupbench.core.contract.read_manifest` reads);
        ``clips`` are a dataset of clips' records (:func:`hupbench.datagen.dataset.clips.clip_record`)."""
        spec, plan, grasps = self.run.dataset, self.plan, self.grasps
        return {
            "schema_version": SCHEMA_VERSION,
            "generator": {"name": "hupbench.datagen", "version": GENERATOR_VERSION,
                          "git_commit": self.resolved_config.get("_provenance", {}).get("git_commit", "unknown")},
            "config": self.resolved_config,
            "config_hash": self.config_hash,
            "counts": counts,
            "grasp_ids": {split: [int(grasps.grasp_id[g]) for g in gs] for split, gs in plan.grasps.items()},
            "grasp_indices": plan.grasps,
            "grasp_theta_vol_deg": {str(int(i)): (None if e is None else [float(v) for v in e])
                                    for i, e in zip(grasps.grasp_id, grasps.probe_euler_deg)},
            # the dataset's copy of the grasps it was rendered from
            "grasps_sha256": file_sha256(self.out_dir / "grasps.npz"),
            "layout": layout_record(spec, plan.layout),
            "image_size": [spec.width, spec.height],
            "K": spec.intrinsics.K.tolist(),
            "modalities": list(spec.stored_modalities), **spec.sensor_record(),
            "rgb_format": spec.rgb_format,
            "keypoint_names": list(kp.KEYPOINT_NAMES),
            "skeleton_edges": [list(e) for e in kp.SKELETON_EDGES],
            "seg_labels": seg_labels(spec.track),
            "depth_scale_m": DEPTH_SCALE_M,
            **cameras_record(spec, plan.views),
            "protocol": protocol(spec),
            "split_floors": {"definition": floors_definition(spec.track), "splits": floors},
            "backgrounds": {"names": list(self.backgrounds.names[: spec.n_backgrounds]),
                            "fingerprint": self.backgrounds.fingerprint()},
            "gloves_rgb": [list(c) for c in GLOVE_RGB[: spec.n_gloves]],
            "arm_rgb": list(ARM_RGB),
            # the probe the frames show (hupbench.datagen.dataset.grasps_file.probe_of_dataset rebuilds it)
            "probe": grasps.probe.record,
            **({} if spec.track != CLINIC else {"subjects": subjects_record(grasps)}),
            **({} if not spec.sequence else {SEQUENCE: sequence_record(spec, clips)}),
        }


def _has_bytes(path: Path) -> bool:
    try:
        return path.stat().st_size > 0
    except FileNotFoundError:
        return False


def _progress(total: int, enabled: bool, desc: str | None = None, unit: str = "frame"):
    from tqdm import tqdm

    return tqdm(total=total, unit=unit, desc=desc, disable=not enabled, smoothing=0.1, dynamic_ncols=True)


def _remove_scaffolding(out_dir: Path) -> None:
    """The manifest is the completion mark; the chunk rows, the progress file and temporary files
    left by killed runs are scaffolding. Also called on a finished folder: a run killed between the
    manifest and this leaves some behind."""
    for split in SPLITS:
        shutil.rmtree(out_dir / split / ".chunks", ignore_errors=True)
    _remove_all_tmp(out_dir)
    (out_dir / ".progress.json").unlink(missing_ok=True)
