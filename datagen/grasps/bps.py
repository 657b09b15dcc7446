"""Basis Point Set (BPS) encoding of the probe, the condition of the grasp sampler.

Prokudin et al. (ICCV 2019) describe a shape by a fixed set of basis points
and, for each, the distance to the nearest point of the shape. GrabNet
conditions its CoarseNet on that feature with basis points drawn uniformly
in a ball of radius 0.15 m around the object; this module does the same for
the probe placed in the generator frame (written here, not taken from
either project).

Convention:
    Basis points live in the generator frame (metres): the probe rotated by
    its Euler angles Theta_Vol (degrees, intrinsic x-y-z) and centred at its
    volume centroid, see :mod:`hupbench.datagen.grasps.frames`. Features are unsigned
    distances in metres.
"""

from __future__ import annotations

import numpy as np

from hupbench.datagen.grasps.frames import T_gen_probe
from hupbench.datagen.assets.probe import Probe

#: GrabNet's ball radius: large enough to hold a hand grasping a 165 mm probe at its centroid
DEFAULT_RADIUS_M = 0.15
DEFAULT_N_BASIS = 1024


def basis_points(n: int = DEFAULT_N_BASIS, radius_m: float = DEFAULT_RADIUS_M, seed: int = 0) -> np.ndarray:
    """Points uniformly distributed in the volume of a ball centred at the origin.

    Direction: a normalised standard Gaussian vector (uniform on the sphere);
    radius: ``radius_m * U**(1/3)`` with U ~ U(0, 1), so that the number of
    points inside radius r grows as r**3, i.e. uniform density in volume.
    The same ``(n, radius_m, seed)`` always gives the same points.

    Args:
        n: number of basis points, >= 1.
        radius_m: ball radius, metres, > 0.
        seed: seed of ``numpy.random.default_rng``.

    Returns:
        (n, 3) float64, metres, generator frame (centre at the probe's
        volume centroid).
    """
    rng = np.random.default_rng(seed)
    direction = rng.standard_normal((n, 3))
    norm = np.linalg.norm(direction, axis=1, keepdims=True)
    # a Gaussian draw of exactly zero has no direction; vanishingly rare, but replace it deterministically
    direction = np.where(norm > 0.0, direction / np.where(norm > 0.0, norm, 1.0), np.array([0.0, 0.0, 1.0]))
    radius = radius_m * rng.uniform(0.0, 1.0, size=(n, 1)) ** (1.0 / 3.0)
    return direction * radius


def encode_probe(probe: Probe, theta_vol_deg, basis: np.ndarray, exact: bool = False) -> np.ndarray:
    """BPS feature of the probe placed in the generator frame with orientation Theta_Vol.

    For each basis point ``b_gen`` the feature is the distance to the nearest
    point of the probe surface: ``|sdf(T_probe_gen @ b_gen)|`` with
    ``T_probe_gen`` the inverse of :func:`~hupbench.datagen.grasps.frames.T_gen_probe`.
    Points inside the probe also get their (positive) distance to the surface,
    as in BPS.

    With ``exact=False`` the probe's gridded signed distance is used: within
    about 0.3 mm of the truth inside its grid box (the probe's bounding box
    plus a margin), an upper bound outside it that errs by about 1.5 mm at
    the median and up to about 17 mm at the ball's rim (0.15 m). Both modes
    are continuous in the basis point; a trained sampler must be fed the mode
    it was trained with. ``exact=True`` costs about 40 us a point.

    Args:
        probe: the :class:`hupbench.datagen.assets.probe.Probe` (see ``build_probe``).
        theta_vol_deg: (3,) Euler angles Theta_Vol, degrees, intrinsic x-y-z.
        basis: (n, 3) float, metres, generator frame (see :func:`basis_points`).
        exact: use the exact mesh distance instead of the grid.

    Returns:
        (n,) float32, metres, >= 0.
    """
    T = T_gen_probe(theta_vol_deg, probe)
    R, t = T[:3, :3], T[:3, 3]
    # p_gen = R p_probe + t  =>  p_probe = R^T (p_gen - t); row vectors: (p_gen - t) @ R
    points_probe = (np.asarray(basis, dtype=np.float64) - t) @ R
    sdf = probe.signed_distance_exact(points_probe) if exact else probe.signed_distance(points_probe)
    return np.abs(sdf).astype(np.float32)

