"""Rendering a dataset's chunks on Ray: one actor per worker, each owning a renderer.

``hupbench generate launcher=ray`` hands the chunks that :func:`hupbench.datagen.dataset.writer.generate`
still needs to Ray actors. Each actor builds one :class:`hupbench.datagen.dataset.chunks.ChunkRenderer`
(the same class the local worker processes use) when it starts, renders the chunks it is
given and returns them encoded; the driver writes them with
:func:`hupbench.datagen.dataset.chunks.write_chunk`. So the output folder only has to exist where the
driver runs, and a Ray run writes exactly the files a local run writes, through the same
resumable chunk mechanism.

Failures: an actor whose process dies is restarted by Ray and the chunks it held are
retried on it (``actor_restarts``); a chunk whose actor is gone for good is handed to a
fresh actor, up to ``max_retries`` times. A chunk is written once, when its
result arrives, so nothing is lost or duplicated; if the driver itself dies, the next run
renders only the chunks that were not written.

Ray is an optional dependency (``pip install 'hupbench[ray]'``) and is imported only here,
only when this launcher runs.
"""

from __future__ import annotations

import importlib
import logging
import math
import os
import socket
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

from hupbench.core.input_checks import check_int
from hupbench.core.errors import BadValueError, RunFailedError

RAY_MISSING = "launcher=ray needs Ray: pip install 'hupbench[ray]'"
LAUNCHERS = ("local", "ray")
#: chunks queued on one actor at a time: one rendering, one waiting, so no actor idles
#: while the driver writes
CHUNKS_IN_FLIGHT_PER_ACTOR = 2
#: object store of a private runtime; a 256 px chunk of 184 frames is about 6 MB encoded
PRIVATE_OBJECT_STORE_BYTES = 256 * 1024**2


@dataclass(frozen=True)
class RayOptions:
    """Where and how wide to render with Ray (the ``ray:`` group of ``conf/generate.yaml``).

    Attributes:
        address: None starts a private Ray runtime on this machine (stopped at the end);
            "auto" joins the cluster that ``ray start`` runs here; "ray://host:10001" goes
            through Ray Client.
        num_workers: actors (each one renderer); None: ``workers`` on a private runtime,
            one per ``cpus_per_worker`` CPUs of a cluster.
        cpus_per_worker: CPUs Ray reserves for each actor.
        actor_restarts: times Ray restarts an actor whose process died, retrying the chunks
            it held on the restarted actor.
        max_retries: times a chunk is handed to a fresh actor after its actor died for good
            (its restarts used up).
        start_timeout_s: seconds to wait for every actor to start (a cluster too small for
            ``num_workers`` fails with a message instead of waiting forever).
    """

    address: str | None = None
    num_workers: int | None = None
    cpus_per_worker: float = 1.0
    actor_restarts: int = 2
    max_retries: int = 3
    start_timeout_s: float = 600.0

    def __post_init__(self) -> None:
        if self.address is not None and (not isinstance(self.address, str) or not self.address):
            raise BadValueError(f"ray.address must be null, 'auto' or 'ray://host:port', got {self.address!r}")
        check_int(self.num_workers, "ray.num_workers", low=1, optional=True)
        if isinstance(self.cpus_per_worker, bool) or not isinstance(self.cpus_per_worker, (int, float)) \
                or not math.isfinite(self.cpus_per_worker) or self.cpus_per_worker <= 0:
            raise BadValueError(f"ray.cpus_per_worker must be a positive number, got {self.cpus_per_worker!r}")
        for name in ("actor_restarts", "max_retries"):
            check_int(getattr(self, name), f"ray.{name}", low=0)
        if not isinstance(self.start_timeout_s, (int, float)) or not self.start_timeout_s > 0:
            raise BadValueError(f"ray.start_timeout_s must be > 0 seconds, got {self.start_timeout_s!r}")


def check_launcher(launcher: str) -> None:
    """Fail before any work if the launcher is unknown, or is Ray and Ray is not installed.

    Raises:
        ValueError: launcher is not one of ``LAUNCHERS``.
        RuntimeError: launcher is "ray" and ``import ray`` fails (the message says how to install it).
    """
    if launcher not in LAUNCHERS:
        raise BadValueError(f"launcher must be one of {LAUNCHERS}, got {launcher!r}")
    if launcher == "ray":
        require_ray()


def require_ray():
    """``import ray``, or a RuntimeError saying how to install it."""
    try:
        import ray
    except ImportError as exc:
        raise RunFailedError(RAY_MISSING) from exc
    return ray


def resolve_factory(factory: str) -> Callable:
    """``"package.module:Name"`` -> the object it names (imported now)."""
    module, _, name = factory.partition(":")
    assert module and name, factory
    return getattr(importlib.import_module(module), name)


class ChunkActor:
    """A Ray actor: one chunk renderer (the dataset writer's ``ChunkRenderer``), built once, rendering chunks.

    Wrapped by ``ray.remote`` in :func:`render_chunks` (so this module imports without Ray).

    Args:
        factory: ``"package.module:Name"`` of the renderer class, called as
            ``Name(run.dataset, grasps_npz, run.job.backgrounds_dir, platform)``. A name rather than the class:
            the class's module imports the renderer, and the actor must choose its GL platform first.
        run: the :class:`hupbench.datagen.dataset.writer.GenerateRun`. grasps_npz: the dataset's grasps file's bytes.
    """

    def __init__(self, factory: str, run, grasps_npz: bytes) -> None:
        from hupbench.datagen.render import gl

        # an actor is its own process: fix PYOPENGL_PLATFORM here, before anything imports
        # pyrender or PyOpenGL (each node picks what works on it when run.job.platform is None)
        self.platform = gl.configure(run.job.platform)
        self._chunks = resolve_factory(factory)(run.dataset, grasps_npz, run.job.backgrounds_dir, self.platform)

    def info(self) -> dict:
        """{"pid", "host", "platform"} of this actor."""
        return {"pid": os.getpid(), "host": socket.gethostname(), "platform": self.platform}

    def render(self, chunk: int, split: str, frames: tuple[int, ...], layout):
        """Render one chunk; returns a :class:`hupbench.datagen.dataset.chunks.ChunkOutput`."""
        return self._chunks.render(chunk, split, frames, layout)


def render_chunks(factory: str, jobs: list[tuple[int, str, tuple[int, ...]]], layout, run, grasps_npz: bytes,
                  on_chunk: Callable[[object], None], log=print) -> dict:
    """Render chunks on Ray actors and hand each result to ``on_chunk`` in the driver.

    Args:
        factory: the chunk renderer every actor builds, ``"package.module:Name"`` (see :class:`ChunkActor`).
        jobs: (chunk, split, frame indices) of the chunks to render.
        layout: the dataset's :class:`hupbench.datagen.dataset.spec.Layout`.
        run: the :class:`hupbench.datagen.dataset.writer.GenerateRun`, sent to every actor; of its ``job``: the
            ``ray`` options, ``workers`` (actors on a private runtime when ``ray.num_workers`` is None), the GL
            ``platform`` for every actor (None: each picks its own) and ``backgrounds_dir`` (must exist on every
            node).
        grasps_npz: bytes of the dataset's grasps.npz (sent to every actor).
        on_chunk: called once per finished chunk with its ``ChunkOutput`` (writes it).
        log: progress messages.

    Returns:
        {"actors": int, "actor_failures": int (chunk results lost to a dead actor and rendered again)}.

    Raises:
        RuntimeError: Ray missing, actors that cannot start, or a chunk whose actors kept dying.
    """
    ray = require_ray()
    options, default_workers = run.job.ray, run.job.workers
    started_here = not ray.is_initialized()
    if started_here:
        _init_ray(ray, options, default_workers)
    actors: list = []
    try:
        n_actors = _n_actors(ray, options, default_workers, started_here)
        remote_cls = ray.remote(num_cpus=options.cpus_per_worker, max_restarts=options.actor_restarts,
                                max_task_retries=options.actor_restarts)(ChunkActor)

        def new_actor():
            # the arguments travel with the actor's creation task (a grasps file is kilobytes), so a
            # restarted actor does not depend on an object-store entry staying alive
            return remote_cls.remote(factory, run, grasps_npz)

        actors = [new_actor() for _ in range(n_actors)]
        for i, info in enumerate(_wait_started(ray, actors, options.start_timeout_s)):
            log(f"ray actor {i}: pid {info['pid']} on {info['host']}, {info['platform']}")
        failures = _schedule(ray, jobs, layout, actors, new_actor, options.max_retries, on_chunk, log)
        return {"actors": n_actors, "actor_failures": failures}
    finally:
        for actor in actors:
            ray.kill(actor, no_restart=True)
        if started_here:
            ray.shutdown()


def _init_ray(ray, options: RayOptions, default_workers: int) -> None:
    quiet = {"logging_level": logging.ERROR, "log_to_driver": False}
    if options.address is None:
        n = options.num_workers or default_workers
        # "local" starts a private runtime even when RAY_ADDRESS points at a cluster; it gets
        # only the CPUs its actors need and no dashboard, because this machine may be shared
        ray.init(address="local", num_cpus=math.ceil(n * options.cpus_per_worker), include_dashboard=False,
                 object_store_memory=PRIVATE_OBJECT_STORE_BYTES, **quiet)
    elif options.address.startswith("ray://"):
        ray.init(address=options.address)  # Ray Client forwards changed init arguments to the server
    else:
        ray.init(address=options.address, **quiet)


def _n_actors(ray, options: RayOptions, default_workers: int, started_here: bool) -> int:
    if options.num_workers is not None:
        return options.num_workers
    if started_here and options.address is None:
        return default_workers
    cpus = float(ray.cluster_resources().get("CPU", 0.0))
    return max(1, int(cpus // options.cpus_per_worker))


def _wait_started(ray, actors: list, timeout_s: float) -> list[dict]:
    refs = [a.info.remote() for a in actors]
    ready, _ = ray.wait(refs, num_returns=len(refs), timeout=timeout_s)
    if len(ready) < len(refs):
        raise RunFailedError(f"only {len(ready)} of {len(refs)} Ray actors started within {timeout_s:.0f} s; "
                           f"the cluster has {ray.cluster_resources().get('CPU', 0)} CPUs: lower ray.num_workers")
    try:
        return ray.get(refs)
    except ray.exceptions.RayActorError as exc:
        # Ray's message ends with the error raised in the actor's constructor; the rest is its traceback
        lines = str(exc).strip().splitlines()
        raise RunFailedError(f"a Ray rendering actor failed to start: {lines[-1] if lines else exc!r}") from exc


def _schedule(ray, jobs, layout, actors: list, new_actor, max_retries: int, on_chunk, log) -> int:
    """Keep every actor fed with chunks until all are written; returns the number of lost results."""
    queue = deque(jobs)
    attempts = {job[0]: 0 for job in jobs}
    pending: dict = {}  # ObjectRef -> (chunk, split, frames, slot, actor handle it went to)
    load = [0] * len(actors)
    failures = 0
    while queue or pending:
        for slot, actor in enumerate(actors):
            while queue and load[slot] < CHUNKS_IN_FLIGHT_PER_ACTOR:
                chunk, split, frames = queue.popleft()
                pending[actor.render.remote(chunk, split, frames, layout)] = (chunk, split, frames, slot, actor)
                load[slot] += 1
        done, _ = ray.wait(list(pending), num_returns=1)
        ref = done[0]
        chunk, split, frames, slot, actor = pending.pop(ref)
        if actors[slot] is actor:
            load[slot] -= 1
        try:
            output = ray.get(ref)
        except ray.exceptions.RayTaskError as exc:
            # an error raised by the rendering code: raise the error itself, as the local launcher
            # does, rather than Ray's wrapper with the remote traceback in its message
            if isinstance(exc.cause, Exception):
                raise exc.cause from exc
            raise
        except ray.exceptions.RayActorError as exc:
            # the actor died beyond Ray's own restarts and retries
            failures += 1
            attempts[chunk] += 1
            if attempts[chunk] > max_retries:
                raise RunFailedError(f"chunk {chunk} lost its Ray actor {attempts[chunk]} times; "
                                   "rerun the same command to resume") from exc
            if actors[slot] is actor:
                log(f"ray actor {slot} died ({type(exc).__name__}); starting a fresh one, chunk {chunk} again")
                ray.kill(actor, no_restart=True)
                actors[slot], load[slot] = new_actor(), 0
                # chunks still queued on the dead actor fail the same way and come back here
            queue.appendleft((chunk, split, frames))
            continue
        on_chunk(output)
    return failures
