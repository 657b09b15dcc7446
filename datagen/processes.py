"""Worker-process counts: one rule for every verb that starts processes (imports nothing heavy)."""

from __future__ import annotations

import os

from datagen.input_checks import check_int
from datagen.errors import BadValueError

#: processes per usable CPU core a verb may start; far more only thrashes (measured: ``workers=100000``
#: spawned processes until the machine stalled)
MAX_WORKERS_PER_CORE = 4


def usable_cores() -> int:
    """The CPU cores this process may run on (its affinity mask where the OS has one)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def check_workers(workers, what: str = "workers") -> int:
    """``workers`` when it is a whole number from 1 to :data:`MAX_WORKERS_PER_CORE` x the usable cores.

    Raises:
        ValueError: naming ``what``, the value and the limit.
    """
    check_int(workers, what, low=1)
    cores = usable_cores()
    if workers > MAX_WORKERS_PER_CORE * cores:
        raise BadValueError(f"{what}={workers} is more than {MAX_WORKERS_PER_CORE} x the {cores} CPU core(s) this "
                         f"process may use ({MAX_WORKERS_PER_CORE * cores}); each worker is a process")
    return workers
