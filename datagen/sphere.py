"""The camera viewpoint sphere of HUP-3D (paper Sec. 2.2).

Circles of radius ``r_circ`` are packed on a sphere of radius ``r_sph``:
``N_lat = ceil(pi / (2 asin(r_circ / r_sph)))`` latitude bands, latitudes
``theta_i = i pi / N_lat`` for ``i = 1 .. N_lat - 1``, each ring holding
``floor(2 pi r_sph sin(theta_i) / (2 r_circ))`` views at equal longitudes,
plus the two poles. With r_sph = 0.8 m and r_circ = 0.15 m: N_lat = 9,
rings of 5, 10, 14, 16, 16, 14, 10, 5 = 90 views, + 2 poles = 92. This is
what the published code computes; the paper's formula writes floor, which
gives N_lat = 8 (rings 6, 11, 15, 16, 15, 11, 6 = 80, + 2 = 82):
``variant="floor"`` selects it.

Views are numbered from the north pole (view 0) ring by ring (longitude
0 first) to the south pole (the last). By default the two poles are
excluded: they look along the forearm, one of them through the arm
(the paper's "92 - 2 excluded = 90").

Convention:
    The sphere's polar axis is the forearm axis of the grasp: north = from
    the hand towards the elbow. Longitude 0 is the hand's dorsal direction.
    Cameras stand ``distance`` from the target, look at it, and keep the
    fingers "up" in the image (up vector = the pointing direction of the
    fingers, -polar axis); at the poles, where that is parallel to the view,
    the up vector is the dorsal direction. Metres and radians.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from datagen.camera import look_at

VARIANTS = ("ceil", "floor")


@dataclass(frozen=True)
class SphereSpec:
    """Viewpoint sphere parameters.

    Attributes:
        r_sph_m, r_circ_m: sphere and circle radii, metres (r_circ < r_sph).
        variant: "ceil" (published code, 92 views) or "floor" (paper's formula, 82).
        exclude: view ids left out (default: the two poles of the ceil variant).
    """

    r_sph_m: float = 0.8
    r_circ_m: float = 0.15
    variant: str = "ceil"
    exclude: tuple = ("poles",)

    def __post_init__(self) -> None:
        for name in ("r_sph_m", "r_circ_m"):
            v = getattr(self, name)
            if not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
                raise ValueError(f"sphere {name} must be positive and finite, got {v!r}")
        if self.r_circ_m >= self.r_sph_m:
            raise ValueError(f"sphere r_circ_m ({self.r_circ_m}) must be smaller than r_sph_m ({self.r_sph_m})")
        if self.variant not in VARIANTS:
            raise ValueError(f"sphere variant must be one of {VARIANTS}, got {self.variant!r}")
        exclude = tuple(self.exclude or ())
        for e in exclude:
            if e != "poles" and (isinstance(e, bool) or not isinstance(e, int)):
                raise ValueError(f"sphere exclude entries must be view ids or 'poles', got {e!r}")
        object.__setattr__(self, "exclude", exclude)


def latitude_count(spec: SphereSpec) -> int:
    """N_lat of the chosen variant."""
    x = math.pi / (2.0 * math.asin(spec.r_circ_m / spec.r_sph_m))
    return math.ceil(x) if spec.variant == "ceil" else math.floor(x)


def all_viewpoints(spec: SphereSpec) -> np.ndarray:
    """Every view of the sphere, poles included.

    Returns:
        (V, 2) float64 (theta, phi) radians: polar angle from north, longitude.
    """
    n_lat = latitude_count(spec)
    views = [(0.0, 0.0)]
    for i in range(1, n_lat):
        theta = i * math.pi / n_lat
        n_ring = math.floor(2.0 * math.pi * spec.r_sph_m * math.sin(theta) / (2.0 * spec.r_circ_m))
        views += [(theta, 2.0 * math.pi * j / n_ring) for j in range(n_ring)]
    views.append((math.pi, 0.0))
    return np.array(views)


@functools.lru_cache(maxsize=16)
def viewpoints(spec: SphereSpec = SphereSpec()) -> tuple[np.ndarray, np.ndarray]:
    """The views in use after exclusions (cached per spec; the arrays are read-only).

    Returns:
        view_ids: (V',) int64 ids into :func:`all_viewpoints`; angles: (V', 2) (theta, phi) radians.
    """
    angles = all_viewpoints(spec)
    total = len(angles)
    excluded = set()
    for e in spec.exclude:
        if e == "poles":
            excluded |= {0, total - 1}
        elif not 0 <= e < total:
            raise ValueError(f"sphere exclude id {e} is not a view: ids are 0..{total - 1}")
        else:
            excluded.add(e)
    ids = np.array([i for i in range(total) if i not in excluded], dtype=np.int64)
    if len(ids) == 0:
        raise ValueError("the sphere exclusions leave no view")
    kept = angles[ids]
    ids.setflags(write=False)
    kept.setflags(write=False)
    return ids, kept


def sphere_frame(forearm_axis: np.ndarray, dorsal: np.ndarray) -> np.ndarray:
    """(3, 3) columns x (longitude 0), y, z (north) of the sphere in the world frame.

    Args:
        forearm_axis: (3,) direction from the hand towards the elbow.
        dorsal: (3,) the back-of-hand direction (made orthogonal to the axis).
    """
    z = np.asarray(forearm_axis, dtype=np.float64)
    z = z / np.linalg.norm(z)
    x = np.asarray(dorsal, dtype=np.float64) - (np.dot(dorsal, z)) * z
    if np.linalg.norm(x) < 1e-9:
        raise ValueError("the dorsal direction must not be parallel to the forearm axis")
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(z, x), z], axis=1)


def camera_pose(theta: float, phi: float, distance_m: float, target_world: np.ndarray,
                frame: np.ndarray) -> np.ndarray:
    """``T_cam_world`` (OpenCV) of one viewpoint.

    Args:
        theta, phi: polar angle from north and longitude, radians.
        distance_m: camera to target, metres (> 0).
        target_world: (3,) the point looked at.
        frame: (3, 3) from :func:`sphere_frame`.

    Returns:
        (4, 4) float64.
    """
    if not math.isfinite(distance_m) or distance_m <= 0:
        raise ValueError(f"camera distance must be positive, got {distance_m!r}")
    direction = frame @ np.array([math.sin(theta) * math.cos(phi), math.sin(theta) * math.sin(phi), math.cos(theta)])
    at_pole = math.sin(theta) < 1e-9
    up = frame[:, 0] if at_pole else -frame[:, 2]
    return look_at(np.asarray(target_world) + distance_m * direction, target_world, up_world=up)
