"""The generator frame and the probe z-offset (HUP-3D's "polygon offset" correction).

GrabNet-style generators work object-centric: the probe, rotated by its
Euler angles Theta_Vol, sits with its volume centroid at the origin. The
renderer, as in HUP-3D, puts the probe frame's origin (the lens apex) at the
world origin. The two placements differ by the centroid, whose z is the
paper's Delta z (the probe is mirror-symmetric in x and y, so x and y are 0):
``p_gen = R_vol @ (p_probe - c)``, ``c = (0, 0, Delta z)``.

Convention:
    Theta_Vol: (alpha, beta, gamma) degrees, intrinsic x-y-z Euler angles
    (R_vol = Rx(alpha) Ry(beta) Rz(gamma)); any real values are accepted, 0
    and 360 give the same rotation. Metres.
"""

from __future__ import annotations

import functools

import numpy as np

from hupbench.core.geometry import euler_to_matrix, make_transform
from hupbench.core.errors import BadValueError


def volume_centroid(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Centroid of the solid bounded by a closed, outward-wound triangle mesh.

    Sums signed tetrahedra (origin, triangle); exact for any closed mesh.

    Args:
        vertices: (V, 3) float, metres. faces: (F, 3) int.

    Returns:
        (3,) float64, metres.
    """
    tri = np.asarray(vertices, dtype=np.float64)[np.asarray(faces)]
    volumes = np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])) / 6.0
    total = volumes.sum()
    assert total > 0, f"the mesh is closed and outward-wound (signed volume {total:.3e} m^3)"
    return (volumes[:, None] * tri.sum(axis=1) / 4.0).sum(axis=0) / total


@functools.lru_cache(maxsize=8)
def probe_z_offset(probe) -> float:
    """Delta z: the height of the probe's volume centroid above the lens apex, metres (cached per probe)."""
    return float(volume_centroid(probe.mesh.vertices, probe.mesh.faces)[2])


#: Theta_Vol angles beyond one turn either way are refused
MAX_EULER_DEG = 360.0


def check_euler_deg(theta_vol) -> np.ndarray:
    """One Theta_Vol triple or a list of them as given by a user: (3,) or (N, 3) finite degrees."""
    try:
        theta = np.asarray(theta_vol, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise BadValueError(f"Theta_Vol must be numbers [alpha, beta, gamma] or a list of them, got {theta_vol!r}") from exc
    if theta.ndim not in (1, 2) or theta.shape[-1] != 3:
        raise BadValueError(f"Theta_Vol must be [alpha, beta, gamma] degrees or a list of them, got shape {theta.shape}")
    if not np.all(np.isfinite(theta)):
        raise BadValueError(f"Theta_Vol must be finite, got {theta.tolist()}")
    if np.any(np.abs(theta) > MAX_EULER_DEG):
        # an angle beyond a turn is a typo (radians, a lost sign or decimal point); far beyond, float64
        # degrees lose the precision of the rotation
        raise BadValueError(f"Theta_Vol angles must be degrees in [-{MAX_EULER_DEG:g}, {MAX_EULER_DEG:g}], "
                         f"got {theta.tolist()}")
    return theta


def T_gen_probe(theta_vol_deg, probe) -> np.ndarray:
    """Probe frame -> generator frame.

    Args:
        theta_vol_deg: (3,) Euler angles Theta_Vol, degrees (from a checked ``GraspGenConfig`` or drawn
            for the corpus).
        probe: a :class:`hupbench.datagen.assets.probe.Probe`.

    Returns:
        (4, 4) float64 ``T_gen_probe``.
    """
    theta = np.asarray(theta_vol_deg, dtype=np.float64)
    assert theta.shape == (3,), theta.shape
    R_vol = euler_to_matrix(np.deg2rad(theta), "xyz")
    centroid = np.array([0.0, 0.0, probe_z_offset(probe)])
    return make_transform(R_vol, -R_vol @ centroid)
