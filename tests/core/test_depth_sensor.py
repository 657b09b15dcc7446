"""The depth sensor model (hupbench.core.depth_sensor) against known geometry: a plane and a sphere whose exact depth
maps are computed here (ray intersections), seen through each preset at 0.4, 0.6 and 1.0 m. The expected noise,
offset and invalid share are computed here from the presets' documented formulas, not by the module's functions."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest

from hupbench.core.contract import CLINIC_SEG_LABELS as LABELS
from hupbench.core.depth_sensor import PRESETS, frame_rng, preset, sensor_depth, stored_sensor_depth
from hupbench.core.errors import BadValueError

#: a colour camera with the dataset's field of view (480 px focal length at 256 px) at a quarter of its pixels
SIDE, FOCAL = 64, 120.0
K = np.array([[FOCAL, 0.0, (SIDE - 1) / 2], [0.0, FOCAL, (SIDE - 1) / 2], [0.0, 0.0, 1.0]])
DISTANCES_M = (0.4, 0.6, 1.0)
#: frames of the case that measures the per-frame offset's sigma (to about 1 / sqrt(2 x 300), 4 %), at OFFSET_Z_M;
#: every other case measures per-pixel statistics over FEW_FRAMES
FRAMES, OFFSET_Z_M, FEW_FRAMES = 300, 0.6, 80
#: the issue's tolerance: within 10 % of the documented value
REL_TOL = 0.10


def _rays() -> tuple[np.ndarray, np.ndarray]:
    v, u = np.mgrid[0:SIDE, 0:SIDE].astype(np.float64)
    return (u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1]


def plane(z_m: float) -> tuple[np.ndarray, np.ndarray]:
    """(depth, unit normals) of a fronto-parallel plane at ``z_m`` filling the image."""
    return np.full((SIDE, SIDE), z_m), np.broadcast_to(np.array([0.0, 0.0, -1.0]), (SIDE, SIDE, 3))


def sphere(centre_z_m: float, radius_m: float) -> tuple[np.ndarray, np.ndarray]:
    """(depth, unit normals) of a sphere on the optical axis, 0 off it."""
    x, y = _rays()
    d = np.stack([x, y, np.ones_like(x)], -1)
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    c = np.array([0.0, 0.0, centre_z_m])
    b = d @ c
    disc = b * b - (c @ c - radius_m ** 2)
    hit = disc > 0
    t = np.where(hit, b - np.sqrt(np.where(hit, disc, 0.0)), 0.0)
    points = d * t[..., None]
    return np.where(hit, points[..., 2], 0.0), (points - c) / radius_m


def _depth_camera_points(sensor, depth: np.ndarray) -> np.ndarray:
    """(H, W, 3) each pixel's surface point in the depth camera's frame (the preset's offset and tilt)."""
    x, y = _rays()
    points = np.stack([x * depth, y * depth, depth], -1) - np.asarray(sensor.offset_m)
    return points @ sensor.rotation()  # R^T p for each row p


def documented_invalid(sensor, depth: np.ndarray, normals: np.ndarray, material: str) -> np.ndarray:
    """The share of no depth the preset's documentation gives per pixel: its dropout and its signal
    ``albedo * cos * (range_ref / range)^2`` against the signal floor (range and incidence from the depth camera),
    all of it outside the range."""
    x, y = _rays()
    towards = np.stack([x * depth, y * depth, depth], -1) - np.asarray(sensor.offset_m)
    range_m = np.linalg.norm(towards, axis=-1)
    cos = np.abs((towards * normals).sum(-1)) / range_m
    signal = sensor.ir_albedo[material] * cos * (sensor.range_ref_m / range_m) ** 2
    low = np.clip(1.0 - signal / sensor.signal_floor, 0.0, 1.0)
    p = 1.0 - (1.0 - sensor.dropout) * (1.0 - low)
    return np.where((range_m < sensor.min_range_m) | (range_m > sensor.max_range_m), 1.0, p)


def documented_reading(sensor, depth: np.ndarray, material: str) -> tuple[np.ndarray, np.ndarray]:
    """(the colour camera's depth of the point the preset reads without random error or per-frame offset: the
    range from the depth camera plus the material's offset, wrapped; the random error's sigma in that depth with the
    output's quantisation), per pixel."""
    points = _depth_camera_points(sensor, depth)
    range_m = np.linalg.norm(points, axis=-1)
    reading = range_m + sensor.material_bias_m.get(material, 0.0)
    if sensor.wrap_m:
        reading = np.mod(reading, sensor.wrap_m)
    along = points / range_m[..., None]  # unit rays of the depth camera
    R = sensor.rotation()
    to_colour_depth = along @ R[2]  # d(colour depth) / d(range)
    z = reading * to_colour_depth + sensor.offset_m[2]
    sigma_range = sensor.sigma_m * (range_m / sensor.range_ref_m) ** 2
    quantum = sensor.quantum_m * to_colour_depth / along[..., 2]  # the output's step, in the depth camera's depth
    return z, np.sqrt((sigma_range * to_colour_depth) ** 2 + quantum ** 2 / 12)


def _frames(sensor, depth: np.ndarray, material: str, n: int = FRAMES) -> np.ndarray:
    labels = np.where(depth > 0, LABELS[material], 0).astype(np.uint8)
    return np.stack([sensor_depth(depth, labels, K, sensor, LABELS, frame_rng(0, i, sensor.name)) for i in range(n)])


def _statistics(sensor, depth, normals, material, inner, n: int = FEW_FRAMES) -> dict:
    """Over the pixels ``inner``: the random error (each pixel's spread over the frames, the frame's offset taken
    out, in units of the documented sigma: RMS over pixels), the per-frame offset's sigma and mean, and the invalid
    share, measured and documented. The random error is taken over time, as a sensor's is characterised: a depth
    pixel's footprint on a curved surface adds an error that is the same in every frame."""
    frames = _frames(sensor, depth, material, n)
    reading, sigma = documented_reading(sensor, depth, material)
    valid = (frames > 0) & inner
    residual = np.where(valid, frames - reading, np.nan)
    offsets = np.zeros(len(frames))  # a preset without a per-frame offset: none to take out
    if sensor.bias_sigma_m > 0:
        offsets = np.nanmedian(residual.reshape(len(frames), -1), axis=1) if valid.any() else offsets * np.nan
    centred = residual - offsets[:, None, None]
    enough = valid.sum(0) >= 10
    spread = np.nanstd(centred[:, enough], axis=0, ddof=1) / sigma[enough] if enough.any() else np.array([np.nan])
    return {"invalid": 1.0 - valid.sum() / (inner.sum() * len(frames)),
            "invalid_documented": float(documented_invalid(sensor, depth, normals, material)[inner].mean()),
            "noise_ratio": float(np.sqrt(np.mean(spread ** 2))), "offset_sigma_m": float(np.nanstd(offsets)),
            "offset_mean_m": float(np.nanmean(offsets))}


@pytest.mark.parametrize("name", list(PRESETS))
@pytest.mark.parametrize("z_m", DISTANCES_M)
def test_a_plane_of_skin_gives_the_documented_noise_offset_and_invalid_share(name, z_m):
    sensor = PRESETS[name]
    depth, normals = plane(z_m)
    inner = np.zeros(depth.shape, bool)
    inner[4:-4, 4:-4] = True
    n = FRAMES if z_m == OFFSET_Z_M else FEW_FRAMES
    s = _statistics(sensor, depth, normals, "patient", inner, n)
    assert s["invalid"] == pytest.approx(s["invalid_documented"], rel=REL_TOL, abs=1e-3), s
    if s["invalid_documented"] > 0.99:  # out of range (the Azure Kinect's 0.5 m near limit): nothing to measure
        return
    assert s["noise_ratio"] == pytest.approx(1.0, rel=REL_TOL), s
    # the skin's offset is in the documented reading: what is left averages to 0 over the frames, within 10 % of the
    # offset (30 mm on HoloLens 2) and 4 standard errors of the per-frame offset's mean
    skin = sensor.material_bias_m.get("patient", 0.0)
    assert abs(s["offset_mean_m"]) < REL_TOL * skin + 4 * sensor.bias_sigma_m / np.sqrt(n), s
    if n == FRAMES:
        assert s["offset_sigma_m"] == pytest.approx(sensor.bias_sigma_m, rel=REL_TOL), s


@pytest.mark.parametrize("name", list(PRESETS))
@pytest.mark.parametrize("z_m", DISTANCES_M)
def test_a_sphere_of_dark_plastic_gives_the_documented_noise_and_invalid_share(name, z_m):
    """The probe's plastic on a sphere: dark, and grazing towards its rim (the pixels within 3 px of the silhouette
    are left out: there the depth map's gradient, which the sensor takes its normals from, is not the sphere's). No
    per-frame offset: the few valid pixels of a far dark sphere would not tell it from the random error."""
    sensor = dataclasses.replace(PRESETS[name], bias_sigma_m=0.0)
    depth, normals = sphere(z_m, radius_m=0.125 * z_m)  # the same size in the image at every distance: 15 px
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (7, 7))
    inner = cv2.erode((depth > 0).astype(np.uint8), disc).astype(bool)
    s = _statistics(sensor, depth, normals, "probe", inner)
    assert s["invalid"] == pytest.approx(s["invalid_documented"], rel=REL_TOL, abs=2e-3), s
    if s["invalid_documented"] < 0.8:  # else too few valid readings per pixel for a spread over time
        assert s["noise_ratio"] == pytest.approx(1.0, rel=REL_TOL), s


@pytest.mark.parametrize("name", list(PRESETS))
def test_dark_plastic_returns_no_depth_at_the_configured_rate(name):
    """A dark plane at 0.6 m (the probe's infrared albedo) loses the share its albedo gives; a bright one far less."""
    sensor = PRESETS[name]
    depth, normals = plane(0.6)
    rates = {}
    for material in ("probe", "hand"):
        frames = _frames(sensor, depth, material, n=20)
        rates[material] = float((frames == 0).mean())
        want = float(documented_invalid(sensor, depth, normals, material).mean())
        assert rates[material] == pytest.approx(want, rel=REL_TOL, abs=2e-3), (material, rates, want)
    assert rates["probe"] > 0.2 and rates["probe"] > 10 * rates["hand"], rates


def test_the_ahat_preset_wraps_a_surface_at_1_3_m_to_0_3_m():
    sensor = PRESETS["hololens2_ahat"]
    depth, _ = plane(1.3)
    x, y = _rays()
    centre = (x * x + y * y) < 0.02 ** 2  # near the axis, where range and depth agree to 0.02 %
    frames = _frames(sensor, depth, "hand", n=20)
    read = frames[:, centre]
    assert (read > 0).mean() > 0.2
    assert np.median(read[read > 0]) == pytest.approx(0.3, abs=0.005)
    assert not (frames > 1.0).any()  # nothing reads beyond the wrap


def _noiseless(name: str):
    """The preset's geometry alone: no random error, offset, dropout or mixed pixels."""
    return dataclasses.replace(PRESETS[name], sigma_m=0.0, bias_sigma_m=0.0, dropout=0.0, signal_floor=1e-12,
                               mixed_rate=0.0, material_bias_m={}, quantum_m=1e-6)


@pytest.mark.parametrize("name", list(PRESETS))
def test_the_depth_cameras_offset_moves_a_depth_edge_by_the_expected_colour_pixels(name):
    """A near half-plane over a far plane, its edge across the depth camera's offset from the colour camera: the far
    plane's strip behind the edge that the depth camera cannot see is a hole as wide as the parallax says,
    ``f * |x2| / z2`` with x2 where the ray from the depth camera over the edge meets the far plane."""
    sensor = _noiseless(name)
    side, focal, z1, z2 = 256, 480.0, 0.55, 0.9
    K_big = np.array([[focal, 0.0, 127.5], [0.0, focal, 127.5], [0.0, 0.0, 1.0]])
    axis = int(np.argmax(np.abs(sensor.offset_m[:2])))  # 0: x (a vertical edge), 1: y (a horizontal edge)
    o = np.asarray(sensor.offset_m)
    coord = (np.arange(side) - 127.5) / focal
    grid = np.broadcast_to(coord[None, :] if axis == 0 else coord[:, None], (side, side))
    widths = []
    for sign in (1.0, -1.0):  # the near plane on either side of the edge (x or y = 0 at z1)
        near = sign * grid > 0
        depth = np.where(near, z1, z2)
        labels = np.where(near, LABELS["hand"], LABELS["patient"]).astype(np.uint8)
        out = sensor_depth(depth, labels, K_big, sensor, LABELS, frame_rng(0, 0, name))
        holes = (out == 0) & ~near
        profile = holes.sum(axis=1 - axis)  # hole pixels per row (a vertical edge) or per column (a horizontal one)
        widths.append(float(np.median(profile[64:192])))
    x2 = o[axis] + (0.0 - o[axis]) * (z2 - o[2]) / (z1 - o[2])
    expected = focal * abs(x2) / z2
    assert min(widths) <= 1.0  # on one side the depth camera sees more than the colour camera: no strip
    assert max(widths) == pytest.approx(expected, abs=1.5), (widths, expected)


def test_a_frames_noise_is_seeded_and_a_fresh_draw_differs():
    sensor = PRESETS["hololens2_ahat"]
    depth = np.full((SIDE, SIDE), 6000, np.uint16)  # 0.6 m in the dataset's 0.1 mm unit
    labels = np.full((SIDE, SIDE), LABELS["patient"], np.uint8)
    first = stored_sensor_depth(depth, labels, K, sensor, LABELS, 1e-4, seed=3, frame_id=7)
    again = stored_sensor_depth(depth, labels, K, sensor, LABELS, 1e-4, seed=3, frame_id=7)
    fresh = stored_sensor_depth(depth, labels, K, sensor, LABELS, 1e-4, seed=3, frame_id=7, draw=1)
    other = stored_sensor_depth(depth, labels, K, sensor, LABELS, 1e-4, seed=3, frame_id=8)
    assert first.dtype == np.uint16 and np.array_equal(first, again)
    assert (first != fresh).mean() > 0.5 and (first != other).mean() > 0.5


def test_an_unknown_preset_is_refused_naming_the_choices():
    assert preset("none") is None
    with pytest.raises(BadValueError, match="dataset.depth_sensor must be one of none, azure_kinect_nfov"):
        preset("kinect_v1")
