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
0 first) to the south pole (the last), the published renderer's order.

Two ways to attach the sphere to the hand (``axis``):

``"body"`` (default, the published renderer): the camera stays fixed and the
    whole SMPL-H body (a T-pose: right arm straight out sideways, palm down)
    is turned by (90 deg - theta) about X, then by -phi about Y (intrinsic
    X-Y), with the right middle-finger MCP put at distance z_ego in front of
    the camera. Seen from the hand, the sphere's polar axis is the body's
    vertical, perpendicular to the straight forearm: north is the BACK OF
    THE HAND (dorsal: the palm faces down in the T-pose). Longitude 0 is the
    body's front, which for the right hand is the thumb (radial) side,
    ``forearm_axis x dorsal``; longitude 90 deg is the elbow (the forearm at
    theta = 90, phi = 90 deg). Image "up" is the body's vertical: the
    meridian's tangent towards the north pole, which stays defined at the
    poles (north pole, looking down on the back of the hand: up is the
    body's back, the little-finger side; south pole: up is the thumb side,
    the body's front). The published renderer drops the two views 10 deg
    off the elbow-side forearm axis (theta 80 / 100 deg, phi 90 deg: ids 34
    and 50), looking into the hollow of the arm, and keeps both poles:
    ``exclude=("elbow",)`` with ``elbow_cone_deg=10``.
``"forearm"`` (the "forearm_box_centre" protocol): the polar axis is the forearm,
    north = from the hand towards the elbow; longitude 0 is the dorsal
    direction. Image "up" is the fingers' direction (-north); at the poles,
    where that is parallel to the view, the dorsal direction. The two poles
    (along the forearm) were excluded: ``exclude=("poles",)``.

Convention:
    Metres and radians. A sphere frame is a (3, 3) matrix whose columns are,
    in the world frame, longitude 0, longitude 90 deg and north. Camera
    poses are ``T_cam_world`` in OpenCV axes (x right, y down, z forward).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from hupbench.core.camera import look_at
from hupbench.core.geometry import invert_transform, make_transform
from hupbench.core.input_checks import check_number, check_shape, is_whole
from hupbench.core.errors import BadValueError

VARIANTS = ("ceil", "floor")
AXES = ("body", "forearm")
#: named exclusion rules: "poles" = both poles; "elbow" = views within ``elbow_cone_deg`` of the
#: elbow-side forearm axis
EXCLUDE_RULES = ("poles", "elbow")
#: slack on the elbow cone, degrees: the published excluded views sit exactly on its edge (10 deg)
_CONE_SLACK_DEG = 1e-6


@dataclass(frozen=True)
class SphereSpec:
    """Viewpoint sphere parameters.

    Attributes:
        r_sph_m, r_circ_m: sphere and circle radii, metres (r_circ < r_sph).
        variant: "ceil" (published code, 92 views) or "floor" (paper's formula, 82).
        axis: "body" (published renderer: polar axis = the body's vertical = dorsal direction,
            perpendicular to the forearm) or "forearm" (polar axis along the forearm).
        exclude: view ids and/or rules left out: "poles", "elbow" (views within
            ``elbow_cone_deg`` of the hand -> elbow direction). Default: the published renderer's
            two exclusions.
        elbow_cone_deg: half-angle of the "elbow" rule's cone, degrees, in [0, 180).
    """

    r_sph_m: float = 0.8
    r_circ_m: float = 0.15
    variant: str = "ceil"
    axis: str = "body"
    exclude: tuple = ("elbow",)
    elbow_cone_deg: float = 10.0

    def __post_init__(self) -> None:
        for name in ("r_sph_m", "r_circ_m"):
            check_number(getattr(self, name), f"sphere {name}", 0, low_open=True)
        if self.r_circ_m >= self.r_sph_m:
            raise BadValueError(f"sphere r_circ_m ({self.r_circ_m}) must be smaller than r_sph_m ({self.r_sph_m})")
        for name, allowed in (("variant", VARIANTS), ("axis", AXES)):
            if getattr(self, name) not in allowed:
                raise BadValueError(f"sphere {name} must be one of {allowed}, got {getattr(self, name)!r}")
        check_number(self.elbow_cone_deg, "sphere elbow_cone_deg", 0, 180)
        exclude = tuple(self.exclude or ())
        unknown = [e for e in exclude if not (e in EXCLUDE_RULES if isinstance(e, str) else is_whole(e))]
        if unknown:
            raise BadValueError(f"sphere exclude rules are {EXCLUDE_RULES} (or view ids), got {unknown[0]!r}")
        object.__setattr__(self, "exclude", exclude)
        viewpoints(self)  # view ids beyond the sphere, or no view left: refused here, not while rendering


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


def unit_directions(angles: np.ndarray) -> np.ndarray:
    """Points of the unit sphere in sphere coordinates.

    Args:
        angles: (V, 2) (theta, phi) radians.

    Returns:
        (V, 3) float64 unit vectors (longitude 0, longitude 90 deg, north components): the
        direction from the target to the camera.
    """
    angles = check_shape(np.asarray(angles, dtype=np.float64), ("V", 2), "angles (theta, phi)")
    theta, phi = angles[:, 0], angles[:, 1]
    return np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], axis=1)


def elbow_direction(axis: str) -> np.ndarray:
    """(3,) the hand -> elbow direction in sphere coordinates of the given ``axis``."""
    assert axis in AXES, axis  # SphereSpec checked it
    # body: longitude 90 deg on the equator (the published renderer's theta = phi = 90 deg);
    # forearm: the north pole
    return np.array([0.0, 1.0, 0.0]) if axis == "body" else np.array([0.0, 0.0, 1.0])


@functools.lru_cache(maxsize=16)
def excluded_view_ids(spec: SphereSpec) -> tuple[int, ...]:
    """Ids (into :func:`all_viewpoints`) that ``spec.exclude`` leaves out, ascending."""
    angles = all_viewpoints(spec)
    total = len(angles)
    excluded = set()
    for e in spec.exclude:
        if e == "poles":
            excluded |= {0, total - 1}
        elif e == "elbow":
            cosine = unit_directions(angles) @ elbow_direction(spec.axis)
            within = np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0))) <= spec.elbow_cone_deg + _CONE_SLACK_DEG
            excluded |= {int(i) for i in np.flatnonzero(within)}
        elif not 0 <= e < total:
            raise BadValueError(f"sphere exclude id {e} is not a view: ids are 0..{total - 1}")
        else:
            excluded.add(int(e))
    return tuple(sorted(excluded))


@functools.lru_cache(maxsize=16)
def viewpoints(spec: SphereSpec) -> tuple[np.ndarray, np.ndarray]:
    """The views in use after exclusions (cached per spec; the arrays are read-only).

    Returns:
        view_ids: (V',) int64 ids into :func:`all_viewpoints`; angles: (V', 2) (theta, phi) radians.
    """
    angles = all_viewpoints(spec)
    excluded = set(excluded_view_ids(spec))
    ids = np.array([i for i in range(len(angles)) if i not in excluded], dtype=np.int64)
    if len(ids) == 0:
        raise BadValueError("the sphere exclusions leave no view")
    kept = angles[ids]
    ids.setflags(write=False)
    kept.setflags(write=False)
    return ids, kept


def arm_frame(forearm_axis: np.ndarray, dorsal: np.ndarray) -> np.ndarray:
    """(3, 3) columns: hand -> elbow, dorsal, radial (thumb side of a right hand), in the world frame.

    Args:
        forearm_axis: (3,) direction from the hand towards the elbow.
        dorsal: (3,) the back-of-hand direction (made orthogonal to the axis).

    Returns:
        (3, 3) float64 rotation; the third column is ``forearm_axis x dorsal``.
    """
    elbow = np.asarray(forearm_axis, dtype=np.float64).reshape(3)
    norm = np.linalg.norm(elbow)
    # both are columns of a grasp's wrist rotation: unit and orthogonal
    assert np.isfinite(norm) and norm > 1e-12, elbow
    elbow = elbow / norm
    back = np.asarray(dorsal, dtype=np.float64).reshape(3)
    back = back - np.dot(back, elbow) * elbow
    assert np.linalg.norm(back) > 1e-9, (forearm_axis, dorsal)
    back /= np.linalg.norm(back)
    return np.stack([elbow, back, np.cross(elbow, back)], axis=1)


def sphere_frame(forearm_axis: np.ndarray, dorsal: np.ndarray, axis: str) -> np.ndarray:
    """(3, 3) columns longitude 0, longitude 90 deg, north of the sphere in the world frame.

    Args:
        forearm_axis: (3,) direction from the hand towards the elbow.
        dorsal: (3,) the back-of-hand direction (made orthogonal to the axis).
        axis: "body": north = dorsal, longitude 0 = radial (thumb side), longitude 90 deg =
            elbow; "forearm": north = elbow, longitude 0 = dorsal, longitude 90 deg = radial.
    """
    assert axis in AXES, axis
    elbow, back, radial = arm_frame(forearm_axis, dorsal).T
    columns = (radial, elbow, back) if axis == "body" else (back, radial, elbow)
    return np.stack(columns, axis=1)


def camera_pose(theta: float, phi: float, distance_m: float, target_world: np.ndarray,
                frame: np.ndarray, axis: str) -> np.ndarray:
    """``T_cam_world`` (OpenCV) of one viewpoint: the camera ``distance_m`` from the target, looking at it.

    Args:
        theta, phi: polar angle from north and longitude, radians.
        distance_m: camera to target, metres (> 0).
        target_world: (3,) the point looked at; it lands at (0, 0, distance_m) in the camera frame.
        frame: (3, 3) from :func:`sphere_frame` with the same ``axis``.
        axis: "body" (image up = the meridian towards north, as the published renderer's body
            rotation gives; defined at the poles too) or "forearm" (up = -north, the fingers; at
            the poles longitude 0, the dorsal direction).

    Returns:
        (4, 4) float64.
    """
    assert math.isfinite(distance_m) and distance_m > 0 and axis in AXES, (distance_m, axis)  # the specs checked them
    frame = np.asarray(frame, dtype=np.float64)
    target = np.asarray(target_world, dtype=np.float64).reshape(3)
    st, ct, sp, cp = math.sin(theta), math.cos(theta), math.sin(phi), math.cos(phi)
    direction = frame @ np.array([st * cp, st * sp, ct])
    if axis == "forearm":
        at_pole = abs(st) < 1e-9
        up = frame[:, 0] if at_pole else -frame[:, 2]
        return look_at(target + distance_m * direction, target, up_world=up)
    # -d(direction)/d(theta): unit, orthogonal to the view and smooth through the poles, so the
    # camera needs no look-at special case anywhere on the sphere
    up = frame @ np.array([-ct * cp, -ct * sp, st])
    z = -direction  # OpenCV z looks from the camera at the target
    y = -up  # OpenCV y points down in the image
    R_world_cam = np.stack([np.cross(y, z), y, z], axis=1)
    T_cam_world = invert_transform(make_transform(R_world_cam, target + distance_m * direction))
    # put the target exactly on the optical axis (the inverse's rounding would leave ~1e-17 m)
    T_cam_world[:3, 3] = np.array([0.0, 0.0, distance_m]) - T_cam_world[:3, :3] @ target
    return T_cam_world
