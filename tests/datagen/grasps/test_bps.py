"""Tests for the Basis Point Set encoding of the probe (datagen/grasps/bps.py)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy import stats

from hupbench.core.geometry import euler_to_matrix, transform_points
from hupbench.datagen.grasps.bps import basis_points, encode_probe
from hupbench.datagen.grasps.frames import T_gen_probe, probe_z_offset
from hupbench.datagen.assets.probe import Probe, build_probe

MM = 1e-3
#: the probe's gridded signed distance is within a few tenths of a millimetre of the mesh
GRID_ERROR_M = 0.5 * MM


@pytest.fixture(scope="module")
def probe() -> Probe:
    return build_probe()


@pytest.fixture(scope="module")
def basis() -> np.ndarray:
    return basis_points(256, seed=3)


# ----------------------------------------------------------------------------- basis points


def test_basis_points_are_uniform_in_the_ball():
    radius_m = 0.15
    points = basis_points(20000, radius_m=radius_m, seed=0)
    assert points.shape == (20000, 3)
    r = np.linalg.norm(points, axis=1)
    assert r.max() <= radius_m
    # uniform in volume: P(|p| < R/2) = (1/2)^3; binomial std here is 0.0023
    assert abs(np.mean(r < radius_m / 2) - 1 / 8) < 0.01
    # the whole radial law: (r/R)^3 ~ U(0, 1)
    assert stats.kstest((r / radius_m) ** 3, "uniform").pvalue > 1e-3
    # isotropic: centred at the origin, E[x^2] = R^2 / 5 on every axis
    np.testing.assert_allclose(points.mean(axis=0), 0.0, atol=3e-3)
    np.testing.assert_allclose((points**2).mean(axis=0), radius_m**2 / 5, rtol=0.05)


def test_basis_points_deterministic_by_seed():
    a = basis_points(64, seed=7)
    np.testing.assert_array_equal(a, basis_points(64, seed=7))
    assert np.abs(a - basis_points(64, seed=8)).max() > 1e-3
    # the radius scales the same draw
    np.testing.assert_allclose(basis_points(64, radius_m=0.3, seed=7), 2.0 * a)


# ----------------------------------------------------------------------------- encoding


def test_encoding_is_rotation_consistent(probe, basis):
    Rz90 = euler_to_matrix(np.deg2rad([0.0, 0.0, 90.0]))
    plain = encode_probe(probe, (0.0, 0.0, 0.0), basis)
    turned = encode_probe(probe, (0.0, 0.0, 90.0), basis @ Rz90.T)
    np.testing.assert_allclose(turned, plain, atol=1e-6)
    # any orientation: rotating the basis with the probe leaves the features unchanged
    theta = (25.0, -40.0, 130.0)
    R_vol = euler_to_matrix(np.deg2rad(theta))
    np.testing.assert_allclose(encode_probe(probe, theta, basis @ R_vol.T), plain, atol=1e-6)
    # ... while the same basis sees a different probe placement
    assert np.abs(encode_probe(probe, theta, basis) - plain).max() > 0.01


def test_features_nonnegative_and_zero_on_the_surface(probe):
    theta = (30.0, 10.0, -60.0)
    surface_probe, _ = trimesh.sample.sample_surface(probe.mesh, 200, seed=1)
    surface_gen = transform_points(T_gen_probe(theta, probe), surface_probe)
    features = encode_probe(probe, theta, surface_gen)
    assert features.dtype == np.float32 and features.shape == (200,)
    assert features.min() >= 0.0
    assert features.max() < GRID_ERROR_M
    assert encode_probe(probe, theta, surface_gen, exact=True).max() < 1e-6
    features = encode_probe(probe, theta, basis_points(2000, seed=5))
    assert features.min() >= 0.0


def test_known_distance_below_the_lens(probe):
    # 10 mm straight below the lens apex (the probe frame's origin); the lens
    # curves away with a 55 mm radius, so the apex is the nearest surface point
    below_probe = np.array([[0.0, 0.0, -0.010]])
    below_gen = below_probe - np.array([0.0, 0.0, probe_z_offset(probe)])
    np.testing.assert_allclose(encode_probe(probe, (0, 0, 0), below_gen, exact=True), [0.010], atol=1e-6)
    np.testing.assert_allclose(encode_probe(probe, (0, 0, 0), below_gen), [0.010], atol=GRID_ERROR_M)
    # at the generator origin (the volume centroid, inside the probe) the depth is
    # at most the probe's half thickness in y
    inside = encode_probe(probe, (0, 0, 0), np.zeros((1, 3)), exact=True)[0]
    assert 0.0 < inside <= probe.mesh.bounds[1, 1]


def test_grid_upper_bounds_exact(probe, basis):
    grid = encode_probe(probe, (10.0, 20.0, 30.0), basis)
    exact = encode_probe(probe, (10.0, 20.0, 30.0), basis, exact=True)
    assert np.all(grid >= exact - GRID_ERROR_M)
    assert np.median(grid - exact) < 5 * MM
