"""The eight built-in backgrounds, painted procedurally with numpy and OpenCV.

HUP-3D's photographs (plain white, a consultation room, 3 x an ultrasound fetal phantom scene and
3 x real pregnant abdomens) are not redistributable; these are stand-ins of the same categories.
:data:`SCENES` holds one painter per built-in, in the order of
:data:`hupbench.datagen.assets.backgrounds.BUILTIN_NAMES`; :mod:`hupbench.datagen.assets.backgrounds` crops, resizes and caches them.

Convention:
    Canvases are float32 RGB in [0, 1], (BASE_PX, BASE_PX, 3); masks are float32 coverage in
    [0, 1]. Every random field comes from ``np.random.default_rng`` with a fixed seed per
    background, so two calls and two processes give the same pixels.
"""

from __future__ import annotations

import functools
from typing import Callable, Sequence

import cv2
import numpy as np

#: side of the square canvas every built-in is painted on, pixels
BASE_PX = 512

Float3 = tuple[float, float, float]


# --------------------------------------------------------------------------- painting helpers
# Canvases are float32 RGB in [0, 1]; masks are float32 coverage in [0, 1].


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Dot product over the last axis (length 3), written out: ``a @ b`` goes through BLAS, whose kernel
    (chosen by the CPU) changes the last bits, and with them a pixel here and there and the fingerprint."""
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1] + a[..., 2] * b[..., 2]


def _grid(size: int) -> tuple[np.ndarray, np.ndarray]:
    """Pixel-centre coordinates (x, y), each (size, size) float32, pixels."""
    coords = np.arange(size, dtype=np.float32)
    return np.meshgrid(coords, coords)


def _smooth_noise(rng: np.random.Generator, size: int, cells: int | tuple[int, int]) -> np.ndarray:
    """Band-limited noise: a cells_y x cells_x random grid upsampled bicubically.

    Returns:
        (size, size) float32, zero mean, unit standard deviation.
    """
    cells_y, cells_x = (cells, cells) if isinstance(cells, int) else cells
    low = rng.standard_normal((cells_y, cells_x)).astype(np.float32)
    field = cv2.resize(low, (size, size), interpolation=cv2.INTER_CUBIC)
    return (field - field.mean()) / max(float(field.std()), 1e-6)


def _wave_noise(rng: np.random.Generator, x: np.ndarray, y: np.ndarray, waves: int, freq: tuple[float, float],
                stretch: float = 1.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Noise defined at arbitrary (e.g. world) coordinates: a sum of random plane waves.

    Args:
        x, y: coordinates, any shape, same unit as 1 / freq.
        waves: number of plane waves.
        freq: (low, high) angular frequency range, radians per unit.
        stretch: > 1 squeezes the waves along y (grain, brushed metal).

    Returns:
        value, d value / dx, d value / dy; each shaped like x, float32, value
        of unit standard deviation.
    """
    value = np.zeros_like(x, dtype=np.float32)
    grad_x, grad_y = np.zeros_like(value), np.zeros_like(value)
    for _ in range(waves):
        angle, phase = rng.uniform(0, np.pi), rng.uniform(0, 2 * np.pi)
        k = rng.uniform(*freq)
        # plain Python floats: numpy float64 scalars would promote the float32 arrays to float64
        kx, ky = float(k * np.cos(angle)), float(k * np.sin(angle) * stretch)
        arg = kx * x + ky * y + phase
        value += np.cos(arg)
        sin = np.sin(arg)
        grad_x -= kx * sin
        grad_y -= ky * sin
    scale = np.float32(np.sqrt(2.0 / waves))
    return value * scale, grad_x * scale, grad_y * scale


def _smoothstep(edge0: float, edge1: float, x: np.ndarray) -> np.ndarray:
    t = np.clip((x - edge0) / (edge1 - edge0), 0.0, 1.0)
    return t * t * (3 - 2 * t)


def _poly_mask(size: int, points: Sequence[tuple[float, float]]) -> np.ndarray:
    """Anti-aliased coverage of a filled polygon given in (sub-)pixel (x, y)."""
    mask = np.zeros((size, size), np.uint8)
    fixed = np.rint(np.asarray(points, np.float64) * 16).astype(np.int32)  # 4 fractional bits
    cv2.fillPoly(mask, [fixed], 255, cv2.LINE_AA, shift=4)
    return mask.astype(np.float32) / 255.0


def _round_rect(x0: float, y0: float, x1: float, y1: float, radius: float) -> list[tuple[float, float]]:
    """Polygon outline of a rectangle with rounded corners, pixels."""
    points = []
    corners = ((x1 - radius, y0 + radius, -90), (x1 - radius, y1 - radius, 0),
               (x0 + radius, y1 - radius, 90), (x0 + radius, y0 + radius, 180))
    for cx, cy, start in corners:
        for step in range(7):
            angle = np.radians(start + 15 * step)
            points.append((cx + radius * np.cos(angle), cy + radius * np.sin(angle)))
    return points


def _ellipse_mask(size: int, centre: tuple[float, float], axes: tuple[float, float],
                  angle_deg: float = 0.0) -> np.ndarray:
    """Anti-aliased coverage of a filled rotated ellipse (about one pixel of soft edge)."""
    x, y = _grid(size)
    c, s = np.cos(np.radians(angle_deg)), np.sin(np.radians(angle_deg))
    dx, dy = x - centre[0], y - centre[1]
    u, v = (c * dx + s * dy) / axes[0], (-s * dx + c * dy) / axes[1]
    radius = np.sqrt(u * u + v * v)
    return np.clip(0.5 - (radius - 1.0) * min(axes), 0.0, 1.0).astype(np.float32)


def _paint(canvas: np.ndarray, mask: np.ndarray, colour) -> None:
    """canvas <- canvas * (1 - mask) + colour * mask, in place; colour is (3,) or (H, W, 3)."""
    m = mask[..., None]
    canvas *= 1.0 - m
    canvas += np.asarray(colour, np.float32) * m


def _soft_shadow(canvas: np.ndarray, mask: np.ndarray, sigma: float, strength: float) -> None:
    """Darken the canvas under a blurred copy of mask (contact and drop shadows), in place."""
    blurred = cv2.GaussianBlur(mask, (0, 0), sigma)
    canvas *= (1.0 - strength * blurred)[..., None]


def _vignette(size: int, strength: float, centre: tuple[float, float] = (0.5, 0.5)) -> np.ndarray:
    """(size, size, 1) float32 multiplier, 1 at the centre falling by ``strength`` at the corners."""
    x, y = _grid(size)
    r2 = ((x / size - centre[0]) ** 2 + (y / size - centre[1]) ** 2) / 0.5
    return (1.0 - strength * r2)[..., None].astype(np.float32)


def _photo_finish(canvas: np.ndarray, rng: np.random.Generator, grain: float, blur_sigma: float) -> np.ndarray:
    """Slight optical softness and sensor grain, clipped to [0, 1]."""
    if blur_sigma > 0:
        canvas = cv2.GaussianBlur(canvas, (0, 0), blur_sigma)
    size = canvas.shape[0]
    canvas = canvas + grain * rng.standard_normal((size, size, 1)).astype(np.float32)
    return np.clip(canvas, 0.0, 1.0)


# --------------------------------------------------------------------------- ray casting
# Used for the phantom and abdomen scenes: an orthographic camera looks at
# ellipsoids standing on the table plane z = 0 (world frame: z up, metres-free
# unit lengths); the table ends at y = table_far_y where a vertical wall rises.


def _camera_rays(size: int, azimuth_deg: float, elevation_deg: float, target: Float3,
                 half_extent: float) -> tuple[np.ndarray, np.ndarray]:
    """Orthographic rays: origins (size*size, 3) float32 and the shared direction (3,).

    Azimuth 0 looks along +y; elevation is the downward tilt from horizontal.
    Image row 0 is the top of the picture.
    """
    az, el = np.radians(azimuth_deg), np.radians(elevation_deg)
    rot = np.array([[np.cos(az), np.sin(az), 0], [-np.sin(az), np.cos(az), 0], [0, 0, 1]])
    direction = _dot(rot, np.array([0.0, np.cos(el), -np.sin(el)]))
    right = _dot(rot, np.array([1.0, 0.0, 0.0]))
    up = np.cross(right, direction)
    coords = (np.arange(size) + 0.5) / size * 2.0 - 1.0
    u, v = np.meshgrid(coords, coords)  # v grows downwards
    origins = (np.asarray(target)[None] + half_extent * (u.reshape(-1, 1) * right - v.reshape(-1, 1) * up)
               - 20.0 * direction)
    return origins.astype(np.float32), direction.astype(np.float32)


def _hit_ellipsoid(origins: np.ndarray, direction: np.ndarray, centre: Float3,
                   radii: Float3) -> tuple[np.ndarray, np.ndarray]:
    """Ray parameters of the near and far intersections, (N,) each, inf where missed."""
    radii_arr = np.asarray(radii, np.float32)
    o = (origins - np.asarray(centre, np.float32)) / radii_arr
    d = direction / radii_arr
    a = float(_dot(d, d))
    b = 2.0 * _dot(o, d)
    c = np.einsum("ij,ij->i", o, o) - 1.0
    disc = b * b - 4 * a * c
    hit = disc >= 0
    root = np.sqrt(np.where(hit, disc, 0.0))
    near = np.where(hit, (-b - root) / (2 * a), np.inf)
    far = np.where(hit, (-b + root) / (2 * a), np.inf)
    return near.astype(np.float32), far.astype(np.float32)


def _ellipsoid_normals(points: np.ndarray, centre: Float3, radii: Float3) -> np.ndarray:
    grad = (points - np.asarray(centre, np.float32)) / np.asarray(radii, np.float32) ** 2
    return grad / np.linalg.norm(grad, axis=1, keepdims=True)


def _trace(origins: np.ndarray, direction: np.ndarray, ellipsoids: Sequence[tuple[Float3, Float3]]):
    """Nearest visible ellipsoid (part above z = 0) along every ray.

    Returns:
        t (N,) float32 (inf where no ellipsoid), which (N,) int (-1 none),
        normals (N, 3) float32 unit, zero where no hit.
    """
    n = origins.shape[0]
    best_t = np.full(n, np.inf, np.float32)
    which = np.full(n, -1, np.int32)
    for k, (centre, radii) in enumerate(ellipsoids):
        near, _ = _hit_ellipsoid(origins, direction, centre, radii)
        z = origins[:, 2] + near * direction[2]
        # the part below the table is hidden by it; rays look down, so the near root decides
        visible = np.isfinite(near) & (z >= 0) & (near < best_t)
        best_t[visible] = near[visible]
        which[visible] = k
    normals = np.zeros((n, 3), np.float32)
    for k, (centre, radii) in enumerate(ellipsoids):
        sel = which == k
        points = origins[sel] + best_t[sel, None] * direction
        normals[sel] = _ellipsoid_normals(points, centre, radii)
    return best_t, which, normals


def _in_shadow(points: np.ndarray, light_dir: np.ndarray, ellipsoids: Sequence[tuple[Float3, Float3]]) -> np.ndarray:
    """(N,) float32, 1 where the way from a table point (z = 0) to the light is blocked."""
    blocked = np.zeros(points.shape[0], bool)
    for centre, radii in ellipsoids:
        _, far = _hit_ellipsoid(points, light_dir, centre, radii)
        # rising from z = 0 every positive-t crossing is above the table, i.e. on the visible part
        blocked |= np.isfinite(far) & (far > 1e-4)
    return blocked.astype(np.float32)


def _shade(normals: np.ndarray, view_dir: np.ndarray, light_dir: np.ndarray, wrap: float) -> tuple[np.ndarray, np.ndarray]:
    """Wrapped Lambert diffuse and Blinn half-vector cosine, (N,) float32 each."""
    diffuse = np.clip((_dot(normals, light_dir) + wrap) / (1 + wrap), 0.0, 1.0)
    half = light_dir - view_dir
    half = half / np.sqrt(_dot(half, half))
    return diffuse.astype(np.float32), np.clip(_dot(normals, half), 0.0, 1.0).astype(np.float32)


def _unit(v: Sequence[float]) -> np.ndarray:
    v = np.asarray(v, np.float32)
    return v / np.sqrt(_dot(v, v))


# --------------------------------------------------------------------------- scenes


def _plain_white() -> np.ndarray:
    return np.ones((BASE_PX, BASE_PX, 3), np.float32)


def _consultation_room() -> np.ndarray:
    """A clinic room: ultrasound cart left, window, examination couch right, wall cupboard."""
    size = BASE_PX
    rng = np.random.default_rng(101)
    x, y = _grid(size)
    canvas = _room_shell(rng, x, y, size)
    _room_window_and_cupboard(canvas, y, size)
    _room_couch(canvas, x, y, size)
    _room_ultrasound_machine(canvas, rng, x, y, size)
    canvas *= _vignette(size, 0.18, (0.55, 0.45))
    return _photo_finish(canvas, rng, grain=0.008, blur_sigma=0.7)


def _room_shell(rng: np.random.Generator, x: np.ndarray, y: np.ndarray, size: int) -> np.ndarray:
    """The room's wall, tiled floor and skirting board: a new (size, size, 3) float32 canvas."""
    floor_y, horizon_y = 330.0, 240.0

    # wall: warm off-white, lit from the window (x ~ 290) and the ceiling
    wall = np.array([0.87, 0.86, 0.80], np.float32)
    light = 0.80 + 0.20 * np.exp(-((x - 290) / 230) ** 2) - 0.10 * (y / floor_y)
    canvas = wall * light[..., None] * (1 + 0.012 * _smooth_noise(rng, size, 24))[..., None]

    # floor: grey-beige vinyl tiles in perspective (vanishing point on the horizon)
    floor = _smoothstep(floor_y - 0.5, floor_y + 0.5, y)
    floor_col = np.array([0.66, 0.64, 0.60], np.float32) * (0.92 + 0.10 * (y - floor_y) / (size - floor_y))[..., None]
    floor_col = floor_col * (1 + 0.02 * _smooth_noise(rng, size, 40))[..., None]
    _paint(canvas, floor, floor_col)
    lines = np.zeros((size, size), np.uint8)
    for depth in (9.0, 8.0, 7.0, 6.0, 5.0, 4.0):  # floor rows; screen y = horizon + 900 / depth
        row = int(round((horizon_y + 900.0 / depth) * 16))
        cv2.line(lines, (0, row), (size * 16, row), 255, 1, cv2.LINE_AA, shift=4)
    for k in range(-12, 13):
        x_wall = 256 + 44 * k
        x_bottom = 256 + (x_wall - 256) * (size - horizon_y) / (floor_y - horizon_y)
        cv2.line(lines, (int(x_wall * 16), int(floor_y * 16)), (int(x_bottom * 16), size * 16), 255, 1,
                 cv2.LINE_AA, shift=4)
    canvas *= (1 - 0.10 * lines.astype(np.float32) / 255 * floor)[..., None]
    # skirting board
    _paint(canvas, _poly_mask(size, [(0, floor_y - 12), (size, floor_y - 12), (size, floor_y), (0, floor_y)]),
           (0.78, 0.77, 0.73))
    return canvas


def _room_window_and_cupboard(canvas: np.ndarray, y: np.ndarray, size: int) -> None:
    """Paint the window with half-closed blinds and the wall cupboard onto ``canvas``."""
    # window with half-closed blinds, behind the couch
    _paint(canvas, _poly_mask(size, _round_rect(196, 46, 364, 214, 3)), (0.95, 0.95, 0.93))
    glass = _poly_mask(size, [(205, 55), (355, 55), (355, 205), (205, 205)])
    sky = np.stack([0.78 + 0.1 * (y / 205), 0.87 + 0.05 * (y / 205), np.full_like(y, 0.97)], -1)
    _paint(canvas, glass, sky)
    slats = (0.5 + 0.5 * np.cos(2 * np.pi * (y - 55) / 9.0)) * (y < 160)
    _paint(canvas, glass * slats.astype(np.float32) * 0.85, (0.93, 0.92, 0.88))
    _paint(canvas, _poly_mask(size, [(278, 55), (282, 55), (282, 205), (278, 205)]), (0.95, 0.95, 0.93))

    # wall cupboard, upper right, with its shadow on the wall
    cupboard = _poly_mask(size, _round_rect(392, 54, 504, 166, 4))
    _soft_shadow(canvas, np.roll(cupboard, (8, -4), (0, 1)), 7, 0.25)
    _paint(canvas, cupboard, (0.90, 0.88, 0.83))
    for x0 in (397, 450):
        door = _poly_mask(size, _round_rect(x0, 59, x0 + 51, 161, 2))
        _paint(canvas, door, np.array([0.93, 0.91, 0.86], np.float32) * (1 - 0.08 * ((y - 59) / 102))[..., None])
    for hx in (442, 455):
        _paint(canvas, _poly_mask(size, _round_rect(hx, 120, hx + 3, 142, 1.5)), (0.55, 0.55, 0.56))


def _room_couch(canvas: np.ndarray, x: np.ndarray, y: np.ndarray, size: int) -> None:
    """Paint the examination couch (pedestal cabinet, mattress, backrest, paper sheet) onto ``canvas``."""
    # examination couch: floor shadow, pedestal cabinet, mattress, raised backrest, paper sheet
    _soft_shadow(canvas, _ellipse_mask(size, (356, 436), (150, 16)), 9, 0.45)
    cabinet = _poly_mask(size, _round_rect(258, 330, 452, 432, 3))
    cab_col = np.array([0.86, 0.86, 0.84], np.float32) * (1 - 0.18 * np.clip((y - 330) / 102, 0, 1))[..., None]
    _paint(canvas, cabinet, cab_col)
    for drawer_y in (364, 398):
        _paint(canvas, _poly_mask(size, [(262, drawer_y), (448, drawer_y), (448, drawer_y + 1.2), (262, drawer_y + 1.2)]),
               (0.55, 0.55, 0.55))
        _paint(canvas, _poly_mask(size, _round_rect(338, drawer_y - 14, 372, drawer_y - 10, 2)), (0.45, 0.46, 0.48))
    _paint(canvas, _poly_mask(size, [(262, 342), (448, 342), (448, 343.2), (262, 343.2)]), (0.55, 0.55, 0.55))
    vinyl = np.array([0.22, 0.46, 0.55], np.float32)
    _soft_shadow(canvas, _poly_mask(size, [(250, 334), (462, 334), (462, 340), (250, 340)]), 3, 0.35)
    front = _poly_mask(size, _round_rect(222, 300, 488, 336, 8))
    _paint(canvas, front, vinyl * (1.0 - 0.25 * np.clip((y - 300) / 36, 0, 1))[..., None])
    top = _poly_mask(size, [(236, 286), (478, 286), (486, 304), (224, 304)])
    _paint(canvas, top, vinyl * 1.35)
    backrest_side = _poly_mask(size, [(388, 303), (430, 303), (492, 228), (466, 214)])
    _paint(canvas, backrest_side, vinyl * (0.9 - 0.2 * np.clip((x - 388) / 104, 0, 1))[..., None])
    backrest_face = _poly_mask(size, [(388, 303), (466, 214), (474, 210), (404, 292)])
    _paint(canvas, backrest_face, vinyl * 1.45)
    paper = _poly_mask(size, [(246, 288), (394, 288), (396, 303), (238, 303)])
    _paint(canvas, paper * 0.92, (0.97, 0.97, 0.95))
    _paint(canvas, _ellipse_mask(size, (230, 297), (9, 11)), (0.93, 0.93, 0.91))


def _room_ultrasound_machine(canvas: np.ndarray, rng: np.random.Generator, x: np.ndarray, y: np.ndarray,
                             size: int) -> None:
    """Paint the ultrasound cart with its console and a B-mode image on the monitor onto ``canvas``."""
    # ultrasound machine: floor shadow, wheeled base, column, console, monitor on a post
    _soft_shadow(canvas, _ellipse_mask(size, (115, 438), (85, 10)), 7, 0.45)
    grey = np.array([0.80, 0.81, 0.83], np.float32)
    cylinder = (0.78 + 0.30 * np.cos(np.clip((x - 115) / 50, -1.5, 1.5)))[..., None]
    _paint(canvas, _poly_mask(size, _round_rect(48, 398, 182, 424, 6)), grey * 0.62)
    for wx in (62, 168):
        _paint(canvas, _ellipse_mask(size, (wx, 430), (9, 9)), (0.12, 0.12, 0.13))
    _paint(canvas, _poly_mask(size, [(74, 272), (156, 272), (150, 400), (80, 400)]), grey * cylinder * 0.95)
    console = _poly_mask(size, [(40, 236), (190, 236), (198, 270), (32, 270)])
    _paint(canvas, console, grey * 1.12)
    _paint(canvas, _poly_mask(size, _round_rect(32, 266, 198, 284, 4)), grey * 0.85)
    for kx in range(52, 130, 12):
        for ky in (242, 253):
            _paint(canvas, _poly_mask(size, _round_rect(kx, ky, kx + 9, ky + 7, 1.5)), (0.30, 0.31, 0.33))
    _paint(canvas, _ellipse_mask(size, (160, 254), (11, 7)), (0.25, 0.26, 0.30))
    _paint(canvas, _ellipse_mask(size, (158, 252), (4, 2.5)), (0.6, 0.62, 0.66))
    cables = np.zeros((size, size), np.uint8)
    for cx in (194, 200):
        curve = np.array([(cx, 262), (cx + 10, 300), (cx + 6, 350), (cx - 10, 392)], np.float64)
        cv2.polylines(cables, [np.rint(curve * 16).astype(np.int32)], False, 255, 3, cv2.LINE_AA, shift=4)
    _paint(canvas, cables.astype(np.float32) / 255, (0.15, 0.15, 0.16))
    for px in (190, 198):
        _paint(canvas, _poly_mask(size, _round_rect(px - 3, 248, px + 4, 268, 3)), (0.2, 0.2, 0.22))
    _paint(canvas, _poly_mask(size, [(108, 190), (122, 190), (122, 238), (108, 238)]), grey * 0.55)
    _soft_shadow(canvas, np.roll(_poly_mask(size, _round_rect(40, 90, 190, 196, 6)), (6, 6), (0, 1)), 6, 0.3)
    _paint(canvas, _poly_mask(size, _round_rect(40, 90, 190, 196, 6)), (0.20, 0.21, 0.23))
    screen = _poly_mask(size, [(48, 98), (182, 98), (182, 186), (48, 186)])
    _paint(canvas, screen, (0.02, 0.02, 0.03))
    # B-mode sector: speckle in a fan, a dark fluid pocket with a bright fetal head outline
    apex_x, apex_y = 118.0, 104.0
    radius = np.hypot(x - apex_x, y - apex_y)
    angle = np.degrees(np.arctan2(y - apex_y, x - apex_x))
    fan = (_smoothstep(-1, 1, 34 - np.abs(angle - 90)) * _smoothstep(78.5, 77.5, radius)
           * _smoothstep(7, 8, radius)).astype(np.float32) * screen
    speckle = np.clip(0.35 + 0.25 * _smooth_noise(rng, size, 180) + 0.12 * _smooth_noise(rng, size, 40), 0, 1)
    fluid = _ellipse_mask(size, (120, 150), (30, 19), 10)
    head = _ellipse_mask(size, (124, 151), (15, 12), 10) - _ellipse_mask(size, (124, 151), (12.5, 9.5), 10)
    echo = speckle * (1 - 0.85 * fluid) + 0.5 * np.clip(head, 0, 1)
    _paint(canvas, fan, np.repeat(np.clip(echo, 0, 1)[..., None], 3, -1) * 0.9)
    for row in range(108, 140, 7):  # on-screen text, as short light bars
        _paint(canvas, _poly_mask(size, [(53, row), (70, row), (70, row + 2), (53, row + 2)]), (0.55, 0.6, 0.65))
    _paint(canvas, _poly_mask(size, [(150, 112), (176, 112), (176, 114), (150, 114)]), (0.55, 0.6, 0.65))


def _phantom(seed: int, azimuth_deg: float, elevation_deg: float, target: Float3, half_extent: float,
             skin: Float3, table: str, wall: Float3, light_dir: Sequence[float], light_col: Float3,
             ambient: float, gel: float) -> np.ndarray:
    """An obstetric training phantom (a silicone belly dome on a flat torso block) on a table."""
    size = BASE_PX
    rng = np.random.default_rng(seed)
    light_dir = _unit(light_dir)
    light = np.asarray(light_col, np.float32)
    torso = ((0.0, 0.0, 0.0), (0.95, 0.68, 0.34))
    dome = ((0.0, 0.04, 0.08), (0.62, 0.55, 0.50))
    ellipsoids = (torso, dome)
    origins, direction = _camera_rays(size, azimuth_deg, elevation_deg, target, half_extent)
    t, which, normals = _trace(origins, direction, ellipsoids)
    hit_obj = which >= 0
    colour = np.zeros((origins.shape[0], 3), np.float32)

    # table top z = 0 up to the far edge, then a wall
    table_far_y = 1.7
    t_table = origins[:, 2] / -direction[2]
    table_pts = origins + t_table[:, None] * direction
    on_table = ~hit_obj & (table_pts[:, 1] <= table_far_y)
    on_wall = ~hit_obj & ~on_table
    tx, ty = table_pts[on_table, 0], table_pts[on_table, 1]
    if table == "drape":  # blue surgical drape, soft folds
        base = np.array([0.33, 0.52, 0.68], np.float32)
        folds, _, _ = _wave_noise(rng, tx, ty, 6, (2.0, 5.0))
        fibre, _, _ = _wave_noise(rng, tx, ty, 12, (60.0, 140.0))
        tex = 1 + 0.06 * folds + 0.02 * fibre
    elif table == "steel":  # brushed stainless steel
        base = np.array([0.66, 0.68, 0.70], np.float32)
        brush, _, _ = _wave_noise(rng, tx, ty, 12, (60.0, 160.0), stretch=0.02)
        tex = 1 + 0.025 * brush + 0.10 * np.exp(-((tx + 0.4 * ty - 0.6) / 0.8) ** 2)
    else:  # light wood: grain along x, warped
        base = np.array([0.72, 0.55, 0.36], np.float32)
        warp, _, _ = _wave_noise(rng, tx, ty, 5, (1.0, 3.0))
        tex = (1 + 0.06 * np.sin(23 * ty + 2.5 * warp) * np.sin(7 * ty + 1.3 * warp)
               + 0.025 * np.sin(97 * ty + 6 * warp))
    shadow = _in_shadow(table_pts[on_table], light_dir, ellipsoids)
    table_diffuse = max(float(light_dir[2]), 0.0)
    shadow_img = np.zeros(origins.shape[0], np.float32)
    shadow_img[on_table] = shadow
    # blur the hard shadow in image space: the lamp is not a point
    shadow_img = cv2.GaussianBlur(shadow_img.reshape(size, size), (0, 0), 6).reshape(-1)
    contact = cv2.GaussianBlur(hit_obj.astype(np.float32).reshape(size, size), (0, 0), 10).reshape(-1)
    lit = ambient + table_diffuse * (1 - 0.75 * shadow_img[on_table])
    colour[on_table] = base * tex[:, None] * (lit * (1 - 0.35 * contact[on_table]))[:, None] * light

    # the wall behind: darker further from the lamp
    wall_t = (table_far_y - origins[on_wall, 1]) / max(float(direction[1]), 1e-3)
    wall_z = origins[on_wall, 2] + wall_t * direction[2]
    colour[on_wall] = np.asarray(wall, np.float32) * (0.75 - 0.25 * np.clip(wall_z / 2, 0, 1))[:, None]

    # silicone: mottled albedo, small bumps in the normal, gel sheen in patches
    points = origins[hit_obj] + t[hit_obj, None] * direction
    n = normals[hit_obj]
    bumps, gx, gy = _wave_noise(rng, points[:, 0], points[:, 1], 24, (25.0, 70.0))
    n = n - 0.0006 * np.stack([gx, gy, np.zeros_like(gx)], 1)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    mottle, _, _ = _wave_noise(rng, points[:, 0], points[:, 1], 8, (3.0, 9.0))
    albedo = np.asarray(skin, np.float32) * (1 + 0.04 * mottle + 0.015 * bumps)[:, None]
    diffuse, cos_half = _shade(n, direction, light_dir, wrap=0.35)
    patches, _, _ = _wave_noise(rng, points[:, 0], points[:, 1], 10, (4.0, 10.0))
    gel_cover = _smoothstep(-0.2, 0.6, patches) * (which[hit_obj] == 1)
    specular = 0.10 * cos_half ** 20 + gel * gel_cover * cos_half ** 140
    # warm subsurface tint where the light does not reach
    shadow_tint = np.array([1.0, 0.86, 0.80], np.float32)
    colour[hit_obj] = (albedo * (ambient * shadow_tint + diffuse[:, None] * light)
                       + specular[:, None] * light)

    image = colour.reshape(size, size, 3) * _vignette(BASE_PX, 0.22)
    # one ray per pixel: the blur also softens the stair-stepped silhouette
    return _photo_finish(image, rng, grain=0.010, blur_sigma=0.7)


def _abdomen(seed: int, skin: Float3, shirt: Float3, sheet: Float3, light_dir: Sequence[float],
             centre: tuple[float, float], tilt_deg: float) -> np.ndarray:
    """Close-up of a pregnant abdomen: a large shaded skin dome, navel, gel, shirt and sheet edges."""
    size = BASE_PX
    rng = np.random.default_rng(seed)
    x, y = _grid(size)
    light_dir = _unit(light_dir)
    skin_arr = np.asarray(skin, np.float32)

    # the belly as an ellipsoid seen from the front: analytic normals in image space
    axis_x, axis_y = 0.58 * size, 0.56 * size
    c, s = np.cos(np.radians(tilt_deg)), np.sin(np.radians(tilt_deg))
    dx, dy = x - centre[0] * size, y - centre[1] * size
    u, v = (c * dx + s * dy) / axis_x, (-s * dx + c * dy) / axis_y
    r2 = u * u + v * v
    belly = np.clip(0.5 - (np.sqrt(r2) - 1.0) * min(axis_x, axis_y), 0, 1).astype(np.float32)
    nz = np.sqrt(np.clip(1 - r2, 0.0, 1.0))
    # rotate (u, v) back to image axes so the lighting follows the tilt
    normals = np.stack([c * u - s * v, s * u + c * v, nz * 1.3], -1)  # 1.3: flatter than a sphere
    bump_h = _smooth_noise(rng, size, 110)
    bump_y, bump_x = np.gradient(bump_h)  # per pixel
    normals[..., 0] -= 0.05 * bump_x
    normals[..., 1] -= 0.05 * bump_y
    normals /= np.linalg.norm(normals, axis=-1, keepdims=True)
    view = np.array([0.0, 0.0, 1.0], np.float32)  # towards the camera
    diffuse = np.clip((_dot(normals, light_dir) + 0.4) / 1.4, 0, 1)
    half = _unit(light_dir + view)
    cos_half = np.clip(_dot(normals, half), 0, 1)

    blotch = _smooth_noise(rng, size, 10)
    pores = _smooth_noise(rng, size, 200)
    albedo = skin_arr * (1 + 0.035 * blotch + 0.02 * pores + 0.01 * bump_h)[..., None]
    # linea nigra: a faint darker line below the navel, common late in pregnancy
    navel_x, navel_y = centre[0] * size + 0.06 * size * s, centre[1] * size + 0.02 * size
    line = np.exp(-((x - navel_x - (y - navel_y) * s) / 6.0) ** 2) * _smoothstep(navel_y + 14, navel_y + 60, y)
    albedo *= (1 - 0.07 * line)[..., None]
    shadow_tint = np.array([0.92, 0.72, 0.66], np.float32)  # light scattered in skin returns reddened
    gel_patch = _smooth_noise(rng, size, 6)
    gel_cover = _smoothstep(0.0, 0.8, gel_patch) * np.exp(-((dx / (0.45 * size)) ** 2 + (dy / (0.35 * size)) ** 2))
    specular = 0.06 * cos_half ** 12 + 0.55 * gel_cover * cos_half ** 90
    skin_rgb = albedo * (0.30 * shadow_tint + 0.85 * diffuse[..., None]) + specular[..., None]

    # navel: a dark slit with a lit lower lip
    navel = _ellipse_mask(size, (navel_x, navel_y), (12.0, 7.0), tilt_deg)
    lip = _ellipse_mask(size, (navel_x, navel_y + 4), (17, 11), tilt_deg) - navel
    skin_rgb *= (1 - 0.25 * cv2.GaussianBlur(lip, (0, 0), 2.0))[..., None]
    skin_rgb *= (1 - 0.6 * cv2.GaussianBlur(navel, (0, 0), 1.2))[..., None]

    # bed sheet around the belly with wrinkles, in the belly's soft shadow
    folds = _smooth_noise(rng, size, 5)
    sheet_rgb = np.asarray(sheet, np.float32) * (0.72 + 0.06 * folds + 0.10 * (y / size))[..., None]
    canvas = sheet_rgb.copy()
    _soft_shadow(canvas, belly, 14, 0.45)
    _paint(canvas, belly, skin_rgb)

    # shirt pulled up over the top edge: wavy hem, vertical folds, shadow on the skin below it
    hem = 0.13 * size + 9 * np.sin(x / size * 7.0 + 1.0) + 5 * np.sin(x / size * 17.0)
    shirt_mask = _smoothstep(-0.7, 0.7, hem - y).astype(np.float32)
    _soft_shadow(canvas, np.roll(shirt_mask, 6, 0), 6, 0.45)
    fold_light = 0.80 + 0.12 * np.sin(x / size * 38 + 2 * np.sin(y / 23)) + 0.10 * (1 - y / hem.max())
    rim = _smoothstep(14, 0, hem - y)  # the rolled hem catches the light
    shirt_rgb = np.asarray(shirt, np.float32) * (fold_light * (1 + 0.25 * rim))[..., None]
    _paint(canvas, shirt_mask, shirt_rgb * (1 + 0.02 * _smooth_noise(rng, size, 120))[..., None])

    # paper towel tucked into the waistband along the bottom edge
    band = 0.90 * size + 6 * np.sin(x / size * 9.0 + 0.5)
    towel = _smoothstep(-0.7, 0.7, y - band).astype(np.float32)
    _soft_shadow(canvas, np.roll(towel, -5, 0), 5, 0.35)
    crinkle = _smooth_noise(rng, size, 14)
    _paint(canvas, towel, np.array([0.95, 0.95, 0.93], np.float32) * (0.88 + 0.05 * crinkle)[..., None])

    canvas *= _vignette(size, 0.2)
    return _photo_finish(canvas, rng, grain=0.008, blur_sigma=0.6)


SCENES: tuple[Callable[[], np.ndarray], ...] = (
    _plain_white,
    _consultation_room,
    functools.partial(_phantom, seed=201, azimuth_deg=-18.0, elevation_deg=42.0, target=(0.0, 0.1, 0.2),
                      half_extent=1.45, skin=(0.90, 0.74, 0.60), table="drape", wall=(0.80, 0.82, 0.80),
                      light_dir=(-0.5, -0.4, 0.8), light_col=(1.0, 0.96, 0.88), ambient=0.35, gel=0.8),
    functools.partial(_phantom, seed=202, azimuth_deg=28.0, elevation_deg=62.0, target=(0.1, 0.0, 0.25),
                      half_extent=1.05, skin=(0.93, 0.72, 0.64), table="steel", wall=(0.70, 0.74, 0.80),
                      light_dir=(0.6, -0.2, 0.75), light_col=(0.92, 0.96, 1.0), ambient=0.32, gel=0.9),
    functools.partial(_phantom, seed=203, azimuth_deg=6.0, elevation_deg=27.0, target=(-0.1, 0.3, 0.3),
                      half_extent=1.6, skin=(0.86, 0.66, 0.50), table="wood", wall=(0.55, 0.52, 0.50),
                      light_dir=(0.2, -0.7, 0.6), light_col=(1.0, 0.90, 0.78), ambient=0.28, gel=1.0),
    functools.partial(_abdomen, seed=301, skin=(0.94, 0.77, 0.66), shirt=(0.55, 0.58, 0.62),
                      sheet=(0.82, 0.88, 0.92), light_dir=(-0.45, -0.5, 0.75), centre=(0.50, 0.56), tilt_deg=-4.0),
    functools.partial(_abdomen, seed=302, skin=(0.64, 0.43, 0.30), shirt=(0.58, 0.16, 0.20),
                      sheet=(0.90, 0.90, 0.88), light_dir=(0.5, -0.45, 0.75), centre=(0.47, 0.58), tilt_deg=5.0),
    functools.partial(_abdomen, seed=303, skin=(0.30, 0.20, 0.155), shirt=(0.85, 0.80, 0.62),
                      sheet=(0.70, 0.82, 0.88), light_dir=(-0.2, -0.6, 0.78), centre=(0.53, 0.55), tilt_deg=-2.0),
)
