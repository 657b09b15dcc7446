"""The probe as the fits know it: its gridded signed distance, its box corners and its orientation marker, in numpy,
built from the generator's probe (eval, training) or read back from a model file (``hupbench predict``, no torch).

The grid is the generator's own (:class:`hupbench.datagen.assets.probe.Probe`: exact signed distances at the nodes,
negative inside, probe frame, metres), evaluated here by the same trilinear formula and its analytic gradient; outside
the grid's box the distance to the box is added and the gradient points away from it. A model that fits carries its
probe in its ONNX file (``hupbench.fit_probe``, :meth:`FitProbe.to_json`), so that predict fits the probe the model
was trained with and needs neither the generator nor torch.
"""

from __future__ import annotations

import base64
import functools
import hashlib
import json
import zlib
from dataclasses import dataclass

import numpy as np

from hupbench.core.errors import BadValueError

__all__ = ["FitProbe", "dataset_fit_probe", "default_fit_probe"]

#: the version of :meth:`FitProbe.to_json`'s layout
_SCHEMA = 1


@dataclass(frozen=True, eq=False)
class FitProbe:
    """A probe's shape for the fits.

    Attributes:
        record: which probe this is (a dataset manifest's ``probe``: ``{"kind": "procedural"}`` or a mesh's record).
        grid: (X, Y, Z) float32 signed distances at the nodes ``origin + spacing * (i, j, k)``, metres, negative
            inside; origin: (3,) float64, probe frame; spacing: metres.
        corners: (8, 3) float64, the probe's box corners (keypoints 21-28), probe frame.
        marker: (3,) float64, the marker's centre, and marker_normal: (3,) its outward unit normal, probe frame.
        marker_channel: the marker colour's strongest channel (0 R, 1 G, 2 B).
        has_marker: whether the probe carries the marker (a mesh probe may not: its half turn is the network's).
    """

    record: dict
    grid: np.ndarray
    origin: np.ndarray
    spacing: float
    corners: np.ndarray
    marker: np.ndarray
    marker_normal: np.ndarray
    marker_channel: int
    has_marker: bool = True

    def marker_lead(self, rgb: np.ndarray, axis: int = -1) -> np.ndarray:
        """How far the marker colour's channel leads the other two in ``rgb`` (channels on ``axis``, values in
        [0, 1]): above about 0.1 a pixel has the marker's colour."""
        c = self.marker_channel
        return np.take(rgb, c, axis=axis) - np.delete(rgb, c, axis=axis).max(axis=axis)

    @property
    def upper(self) -> np.ndarray:
        """(3,) float64: the grid's last node, probe frame."""
        return self.origin + self.spacing * (np.array(self.grid.shape) - 1)

    @functools.cached_property
    def _flat_grid(self) -> np.ndarray:
        """The grid's values flat, float64 (converted once, not at every gather)."""
        return self.grid.reshape(-1).astype(np.float64)

    def signed_distance_and_gradient(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """((...) signed distance, metres, negative inside; (..., 3) its gradient) at points (..., 3) float, metres,
        probe frame; float64."""
        p = np.asarray(points, dtype=np.float64)
        clamped = np.minimum(np.maximum(p, self.origin), self.upper)
        u = (clamped - self.origin) / self.spacing
        shape = np.array(self.grid.shape)
        i0 = np.minimum(np.maximum(np.floor(u).astype(np.int64), 0), shape - 2)
        fx, fy, fz = np.moveaxis(u - i0, -1, 0)
        flat = self._flat_grid
        sy, sx = shape[2], shape[1] * shape[2]
        base = i0[..., 0] * sx + i0[..., 1] * sy + i0[..., 2]
        ax, dx = {}, {}
        for b in (0, 1):
            for c in (0, 1):
                v0, v1 = flat[base + b * sy + c], flat[base + sx + b * sy + c]
                dx[b, c] = v1 - v0
                ax[b, c] = v0 + fx * dx[b, c]
        by = {c: ax[0, c] + fy * (ax[1, c] - ax[0, c]) for c in (0, 1)}
        bdx = {c: dx[0, c] + fy * (dx[1, c] - dx[0, c]) for c in (0, 1)}
        bdy = {c: ax[1, c] - ax[0, c] for c in (0, 1)}
        value = by[0] + fz * (by[1] - by[0])
        grad = np.stack([bdx[0] + fz * (bdx[1] - bdx[0]), bdy[0] + fz * (bdy[1] - bdy[0]), by[1] - by[0]],
                        axis=-1) / self.spacing
        out = p - clamped
        ox, oy, oz = np.moveaxis(out, -1, 0)
        dist_out = np.sqrt(ox * ox + oy * oy + oz * oz)
        away = out / np.maximum(dist_out, 1e-12)[..., None]
        return value + dist_out, np.where((dist_out > 0)[..., None], away, grad)

    @classmethod
    def of(cls, probe, marker_rgb) -> "FitProbe":
        """The fits' view of a generator probe (:class:`hupbench.datagen.assets.probe.Probe`) whose marker is drawn in
        ``marker_rgb`` (3,): the marker's centre and normal are the area-weighted mean of its faces'."""
        mesh = probe.mesh
        marked = np.flatnonzero(probe.marker_face_mask)
        if len(marked):
            area = mesh.area_faces[marked]
            centre = (mesh.triangles_center[marked] * area[:, None]).sum(0) / area.sum()
            normal = (mesh.face_normals[marked] * area[:, None]).sum(0)
            normal = normal / np.linalg.norm(normal)
        else:  # a probe without a marker (has_marker False: the site is never looked at)
            centre, normal = np.zeros(3), np.array([0.0, 0.0, -1.0])
        return cls(dict(probe.record), np.asarray(probe.sdf_grid, dtype=np.float32), np.array(probe.sdf_origin, float),
                   float(probe.sdf_spacing), np.array(probe.corners_probe, float), np.asarray(centre, float),
                   np.asarray(normal, float), int(np.argmax(marker_rgb)), bool(len(marked)))

    def to_json(self) -> str:
        """This probe as a JSON string (the grid float32, zlib-compressed, base64, with its sha256)."""
        data = np.ascontiguousarray(self.grid, dtype="<f4").tobytes()
        return json.dumps({
            "schema": _SCHEMA, "record": self.record, "shape": list(self.grid.shape),
            "origin": self.origin.tolist(), "spacing": self.spacing, "corners": self.corners.tolist(),
            "marker": self.marker.tolist(), "marker_normal": self.marker_normal.tolist(),
            "marker_channel": self.marker_channel, "has_marker": self.has_marker,
            "grid_sha256": hashlib.sha256(data).hexdigest(),
            "grid": base64.b64encode(zlib.compress(data, 6)).decode("ascii")}, sort_keys=True)

    @classmethod
    def from_json(cls, text: str, source: str) -> "FitProbe":
        """Read :meth:`to_json`'s string; ``source`` names it in the error.

        Raises:
            BadValueError: not that layout, or its grid damaged (one line naming what).
        """
        try:
            d = json.loads(text)
            shape = tuple(int(n) for n in d["shape"])
            data = zlib.decompress(base64.b64decode(d["grid"], validate=True))
            fields = (d["schema"], d["record"], d["origin"], d["spacing"], d["corners"], d["marker"],
                      d["marker_normal"], d["marker_channel"], d["has_marker"], d["grid_sha256"])
        except (ValueError, KeyError, TypeError, zlib.error) as exc:
            raise BadValueError(f"{source}: not a probe of the fits ({type(exc).__name__}: {exc})") from None
        schema, record, origin, spacing, corners, marker, normal, channel, has_marker, sha = fields
        if schema != _SCHEMA:
            raise BadValueError(f"{source}: probe layout {schema!r}; this hupbench reads {_SCHEMA}")
        if hashlib.sha256(data).hexdigest() != sha or len(shape) != 3 or len(data) != 4 * int(np.prod(shape)):
            raise BadValueError(f"{source}: the probe's distance grid is damaged (its bytes do not match its sha256 "
                                f"or its shape {list(shape)})")
        arrays = [np.asarray(a, dtype=np.float64) for a in (origin, corners, marker, normal)]
        if ([a.shape for a in arrays] != [(3,), (8, 3), (3,), (3,)] or not all(np.isfinite(a).all() for a in arrays)
                or not isinstance(record, dict) or channel not in (0, 1, 2) or not float(spacing) > 0
                or not isinstance(has_marker, bool)):
            raise BadValueError(f"{source}: the probe's origin, corners, marker or spacing are not what the fits read")
        grid = np.frombuffer(data, dtype="<f4").reshape(shape).astype(np.float32)
        return cls(record, grid, arrays[0], float(spacing), arrays[1], arrays[2], arrays[3], int(channel), has_marker)


@functools.lru_cache(maxsize=1)
def default_fit_probe() -> FitProbe:
    """The procedural probe of the default spec, as the fits know it (built by the generator once per process)."""
    from hupbench.datagen.assets.probe import build_probe
    from hupbench.datagen.render.scene import PROBE_MARKER_RGB

    return FitProbe.of(build_probe(), PROBE_MARKER_RGB)


def dataset_fit_probe(dataset) -> FitProbe:
    """The probe a dataset folder was rendered with (its manifest's record; a mesh probe rebuilt from its
    ``grasps.npz``), as the fits know it: what a model trained on that dataset fits."""
    from hupbench.datagen.dataset.grasps_file import probe_of_dataset
    from hupbench.datagen.render.scene import PROBE_MARKER_RGB

    probe = probe_of_dataset(dataset)
    return default_fit_probe() if probe.record == default_fit_probe().record else FitProbe.of(probe, PROBE_MARKER_RGB)
