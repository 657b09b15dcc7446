"""Worker processes and threads: one rule for how many a verb may start, quiet workers on Ctrl-C, and numpy's BLAS
held to one thread where its products are small (imports nothing heavy)."""

from __future__ import annotations

import contextlib
import functools
import os
import signal
import threading
from typing import Iterator

from hupbench.core.input_checks import check_int
from hupbench.core.errors import BadValueError

#: processes (or torch threads) per usable CPU core a verb may start; far more only thrashes
MAX_WORKERS_PER_CORE = 4


def usable_cores() -> int:
    """The CPU cores this process may run on (its affinity mask where the OS has one)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def check_workers(workers, what: str = "workers") -> int:
    """``workers`` when it is a whole number from 1 to :data:`MAX_WORKERS_PER_CORE` x the usable cores.

    Raises:
        BadValueError: naming ``what``, the value and the limit.
    """
    check_int(workers, what, low=1)
    cores = usable_cores()
    if workers > MAX_WORKERS_PER_CORE * cores:
        raise BadValueError(f"{what}={workers} is more than {MAX_WORKERS_PER_CORE} x the {cores} CPU core(s) this "
                            f"process may use ({MAX_WORKERS_PER_CORE * cores}); each worker is a process")
    return workers


def check_threads(threads, what: str = "threads") -> int:
    """``threads`` (torch's CPU threads) when it is a whole number from 1 to :data:`MAX_WORKERS_PER_CORE` x the
    usable cores: torch starts them all at once."""
    cores = usable_cores()
    return check_int(threads, what, 1, MAX_WORKERS_PER_CORE * cores,
                     hint=f" ({MAX_WORKERS_PER_CORE} x the {cores} CPU core(s) this process may use)")


@contextlib.contextmanager
def workers_ignore_ctrl_c() -> Iterator[None]:
    """Start worker processes inside this block: they inherit an ignored SIGINT.

    Ctrl-C in a terminal signals the whole process group; the parent alone answers it (one line, exit
    130) and stops its workers, which would otherwise each print a KeyboardInterrupt traceback. Python
    keeps a SIGINT its parent ignored ignored, in a fork as in a spawned interpreter.
    """
    if threading.current_thread() is not threading.main_thread():
        yield  # only the main thread may set a handler; its Ctrl-C does not reach this one
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


@functools.cache
def _thread_pools():
    """threadpoolctl's controller of the thread pools loaded in this process (found once: it reads the process's
    libraries)."""
    from threadpoolctl import ThreadpoolController

    return ThreadpoolController()


@contextlib.contextmanager
def one_blas_thread() -> Iterator[None]:
    """Inside this block (or a function it decorates) numpy's BLAS runs its products on one thread, and the
    thread count it had before comes back after.

    The fits after the network multiply many small matrices (66 x 120 by 120 x 66): a second BLAS thread gains
    nothing there, and BLAS threads, waiting spinning for the next product, take the CPU from the fit and from
    torch's own threads. Measured (``benchmarks/latency.py``, the paper protocol's best checkpoint, batch 1, the
    2-core AMD EPYC, a noisy host): PyTorch end to end 108 ms with two BLAS threads, 48 with
    ``OPENBLAS_NUM_THREADS=1``, 48-57 in four runs with this block. About 20 microseconds a block."""
    with _thread_pools().limit(limits=1, user_api="blas"):
        yield
