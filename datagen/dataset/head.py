"""Cameras where a sonographer's eyes can be: a free head above the patient, looking at the probe.

A head-worn camera (a headset) sees the probe from the sonographer's eyes. The sonographer stands or sits
beside the bed and looks down at the probe on the patient's abdomen, so the eyes are above the bed plane,
at arm's length or a little more from the probe, and the head is turned and tilted freely: the probe is
rarely at the centre of the image and the horizon is rarely level. :func:`head_cameras` draws such
cameras around a target point (keypoint 9, the middle-finger MCP):

1. the direction from the target to the camera uniformly over the spherical cap at least
   ``elevation_min_deg`` above the plane perpendicular to the room's vertical (uniform in azimuth and in
   the sine of the elevation: the cap's area element), and the distance uniformly in ``distance_m``;
2. the camera looks at the target with image up = the room's vertical projected on the image plane,
   which is the meridian's tangent towards the zenith, ``cos(e) vertical - sin(e) horizontal``; that
   formula stays defined at the zenith (e = 90 deg: up = away from the camera's azimuth) and is smooth
   in the elevation, so no look-at fallback is needed anywhere on the cap;
3. the head rolls about the optical axis by a uniform angle in +-``roll_deg``;
4. the head turns about the camera centre (the smallest rotation) so that the target projects to a
   pixel drawn uniformly within +-``aim_jitter`` of the image width and height around the principal
   point; the centre and the distance to the target are unchanged.

A camera whose centre the caller's ``clear`` refuses (inside the patient, in the arm) is redrawn.

Convention:
    Metres, degrees in the records, radians inside. The world is the probe frame; ``vertical_world`` is
    the room's up. Cameras are ``T_cam_world`` in OpenCV axes (x right, y down, z forward). Azimuth 0 is
    the horizontal axis :func:`horizontal_axes` derives from the vertical, azimuth 90 deg is
    ``vertical x azimuth-0``. Roll turns the camera's x axis towards its y axis about z (the scene turns
    anticlockwise in the image for a positive roll); roll 0 = image up along the vertical projected.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from hupbench.core.camera import Intrinsics
from hupbench.core.errors import BadValueError, RunFailedError
from hupbench.core.geometry import skew
from hupbench.core.input_checks import check_int, check_interval, check_number, is_number

#: the config node's dotted path, naming its keys in errors
NODE = "dataset.head"
#: camera distances a head can be at, metres (the configurable range must lie within)
DISTANCE_LIMITS_M = (0.1, 10.0)
#: rounds of redraws of refused cameras before giving up (a cap with 1 % clear room still fills)
MAX_DRAW_ROUNDS = 200


@dataclass(frozen=True)
class HeadSpec:
    """Where a sonographer's head-worn camera can be (config node ``dataset.head``).

    Attributes:
        distance_m: (min, max) camera to target distance, metres, drawn uniformly (continuously) in
            between; within 0.1-10 m, min <= max. 0.35-0.8 m: from a head bent over the probe to arm's
            length plus a step back.
        elevation_min_deg: the camera's least elevation above the bed plane seen from the target, degrees,
            in [0, 90). A sonographer standing or sitting beside the bed looks down at the probe on the
            abdomen; 25 deg keeps the eyes above the abdomen's flank (a camera lower than that would sit
            at or below the skin a few cm away, or look along the bed).
        aim_jitter: keypoint 9 lands uniformly within +-aim_jitter x the image width (height) of the
            principal point, in [0, 0.5).
        roll_deg: head roll, uniform in +-roll_deg about the optical axis, degrees, in [0, 180].
        views_per_grasp: cameras drawn per grasp, >= 1.
    """

    distance_m: tuple = (0.35, 0.8)
    elevation_min_deg: float = 25.0
    aim_jitter: float = 0.15
    roll_deg: float = 15.0
    views_per_grasp: int = 33

    def __post_init__(self) -> None:
        object.__setattr__(self, "distance_m", check_interval(self.distance_m, f"{NODE}.distance_m",
                                                             *DISTANCE_LIMITS_M, unit="m"))
        for name, high_open in (("elevation_min_deg", 90.0), ("aim_jitter", 0.5)):
            value = getattr(self, name)
            if not (is_number(value) and 0.0 <= value < high_open):
                raise BadValueError(f"{NODE}.{name} must be a finite number in [0, {high_open:g}), got {value!r}")
        check_number(self.roll_deg, f"{NODE}.roll_deg", 0.0, 180.0)
        check_int(self.views_per_grasp, f"{NODE}.views_per_grasp", low=1)


def horizontal_axes(vertical_world: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The room's frame from its vertical: azimuth 0, azimuth 90 deg and up, unit and right-handed.

    Azimuth 0 is the world axis least aligned with the vertical (ties go to x, then y) made
    perpendicular to it: a fixed choice for a given vertical.

    Args:
        vertical_world: (3,) float, the room's up in the world frame (any length > 0).

    Returns:
        (h0, h1, up), each (3,) float64, with ``h1 = up x h0``.
    """
    up = np.asarray(vertical_world, dtype=np.float64).reshape(3)
    norm = np.linalg.norm(up)
    assert np.isfinite(norm) and norm > 1e-12, vertical_world  # the patient's placement gives a unit vector
    up = up / norm
    axis = np.eye(3)[int(np.argmin(np.abs(up)))]
    h0 = axis - np.dot(axis, up) * up
    h0 /= np.linalg.norm(h0)
    return h0, np.cross(up, h0), up


def _draw(spec: HeadSpec, intrinsics: Intrinsics, n: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """``n`` cameras' random parameters, in a fixed order of draws (distance, elevation, azimuth, roll, aim)."""
    sin_low = math.sin(math.radians(spec.elevation_min_deg))
    distance = rng.uniform(*spec.distance_m, size=n)
    # uniform on the cap: the area element is d(sin e) d(azimuth)
    elevation = np.arcsin(rng.uniform(sin_low, 1.0, size=n))
    azimuth = rng.uniform(0.0, 2.0 * math.pi, size=n)
    roll = np.radians(rng.uniform(-spec.roll_deg, spec.roll_deg, size=n))
    offset = rng.uniform(-spec.aim_jitter, spec.aim_jitter, size=(n, 2)) * [intrinsics.width, intrinsics.height]
    aim = np.array([intrinsics.cx, intrinsics.cy]) + offset
    return {"distance_m": distance, "elevation": elevation, "azimuth": azimuth, "roll": roll, "aim_px": aim}


def head_poses(draws: dict[str, np.ndarray], intrinsics: Intrinsics, target_world: np.ndarray,
               vertical_world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Camera poses from drawn parameters (steps 2-4 of the module's construction).

    Args:
        draws: arrays of V cameras: "distance_m" (V,) metres; "elevation", "azimuth", "roll" (V,) radians;
            "aim_px" (V, 2) pixels where the target should land.
        intrinsics: the camera's pinhole intrinsics.
        target_world: (3,) metres, the point looked at (keypoint 9).
        vertical_world: (3,) the room's up.

    Returns:
        T_cam_world: (V, 4, 4) float64, OpenCV axes; centre_world: (V, 3) float64, metres.
    """
    h0, h1, up = horizontal_axes(vertical_world)
    target = np.asarray(target_world, dtype=np.float64).reshape(3)
    e, a, roll = draws["elevation"][:, None], draws["azimuth"][:, None], draws["roll"]
    horizontal = np.cos(a) * h0 + np.sin(a) * h1  # (V, 3) the camera's side of the target
    direction = np.cos(e) * horizontal + np.sin(e) * up  # (V, 3) target -> camera
    image_up = np.cos(e) * up - np.sin(e) * horizontal  # (V, 3) -d(direction)/de: the vertical projected
    z, y = -direction, -image_up  # OpenCV: z looks at the target, y points down the image
    R_world_cam = np.stack([np.cross(y, z), y, z], axis=2)  # (V, 3, 3) columns x, y, z
    c, s = np.cos(roll), np.sin(roll)
    Rz = np.zeros((len(roll), 3, 3))
    Rz[:, 0, 0], Rz[:, 0, 1], Rz[:, 1, 0], Rz[:, 1, 1], Rz[:, 2, 2] = c, -s, s, c, 1.0
    R_cam_world = np.swapaxes(R_world_cam @ Rz, 1, 2)
    # the ray of the aim pixel, and the smallest turn of the camera taking its optical axis there
    ray = np.column_stack([(draws["aim_px"][:, 0] - intrinsics.cx) / intrinsics.fx,
                           (draws["aim_px"][:, 1] - intrinsics.cy) / intrinsics.fy, np.ones(len(roll))])
    ray /= np.linalg.norm(ray, axis=1, keepdims=True)
    # Rodrigues with axis z x ray (unnormalised: |k| = sin) and 1 / (1 + cos); cos = ray_z > 0 here
    k = skew(np.column_stack([-ray[:, 1], ray[:, 0], np.zeros(len(roll))]))
    turn = np.eye(3) + k + (k @ k) / (1.0 + ray[:, 2])[:, None, None]
    R = turn @ R_cam_world
    centre = target + draws["distance_m"][:, None] * direction
    T_cam_world = np.tile(np.eye(4), (len(roll), 1, 1))
    T_cam_world[:, :3, :3] = R
    T_cam_world[:, :3, 3] = -np.einsum("vij,vj->vi", R, centre)
    return T_cam_world, centre


def head_cameras(spec: HeadSpec, intrinsics: Intrinsics, target_world: np.ndarray, vertical_world: np.ndarray,
                 clear: Callable[[np.ndarray], np.ndarray], rng: np.random.Generator) -> dict[str, np.ndarray]:
    """``spec.views_per_grasp`` head cameras looking at ``target_world`` from above (see the module).

    Cameras are drawn in rounds: a round draws every missing camera, keeps those whose centre ``clear``
    accepts (in draw order) and redraws the rest from the same ``rng``.

    Args:
        spec: the head's ranges.
        intrinsics: the camera's pinhole intrinsics (the aim box is relative to its size and principal point).
        target_world: (3,) float, metres, world (probe) frame: keypoint 9, where the camera looks.
        vertical_world: (3,) float, the room's up in the world frame (any length > 0).
        clear: maps camera centres (N, 3) metres, world frame, to (N,) bool: True where a camera may be
            (outside the patient, clear of the arm).
        rng: the random generator; the same generator state gives the same cameras.

    Returns:
        {"T_cam_world": (V, 4, 4) float64 OpenCV axes; "distance_m": (V,) camera centre to target, metres;
        "elevation_deg", "azimuth_deg" (V,) of the target -> camera direction, degrees (azimuth in
        [0, 360)); "roll_deg": (V,) degrees; "aim_px": (V, 2) float64 pixels (u, v) where the target
        projects}, V = ``spec.views_per_grasp``.

    Raises:
        RunFailedError: some cameras are still refused by ``clear`` after :data:`MAX_DRAW_ROUNDS` rounds.
    """
    wanted = spec.views_per_grasp
    kept: list[dict[str, np.ndarray]] = []
    have = 0
    for _ in range(MAX_DRAW_ROUNDS):
        draws = _draw(spec, intrinsics, wanted - have, rng)
        T_cam_world, centre = head_poses(draws, intrinsics, target_world, vertical_world)
        ok = np.asarray(clear(centre), dtype=bool).reshape(len(centre))
        kept.append({key: value[ok] for key, value in draws.items()} | {"T_cam_world": T_cam_world[ok]})
        have += int(ok.sum())
        if have == wanted:
            break
    else:
        raise RunFailedError(
            f"{wanted - have} of {wanted} head cameras are still inside the patient or the arm after "
            f"{MAX_DRAW_ROUNDS} rounds of redraws: too little of the cap above {NODE}.elevation_min_deg = "
            f"{spec.elevation_min_deg:g} deg within {NODE}.distance_m = {list(spec.distance_m)} is clear")
    out = {key: np.concatenate([k[key] for k in kept]) for key in kept[0]}
    return {"T_cam_world": out["T_cam_world"], "distance_m": out["distance_m"],
            "elevation_deg": np.degrees(out["elevation"]), "azimuth_deg": np.degrees(out["azimuth"]),
            "roll_deg": np.degrees(out["roll"]), "aim_px": out["aim_px"]}
