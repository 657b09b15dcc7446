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
    volume centroid, see :mod:`datagen.grasps.frames`. Features are unsigned
    distances in metres.
"""

from __future__ import annotations

import numpy as np

from datagen.grasps.frames import T_gen_probe, check_euler_deg
from datagen.assets.probe import Probe
from datagen.input_checks import check_int
from datagen.errors import BadTypeError, BadValueError

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

    Raises:
        TypeError: ``n`` or ``seed`` is not an integer.
        ValueError: ``n < 1`` or ``radius_m`` not a finite positive number.
    """
    check_int(n, "n", low=1, error=BadTypeError)
    check_int(seed, "seed", error=BadTypeError)
    radius_m = float(radius_m)
    if not (np.isfinite(radius_m) and radius_m > 0.0):
        raise BadValueError(f"radius_m must be a finite positive number of metres, got {radius_m}")
    rng = np.random.default_rng(seed)
    direction = rng.standard_normal((n, 3))
    norm = np.linalg.norm(direction, axis=1, keepdims=True)
    # a Gaussian draw of exactly zero has no direction; vanishingly rare, but replace it deterministically
    direction = np.where(norm > 0.0, direction / np.where(norm > 0.0, norm, 1.0), np.array([0.0, 0.0, 1.0]))
    radius = radius_m * rng.uniform(0.0, 1.0, size=(n, 1)) ** (1.0 / 3.0)
    return direction * radius


def _check_probe(probe) -> None:
    if not isinstance(probe, Probe):
        raise BadTypeError(f"probe must be a datagen.assets.probe.Probe (see build_probe), got {type(probe).__name__}")


def _check_basis(basis: np.ndarray) -> np.ndarray:
    arr = np.asarray(basis)
    if arr.dtype == object or not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)):
        raise BadValueError(f"basis must be a real array, got dtype {arr.dtype}")
    if arr.ndim != 2 or arr.shape[1] != 3 or arr.shape[0] < 1:
        raise BadValueError(f"basis must be (n, 3) with n >= 1, got {tuple(arr.shape)}")
    arr = arr.astype(np.float64, copy=False)
    if not np.all(np.isfinite(arr)):
        raise BadValueError("basis contains NaN or inf")
    return arr


def _distances(probe: Probe, points_probe: np.ndarray, exact: bool) -> np.ndarray:
    sdf = probe.signed_distance_exact(points_probe) if exact else probe.signed_distance(points_probe)
    return np.abs(sdf).astype(np.float32)


def encode_probe(probe: Probe, theta_vol_deg, basis: np.ndarray, exact: bool = False) -> np.ndarray:
    """BPS feature of the probe placed in the generator frame with orientation Theta_Vol.

    For each basis point ``b_gen`` the feature is the distance to the nearest
    point of the probe surface: ``|sdf(T_probe_gen @ b_gen)|`` with
    ``T_probe_gen`` the inverse of :func:`~datagen.grasps.frames.T_gen_probe`.
    Points inside the probe also get their (positive) distance to the surface,
    as in BPS.

    With ``exact=False`` the probe's gridded signed distance is used: within
    about 0.3 mm of the truth inside its grid box (the probe's bounding box
    plus a margin), an upper bound outside it that errs by about 1.5 mm at
    the median and up to about 17 mm at the ball's rim (0.15 m). Both modes
    are continuous in the basis point; a trained sampler must be fed the mode
    it was trained with. ``exact=True`` costs about 40 us a point.

    Args:
        probe: the :class:`datagen.assets.probe.Probe` (see ``build_probe``).
        theta_vol_deg: (3,) Euler angles Theta_Vol, degrees, intrinsic x-y-z.
        basis: (n, 3) float, metres, generator frame (see :func:`basis_points`).
        exact: use the exact mesh distance instead of the grid.

    Returns:
        (n,) float32, metres, >= 0.

    Raises:
        TypeError: ``probe`` is not a Probe.
        ValueError: Theta_Vol not one finite triple; basis not a finite (n, 3) array.
    """
    _check_probe(probe)
    basis = _check_basis(basis)
    T = T_gen_probe(theta_vol_deg, probe)  # validates Theta_Vol
    R, t = T[:3, :3], T[:3, 3]
    # p_gen = R p_probe + t  =>  p_probe = R^T (p_gen - t); row vectors: (p_gen - t) @ R
    points_probe = (basis - t) @ R
    return _distances(probe, points_probe, exact)


def encode_many(probe: Probe, thetas_deg, basis: np.ndarray, exact: bool = False) -> np.ndarray:
    """:func:`encode_probe` for several orientations, in one batched distance query.

    Args:
        probe: the :class:`datagen.assets.probe.Probe`.
        thetas_deg: (N, 3) Euler angles Theta_Vol, degrees, N >= 1.
        basis: (n, 3) float, metres, generator frame.
        exact: as in :func:`encode_probe`.

    Returns:
        (N, n) float32, metres, >= 0; row i equals ``encode_probe(probe, thetas_deg[i], basis)``.

    Raises:
        TypeError: ``probe`` is not a Probe.
        ValueError: thetas not a finite (N, 3) array with N >= 1; bad basis.
    """
    _check_probe(probe)
    basis = _check_basis(basis)
    thetas = check_euler_deg(thetas_deg)
    if thetas.ndim != 2 or thetas.shape[0] < 1:
        raise BadValueError(f"thetas_deg must be (N, 3) with N >= 1, got {thetas.shape}")
    T = np.stack([T_gen_probe(theta, probe) for theta in thetas])  # (N, 4, 4)
    R, t = T[:, :3, :3], T[:, :3, 3]
    points_probe = np.einsum("nbi,nij->nbj", basis[None] - t[:, None, :], R)  # (N, n, 3), R^T (b - t)
    return _distances(probe, points_probe, exact)
