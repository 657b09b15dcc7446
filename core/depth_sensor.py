"""A time-of-flight depth camera, simulated from the renderer's z-buffer (numpy and OpenCV only).

The renderer gives a perfect depth map: every surface, 0.1 mm steps, no noise, seen from the colour camera itself.
A real RGB-D rig measures depth with its own camera, beside the colour camera, and returns noise, holes and flying
pixels. :func:`sensor_depth` turns a clean depth map (and its label map, which says what material each pixel is)
into what such a camera would give, in the colour image, in five steps:

1. The depth camera's view: the clean surface points are moved into the depth camera (its own resolution, field of
   view and pose beside the colour camera) and z-buffered there. What the colour camera sees and the depth camera
   does not is a hole (no depth).
2. What returns no signal: the infrared signal of a pixel is ``albedo * cos(incidence) * (range_ref_m / range)^2``;
   below ``signal_floor`` a pixel is invalid with probability ``1 - signal / signal_floor`` (dark plastic, grazing
   angles, far surfaces), and any pixel with probability ``dropout``.
3. Mixed pixels: a pixel at a depth discontinuity (its 3 x 3 neighbourhood spans more than ``edge_m``) is mixed with
   probability ``mixed_rate``: invalid for a ``mixed_invalid`` share of those, else a flying pixel between the two
   surfaces.
4. The range measured: range + N(0, (sigma_m * (range / range_ref_m)^2)^2) + a per-frame offset N(0, bias_sigma_m^2)
   + the material's offset (skin reads behind its surface: multipath and subsurface scattering); wrapped at
   ``wrap_m`` where the camera's phase wraps (AHAT); outside [min_range_m, max_range_m] invalid; quantised to
   ``quantum_m`` in depth.
5. Back into the colour image: each depth pixel, spread over the colour pixels it covers, is z-buffered in the colour
   camera at its true surface (the nearest surface wins, its measurement, invalid or not, is the pixel's); a colour
   pixel no depth pixel reaches is 0, as in a real rig's registered depth image. (A rig registers by the measured
   depth, which also moves flying and wrapped pixels sideways; here they keep their place and their wrong depth.)

Invalid is 0 throughout. The noise of a frame is drawn from the ``seed`` given (the dataset's seed and the frame's id:
every model evaluated on a split reads the same sensor depth).

Presets (:data:`PRESETS`), with the sources of their parameters; what is not published is said to be assumed:

- ``none``: the z-buffer unchanged (the paper protocol's default).
- ``azure_kinect_nfov``: Azure Kinect DK, NFOV unbinned: 640 x 576, 75 x 65 deg, 0.5-3.86 m (the DK hardware
  specification); random error sigma <= 17 mm and systematic error < 11 mm + 0.1 % of distance (specification);
  pixels saturated, low-signal or mixed are invalidated, black plastic returns 0. The colour camera sits about
  32 mm beside the depth camera and is tilted 6 deg against it (DK specification drawings).
- ``hololens2_ahat``: HoloLens 2 research mode, AHAT: 512 x 512 at 45 fps, single-frequency, so range wraps beyond
  about 1 m (Microsoft's research-mode documentation; Ungureanu et al. 2020, arXiv:2008.11239). Users report
  point clouds 2-4 cm behind the true surface of skin. Field of view and the offset from the photo-video camera
  are assumed (about 75 deg; 2 cm up and 1 cm back), not calibrated.
- ``hololens2_longthrow``: HoloLens 2 research mode, Long-Throw: 320 x 288 at 1-5 fps, no wrap in the clinic's
  ranges (up to about 4 m, assumed), the same skin offset and assumed pose.

A user's own sensor: take the preset of its family and set its resolution, field of view, pose beside the colour
camera and range from the data sheet; noise sigma and the skin offset from a plane and a hand measured with it.
"""

from __future__ import annotations

import dataclasses
import math
import zlib
from dataclasses import dataclass, field

import cv2
import numpy as np

from hupbench.core.errors import BadValueError

__all__ = ["NONE", "PRESETS", "SensorPreset", "frame_rng", "invalid_probability", "preset", "sensor_depth",
           "sensor_expectation", "stored_sensor_depth", "depth_input_warnings"]

NONE = "none"


@dataclass(frozen=True)
class SensorPreset:
    """One depth camera's model (see the module's docs for how each field enters).

    Attributes:
        name: the preset's name (``dataset.depth_sensor``).
        resolution: (width, height) of the depth camera, pixels. fov_deg: its (horizontal, vertical) field of view.
        offset_m: the depth camera's centre in the colour camera's frame (OpenCV axes), metres.
        tilt_deg: its rotation against the colour camera about the colour camera's x axis, degrees.
        min_range_m, max_range_m: the range it measures; outside it a pixel is invalid.
        wrap_m: the range at which its phase wraps (a surface at ``wrap_m + d`` reads ``d``); 0 for none.
        sigma_m: random error (one sigma) at ``range_ref_m``, growing with the square of the range.
        bias_sigma_m: sigma of the per-frame offset of every range.
        range_ref_m: the range at which ``sigma_m`` and the signal are given.
        signal_floor: the signal below which pixels start to drop.
        dropout: the share of pixels that drop whatever their signal.
        edge_m: a depth jump in a pixel's 3 x 3 neighbourhood that makes it a mixed-pixel candidate.
        mixed_rate: the share of those candidates that are mixed. mixed_invalid: the share of mixed pixels invalid
            (the rest fly between the two surfaces).
        quantum_m: the depth step of the camera's output.
        ir_albedo: infrared albedo per material (a label name of the dataset's seg map); a label not named reads 0.5.
        material_bias_m: range offset per material (skin reads behind its surface), metres.
    """

    name: str
    resolution: tuple[int, int]
    fov_deg: tuple[float, float]
    offset_m: tuple[float, float, float]
    tilt_deg: float
    min_range_m: float
    max_range_m: float
    wrap_m: float
    sigma_m: float
    bias_sigma_m: float
    range_ref_m: float
    signal_floor: float
    dropout: float
    edge_m: float
    mixed_rate: float
    mixed_invalid: float
    quantum_m: float
    ir_albedo: dict = field(default_factory=dict)
    material_bias_m: dict = field(default_factory=dict)

    def parameters(self) -> dict:
        """The preset as a JSON-ready dict (the manifest records it)."""
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in dataclasses.asdict(self).items()}

    @classmethod
    def from_parameters(cls, parameters: dict) -> "SensorPreset":
        """The preset a manifest records (:meth:`parameters`), or a BadValueError naming what is wrong."""
        try:
            fields = {k: (tuple(v) if isinstance(v, list) else v) for k, v in parameters.items()}
            return cls(**fields)
        except (TypeError, AttributeError) as exc:
            raise BadValueError(f"depth_sensor parameters {parameters!r} are not a sensor preset's: {exc}") from None

    def intrinsics(self) -> np.ndarray:
        """(3, 3) K of the depth camera: centred, square-pixel focal lengths from its field of view."""
        w, h = self.resolution
        fx = (w / 2) / math.tan(math.radians(self.fov_deg[0]) / 2)
        fy = (h / 2) / math.tan(math.radians(self.fov_deg[1]) / 2)
        return np.array([[fx, 0.0, (w - 1) / 2], [0.0, fy, (h - 1) / 2], [0.0, 0.0, 1.0]])

    def rotation(self) -> np.ndarray:
        """(3, 3) R of the depth camera's axes in the colour camera's frame (a point p_d maps to R p_d + offset)."""
        a = math.radians(self.tilt_deg)
        return np.array([[1.0, 0.0, 0.0], [0.0, math.cos(a), -math.sin(a)], [0.0, math.sin(a), math.cos(a)]])

    def noise_sigma_m(self, range_m: np.ndarray | float) -> np.ndarray | float:
        """The random error (one sigma, metres) at ``range_m``."""
        return self.sigma_m * (np.asarray(range_m) / self.range_ref_m) ** 2


#: dark probe plastic, a gloved hand, skin, and the room's walls and furniture, in the infrared (assumed values in the
#: range measured for such materials near 850 nm: black ABS a few per cent, skin about half)
_ALBEDO = {"background": 0.5, "hand": 0.4, "arm": 0.5, "probe": 0.04, "patient": 0.5}
#: skin reads 2-4 cm behind its surface on HoloLens 2 (users' reports); the arm is bare skin, the hand is gloved
_HOLOLENS_SKIN_BIAS_M = {"patient": 0.03, "arm": 0.03}
_HOLOLENS = dict(fov_deg=(75.0, 75.0), offset_m=(0.0, -0.02, -0.01), tilt_deg=0.0, bias_sigma_m=0.002,
                 range_ref_m=0.5, signal_floor=0.15, dropout=0.01, edge_m=0.02, mixed_rate=0.8, mixed_invalid=0.5,
                 quantum_m=0.001, ir_albedo=_ALBEDO, material_bias_m=_HOLOLENS_SKIN_BIAS_M)

PRESETS: dict[str, SensorPreset] = {
    "azure_kinect_nfov": SensorPreset(
        "azure_kinect_nfov", resolution=(640, 576), fov_deg=(75.0, 65.0), offset_m=(0.032, -0.002, 0.004),
        tilt_deg=6.0, min_range_m=0.5, max_range_m=3.86, wrap_m=0.0, sigma_m=0.0015, bias_sigma_m=0.002,
        range_ref_m=1.0, signal_floor=0.2, dropout=0.005, edge_m=0.02, mixed_rate=0.9, mixed_invalid=0.8,
        quantum_m=0.001, ir_albedo=_ALBEDO, material_bias_m={}),
    "hololens2_ahat": SensorPreset("hololens2_ahat", resolution=(512, 512), min_range_m=0.1, max_range_m=4.0,
                                   wrap_m=1.0, sigma_m=0.002, **_HOLOLENS),
    "hololens2_longthrow": SensorPreset("hololens2_longthrow", resolution=(320, 288), min_range_m=0.2,
                                        max_range_m=4.0, wrap_m=0.0, sigma_m=0.003, **_HOLOLENS),
}


def preset(name: str, where: str = "dataset.depth_sensor") -> SensorPreset | None:
    """The preset called ``name`` (None for ``none``), or a BadValueError naming ``where`` and the choices."""
    if name == NONE:
        return None
    if not isinstance(name, str) or name not in PRESETS:
        raise BadValueError(f"{where} must be one of {', '.join([NONE, *PRESETS])}, got {name!r}")
    return PRESETS[name]


def frame_rng(seed: int, frame_id: int, sensor: str, draw: int = 0) -> np.random.Generator:
    """The generator of one frame's sensor noise: the dataset's ``seed``, the frame's id, the preset and ``draw``
    (0: the dataset's own sample; a training epoch's fresh sample otherwise)."""
    return np.random.default_rng([int(seed), int(frame_id), zlib.crc32(sensor.encode()), int(draw)])


def _rays(K: np.ndarray, shape: tuple[int, int], sub: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Normalised image coordinates (x, y) of every pixel of an ``shape`` (H, W) image, each pixel split into
    ``sub`` x ``sub`` samples: two (H * sub, W * sub) arrays."""
    h, w = shape
    offsets = (np.arange(sub) + 0.5) / sub - 0.5
    u = (np.arange(w)[:, None] + offsets[None]).reshape(-1)
    v = (np.arange(h)[:, None] + offsets[None]).reshape(-1)
    return np.broadcast_to((u[None] - K[0, 2]) / K[0, 0], (h * sub, w * sub)), \
        np.broadcast_to(((v - K[1, 2]) / K[1, 1])[:, None], (h * sub, w * sub))


def _splat(z: np.ndarray, labels: np.ndarray, K_src: np.ndarray, R: np.ndarray, t: np.ndarray, K_dst: np.ndarray,
           shape_dst: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """The surface of depth map ``z`` (0 = none) in camera ``K_src`` seen from a camera ``K_dst`` of size
    ``shape_dst`` whose frame maps source points as ``R p + t``: (H, W) nearest depth (0 = none) and its ``labels``
    ((H, W) or (H, W, C) values carried with each pixel). Each source pixel is split finely enough that its samples land less than a destination pixel apart."""
    density = max(K_dst[0, 0] / K_src[0, 0], K_dst[1, 1] / K_src[1, 1])
    sub = int(density * 1.2) + 1
    if sub > 1:
        z = np.repeat(np.repeat(z, sub, 0), sub, 1)
        labels = np.repeat(np.repeat(labels, sub, 0), sub, 1)
    x, y = _rays(K_src, (z.shape[0] // sub, z.shape[1] // sub), sub)
    keep = z > 0
    zk = z[keep]
    xk, yk = x[keep] * zk, y[keep] * zk
    px, py, zd = (R[i, 0] * xk + R[i, 1] * yk + R[i, 2] * zk + t[i] for i in range(3))
    front = zd > 1e-6
    px, py, zd, lab = px[front], py[front], zd[front], labels[keep][front]
    u = np.rint(K_dst[0, 0] * px / zd + K_dst[0, 2]).astype(np.int64)
    v = np.rint(K_dst[1, 1] * py / zd + K_dst[1, 2]).astype(np.int64)
    h, w = shape_dst
    inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
    index, zd, lab = v[inside] * w + u[inside], zd[inside], lab[inside]
    out = np.full(h * w, np.inf)
    np.minimum.at(out, index, zd)
    out_labels = np.zeros((h * w,) + labels.shape[2:], dtype=labels.dtype)
    nearest = zd == out[index]
    out_labels[index[nearest]] = lab[nearest]
    out[np.isinf(out)] = 0.0
    return out.reshape(h, w), out_labels.reshape((h, w) + labels.shape[2:])


def _crop(z: np.ndarray, labels: np.ndarray, K: np.ndarray, margin: int = 2
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The part of a depth image that has surface (with ``margin`` pixels around it), its labels and its K: the
    depth camera sees far more than the colour camera, and only what the colour camera sees matters."""
    rows, cols = np.flatnonzero(z.any(1)), np.flatnonzero(z.any(0))
    if rows.size == 0:
        return z[:1, :1], labels[:1, :1], K
    r0, r1 = max(rows[0] - margin, 0), min(rows[-1] + margin + 1, z.shape[0])
    c0, c1 = max(cols[0] - margin, 0), min(cols[-1] + margin + 1, z.shape[1])
    K = K.copy()
    K[0, 2] -= c0
    K[1, 2] -= r0
    return z[r0:r1, c0:c1], labels[r0:r1, c0:c1], K


def _surface_gradient(z: np.ndarray, axis: int, jump_m: float = 0.01) -> np.ndarray:
    """d(depth) / d(pixel) along ``axis`` from the neighbours on the same surface (a neighbour without a surface, or
    more than ``jump_m`` away, is another surface): central where both are, one-sided where one is, else 0."""
    padded = np.pad(z, [(1, 1) if a == axis else (0, 0) for a in range(2)])
    take = [slice(None), slice(None)]
    take[axis] = slice(2, None)
    after = padded[tuple(take)]
    take[axis] = slice(None, -2)
    before = padded[tuple(take)]
    has_after = (after > 0) & (np.abs(after - z) < jump_m)
    has_before = (before > 0) & (np.abs(z - before) < jump_m)
    both = has_after & has_before
    return np.where(both, (after - before) / 2, np.where(has_after, after - z, np.where(has_before, z - before, 0.0)))


def _incidence_cos(z: np.ndarray, K: np.ndarray) -> np.ndarray:
    """|cos| of the angle between each pixel's ray and its surface normal (from the depth map's gradient on the
    pixel's own surface, :func:`_surface_gradient`)."""
    x, y = _rays(K, z.shape)
    zu, zv = _surface_gradient(z, 1), _surface_gradient(z, 0)
    du = np.stack([zu * x + z / K[0, 0], zu * y, zu], -1)
    dv = np.stack([zv * x, zv * y + z / K[1, 1], zv], -1)
    normal = np.cross(du, dv)
    ray = np.stack([x, y, np.ones_like(x)], -1)
    num = np.abs((normal * ray).sum(-1))
    den = np.linalg.norm(normal, axis=-1) * np.linalg.norm(ray, axis=-1)
    return np.where(den > 0, num / np.where(den > 0, den, 1.0), 1.0)


def _edges(z: np.ndarray, edge_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pixels with a surface whose 3 x 3 neighbourhood spans more than ``edge_m`` of depth, and that
    neighbourhood's nearest and farthest surface (metres)."""
    kernel = np.ones((3, 3), np.uint8)
    near = cv2.erode(np.where(z > 0, z, np.inf).astype(np.float32), kernel).astype(np.float64)
    far = cv2.dilate(z.astype(np.float32), kernel).astype(np.float64)
    return (z > 0) & (far - near > edge_m), near, far


def _albedo(labels: np.ndarray, label_ids: dict[str, int], sensor: SensorPreset) -> np.ndarray:
    table = np.full(256, 0.5)
    for name, value in sensor.ir_albedo.items():
        if name in label_ids:
            table[label_ids[name]] = value
    return table[labels]


def _material_bias(labels: np.ndarray, label_ids: dict[str, int], sensor: SensorPreset) -> np.ndarray:
    table = np.zeros(256)
    for name, value in sensor.material_bias_m.items():
        if name in label_ids:
            table[label_ids[name]] = value
    return table[labels]


def invalid_probability(z: np.ndarray, labels: np.ndarray, K: np.ndarray, sensor: SensorPreset,
                        label_ids: dict[str, int]) -> np.ndarray:
    """Each pixel's chance of returning no depth from its signal and the dropout alone (step 2), for a depth map
    ``z`` (metres, 0 = none) and its labels seen by the camera ``K``; 0 where there is no surface."""
    x, y = _rays(K, z.shape)
    range_m = z * np.sqrt(x * x + y * y + 1.0)
    cos = _incidence_cos(z, K)
    signal = _albedo(labels, label_ids, sensor) * cos * (sensor.range_ref_m / np.maximum(range_m, 1e-6)) ** 2
    low = np.clip(1.0 - signal / sensor.signal_floor, 0.0, 1.0)
    return np.where(z > 0, 1.0 - (1.0 - sensor.dropout) * (1.0 - low), 0.0)


def _depth_camera(depth_m: np.ndarray, labels: np.ndarray, K: np.ndarray, sensor: SensorPreset) -> dict:
    """Step 1: the clean surface seen by the depth camera (cropped to what the colour camera sees): "z" depth and
    "labels" there, its "K", its "R" and "offset" in the colour camera's frame, "scale" (range / depth per pixel)."""
    depth_m = np.asarray(depth_m, dtype=np.float64)
    if depth_m.ndim != 2 or labels.shape != depth_m.shape:
        raise BadValueError(f"sensor_depth: depth {depth_m.shape} and labels {labels.shape} must be one (H, W) shape")
    R, offset = sensor.rotation(), np.asarray(sensor.offset_m, dtype=np.float64)
    z, lab = _splat(depth_m, labels, K, R.T, -R.T @ offset, sensor.intrinsics(), sensor.resolution[::-1])
    z, lab, K_d = _crop(z, lab, sensor.intrinsics())
    x, y = _rays(K_d, z.shape)
    # a depth d along the depth camera's axis is the colour camera's depth d * to_colour + offset[2]
    to_colour = R[2, 0] * x + R[2, 1] * y + R[2, 2]
    return {"z": z, "labels": lab, "K": K_d, "R": R, "offset": offset, "scale": np.sqrt(x * x + y * y + 1.0),
            "to_colour": to_colour}


def _colour_depth(view: dict, z: np.ndarray) -> np.ndarray:
    """Depths ``z`` along the depth camera's rays as the colour camera's depth of the same points (0 stays 0)."""
    return np.where(z > 0, z * view["to_colour"] + view["offset"][2], 0.0)


def _expected_range(view: dict, sensor: SensorPreset, label_ids: dict[str, int]) -> np.ndarray:
    """The range the sensor reads without its random error and per-frame offset: the material's offset added and
    wrapped where the phase wraps."""
    measured = view["z"] * view["scale"] + _material_bias(view["labels"], label_ids, sensor)
    return np.mod(measured, sensor.wrap_m) if sensor.wrap_m > 0 else measured


def _out_of_range(view: dict, sensor: SensorPreset) -> np.ndarray:
    range_m = view["z"] * view["scale"]
    return (range_m < sensor.min_range_m) | (range_m > sensor.max_range_m)


def sensor_depth(depth_m: np.ndarray, labels: np.ndarray, K: np.ndarray, sensor: SensorPreset,
                 label_ids: dict[str, int], rng: np.random.Generator) -> np.ndarray:
    """What ``sensor`` measures of a scene whose clean depth the colour camera ``K`` saw as ``depth_m``.

    Args:
        depth_m: (H, W) float metres along the colour camera's axis, 0 = no surface. labels: (H, W) uint8, each
            pixel's material (the dataset's seg map). K: (3, 3) the colour camera's intrinsics.
        sensor: the preset. label_ids: {material name: label}. rng: the frame's noise (:func:`frame_rng`).

    Returns:
        (H, W) float64 depth in metres in the colour image, 0 where the sensor gives none.
    """
    view = _depth_camera(depth_m, labels, K, sensor)
    z, lab, K_d, scale = view["z"], view["labels"], view["K"], view["scale"]
    valid = z > 0
    invalid = valid & (rng.random(z.shape) < invalid_probability(z, lab, K_d, sensor, label_ids))
    edge, near, far = _edges(z, sensor.edge_m)
    mixed = edge & (rng.random(z.shape) < sensor.mixed_rate)
    mixed_invalid = mixed & (rng.random(z.shape) < sensor.mixed_invalid)
    fly = mixed & ~mixed_invalid & np.isfinite(near) & (far > 0)
    w = rng.random(z.shape)
    flown = z.copy()
    flown[fly] = near[fly] + w[fly] * (far[fly] - near[fly])
    range_m = flown * scale
    measured = (range_m + rng.normal(0.0, 1.0, z.shape) * sensor.noise_sigma_m(range_m)
                + rng.normal(0.0, sensor.bias_sigma_m) + _material_bias(lab, label_ids, sensor))
    if sensor.wrap_m > 0:
        measured = np.mod(measured, sensor.wrap_m)
    out = np.round(measured / scale / sensor.quantum_m) * sensor.quantum_m
    out[~valid | invalid | mixed_invalid | _out_of_range(view, sensor) | (measured <= 0)] = 0.0
    _, colour = _splat(z, _colour_depth(view, out), K_d, view["R"], view["offset"], K, np.asarray(depth_m).shape)
    return colour


def sensor_expectation(depth_m: np.ndarray, labels: np.ndarray, K: np.ndarray, sensor: SensorPreset,
                       label_ids: dict[str, int]) -> dict[str, np.ndarray]:
    """What :func:`sensor_depth` gives each colour pixel on average, for checking a measured frame against the preset
    (``hupbench verify``): (H, W) maps of "seen" (the depth camera sees that surface), "z" (the depth it reads without
    random error or per-frame offset: the material's offset and the wrap in), "sigma_m" (its random error in depth,
    quantisation in), "p_invalid" (its chance of giving no depth: signal, dropout, mixed pixels, range) and "steady"
    (no depth edge near, in range, not within 4 sigma of a wrap: where "z" and "sigma_m" say all)."""
    view = _depth_camera(depth_m, labels, K, sensor)
    z, scale = view["z"], view["scale"]
    edge, _, _ = _edges(z, sensor.edge_m)
    near_edge = cv2.dilate(edge.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    expected = _expected_range(view, sensor, label_ids)
    sigma = sensor.noise_sigma_m(z * scale)
    margin = 4 * (sigma + sensor.bias_sigma_m)
    wrapped = (expected < margin) | ((expected > sensor.wrap_m - margin) if sensor.wrap_m > 0 else False)
    out_of_range = _out_of_range(view, sensor)
    p = invalid_probability(z, view["labels"], view["K"], sensor, label_ids)
    p = np.where(out_of_range, 1.0, 1.0 - (1.0 - p) * (1.0 - edge * sensor.mixed_rate * sensor.mixed_invalid))
    steady = (z > 0) & ~near_edge & ~out_of_range & ~wrapped
    sigma_z = np.sqrt((sigma / scale) ** 2 + sensor.quantum_m ** 2 / 12) * view["to_colour"]
    channels = np.stack([_colour_depth(view, expected / scale), sigma_z, p, steady, np.ones_like(z)], -1)
    _, back = _splat(z, channels, view["K"], view["R"], view["offset"], K, np.asarray(depth_m).shape)
    return {"z": back[..., 0], "sigma_m": back[..., 1], "p_invalid": back[..., 2], "steady": back[..., 3] > 0.5,
            "seen": back[..., 4] > 0.5}


def stored_sensor_depth(depth: np.ndarray, labels: np.ndarray, K: np.ndarray, sensor: SensorPreset,
                        label_ids: dict[str, int], depth_scale_m: float, seed: int, frame_id: int,
                        draw: int = 0) -> np.ndarray:
    """A stored frame's sensor depth: :func:`sensor_depth` of its stored clean depth (uint16, ``depth_scale_m`` per
    unit) with the frame's noise (:func:`frame_rng`), in the same unit. The generator writes ``draw`` 0; the
    reader computes the same bytes from the stored clean depth, or a fresh sample with another ``draw``."""
    out = sensor_depth(depth.astype(np.float64) * depth_scale_m, labels, K, sensor, label_ids,
                       frame_rng(seed, frame_id, sensor.name, draw))
    return np.clip(np.round(out / depth_scale_m), 0, np.iinfo(np.uint16).max).astype(np.uint16)


#: how far beyond a preset's last measurable depth a user's depth may reach before it is called one the preset cannot
#: give (the depth camera's offset and the per-pixel ray put the colour camera's depth a little past the range)
BEYOND_SLACK_M = 0.05


def depth_input_warnings(depth_m: np.ndarray, sensor: SensorPreset) -> list[str]:
    """Why a user's depth map (metres, 0 = none) looks like no depth ``sensor`` (the model's training sensor) gives:
    no invalid pixel at all (a renderer's z-buffer), or depths beyond what it measures (its wrap or its range)."""
    out = []
    if np.all(depth_m > 0):
        out.append(f"no pixel of the depth map is 0 (no depth): a {sensor.name} depth camera leaves holes (dark "
                   "plastic, depth edges, grazing surfaces), so this looks like a renderer's z-buffer, not the depth "
                   "the model was trained on")
    limit = sensor.wrap_m if sensor.wrap_m > 0 else sensor.max_range_m
    beyond = float((depth_m > limit + BEYOND_SLACK_M).mean())
    if beyond > 0:
        why = "its range wraps there" if sensor.wrap_m > 0 else "its range ends there"
        out.append(f"{beyond:.1%} of the depth map lies beyond {limit:g} m, which a {sensor.name} depth camera does "
                   f"not give ({why}): the model was trained on that camera's depth")
    return out
