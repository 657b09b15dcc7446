"""Both fits run numpy's BLAS on one thread (hupbench.core.processes.one_blas_thread): its products are small, and its
waiting threads would take the CPU from torch's."""

import numpy as np
from threadpoolctl import threadpool_info, threadpool_limits

from hupbench.core import keypoints as kp
from hupbench.fits import after_network, hand_fit, probe_fit
from hupbench.fits.known_probe import default_fit_probe

S = 32
K = np.array([[40.0, 0.0, 15.5], [0.0, 40.0, 15.5], [0.0, 0.0, 1.0]])


def blas_threads() -> set[int]:
    return {pool["num_threads"] for pool in threadpool_info() if pool["user_api"] == "blas"}


def test_both_fits_run_blas_on_one_thread_and_give_its_threads_back(monkeypatch):
    seen = {}

    def recording(part, sample):
        def wrapped(*args):
            seen[part] = blas_threads()
            return sample(*args)
        return wrapped

    monkeypatch.setattr(probe_fit, "sample_points", recording("probe", probe_fit.sample_points))
    monkeypatch.setattr(hand_fit, "sample_points", recording("hand", hand_fit.sample_points))
    images = np.zeros((1, 4, S, S), dtype=np.float32)
    images[:, 3] = 0.5                                                               # a wall half a metre away
    points3d = np.zeros((1, kp.NUM_KEYPOINTS, 3))
    points3d[0, kp.CORNER_SLICE] = default_fit_probe().corners + [0.0, 0.0, 0.45]
    points3d[0, kp.HAND_SLICE] = np.random.default_rng(0).normal(0.0, 0.02, (kp.NUM_HAND, 3)) + [0.0, 0.0, 0.48]
    with threadpool_limits(limits=2, user_api="blas"):
        after_network({"probe_fit": "depth", "hand_fit": "depth"}, np.zeros((1, kp.NUM_KEYPOINTS, 2)), points3d,
                      images, K)
        assert blas_threads() == {2}
    assert seen == {"probe": {1}, "hand": {1}}
