"""hupbench.core.processes: numpy's BLAS held to one thread inside ``one_blas_thread`` and given its threads back
after."""

import os

import numpy  # noqa: F401  (loads the BLAS these tests count the threads of)
from threadpoolctl import threadpool_info, threadpool_limits

from hupbench.core.processes import one_blas_thread, usable_cores
from helpers import THREADS


def blas_threads() -> set[int]:
    """The thread counts of the BLAS libraries loaded in this process (numpy's)."""
    return {pool["num_threads"] for pool in threadpool_info() if pool["user_api"] == "blas"}


def test_blas_runs_on_one_thread_inside_and_on_its_own_count_after():
    with threadpool_limits(limits=2, user_api="blas"):
        assert blas_threads() == {2}
        with one_blas_thread():
            assert blas_threads() == {1}
        assert blas_threads() == {2}

        @one_blas_thread()
        def inside() -> set[int]:
            return blas_threads()

        assert inside() == {1} and blas_threads() == {2}


def test_the_test_processes_share_the_cores_and_pass_their_share_on():
    """The suite's own guard against thrashing (helpers.THREADS): pytest-xdist's workers together run no more torch
    threads than there are cores, and a command a test starts inherits the worker's share."""
    import torch

    workers = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
    assert torch.get_num_threads() == THREADS and workers * THREADS <= max(usable_cores(), workers)
    assert os.environ["OMP_NUM_THREADS"] == str(THREADS)
