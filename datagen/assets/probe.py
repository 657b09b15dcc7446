"""The procedural convex-array abdominal ultrasound probe and its signed distance.

:func:`build_probe` assembles the probe: the swept shape of :mod:`hupbench.datagen.assets.probe_shape` with the
orientation marker of :mod:`hupbench.datagen.assets.probe_marker`, its box corners (keypoints 21-28), regions
and a gridded signed distance.

The signed distance is gridded: exact point-to-triangle distances
(:mod:`hupbench.datagen.mesh_distance`) at the nodes of a regular grid, signed with angle-weighted
pseudo-normals, then interpolated trilinearly (numpy and differentiable torch versions of the
same formula). The grid of the symmetric sweep is computed on one quadrant and mirrored;
the nodes the marker can affect are then recomputed exactly on the marked
mesh, so every node is exact for the probe as built.

Convention:
    Metres. Probe frame: origin at the lens apex (the centre of the curved
    acoustic face, the point that touches the patient); +z along the long
    axis from the lens towards the cable end; +x along the transducer array
    (the 72 mm head width); +y across the head (the 22 mm head thickness);
    right-handed. Signed distances are NEGATIVE INSIDE the probe and positive
    outside (the opposite of ``trimesh.proximity.signed_distance``).
"""

from __future__ import annotations

import functools
from dataclasses import asdict

import numpy as np
import torch
import trimesh

from hupbench.core import tolerances as tol
from hupbench.datagen.assets.probe_marker import add_marker
from hupbench.datagen.assets.probe_mesh import (
    ProbeMeshSpec,
    ProbeSource,
    TriangleDistance,
    box_corners,
    marker_patch,
    mesh_probe_record,
    probe_geometry_sha256,
    read_cached,
    regions,
    signed_grid,
)
from hupbench.datagen.assets.probe_shape import (
    ProbeSpec,
    RegionZ,
    build_rings,
    lens_sag,
    ring_faces,
)
from hupbench.core.keypoints import CORNER_BITS
from hupbench.datagen.mesh_distance import MeshDistance

__all__ = ["Probe", "ProbeSpec", "RegionZ", "build_mesh_probe", "build_probe", "probe_of"]


def _patch_grid(grid: np.ndarray, axes: tuple[np.ndarray, np.ndarray, np.ndarray], distance: "MeshDistance",
                changed_lo: np.ndarray, changed_hi: np.ndarray) -> np.ndarray:
    """Exact signed distances of the marked mesh from those of the symmetric sweep.

    The two surfaces differ only inside the box ``[changed_lo, changed_hi]``.
    A node whose distance to that box exceeds its old unsigned distance keeps
    its closest point (outside the box, on both surfaces) and its side (it is
    not between the two surfaces), so its value is unchanged; every other
    node is recomputed exactly on the marked mesh.

    Args:
        grid: (nx, ny, nz) float64 exact signed distances to the sweep, metres.
        axes: node coordinates along x, y, z, metres.
        distance: the marked mesh's exact distance.
        changed_lo, changed_hi: (3,) float64, metres, probe frame.

    Returns:
        (nx, ny, nz) float64, a new array.
    """
    xs, ys, zs = axes
    gap = [np.maximum(np.maximum(lo - c, c - hi), 0.0) for c, lo, hi in zip(axes, changed_lo, changed_hi)]
    to_box = np.sqrt(gap[0][:, None, None] ** 2 + gap[1][None, :, None] ** 2 + gap[2][None, None, :] ** 2)
    redo = np.argwhere(to_box <= np.abs(grid) + tol.PROBE_SDF_PRUNE_SLACK_M)
    out = grid.copy()
    points = np.column_stack([xs[redo[:, 0]], ys[redo[:, 1]], zs[redo[:, 2]]])
    out[redo[:, 0], redo[:, 1], redo[:, 2]] = distance.signed(points)
    return out


# --------------------------------------------------------------------------- the probe


def _as_points(points: np.ndarray) -> np.ndarray:
    """(..., 3) points as float64; callers hand in points this package computed, finite."""
    assert not isinstance(points, torch.Tensor), "signed_distance_torch takes tensors"
    arr = np.asarray(points, dtype=np.float64)
    assert arr.ndim >= 1 and arr.shape[-1] == 3, arr.shape
    return arr


class Probe:
    """The procedural probe: mesh, lens faces, box corners, regions and signed distance.

    Build it with :func:`build_probe` (cached: the same spec gives the same
    object, so treat every attribute as read-only; copy the mesh before
    changing it).

    Attributes:
        spec: the :class:`ProbeSpec` it was built from, or for a mesh probe
            (:func:`build_mesh_probe`) its :class:`hupbench.datagen.assets.probe_mesh.ProbeMeshSpec`.
        marker_patch: a mesh probe's orientation marker, a patch laid on its
            surface (``trimesh.Trimesh``, probe frame; None without one); None
            for the procedural probe, whose marker is part of ``mesh``.
        mesh: ``trimesh.Trimesh`` in the probe frame, metres: watertight,
            outward-wound, smooth vertex normals (no creases anywhere);
            exactly mirror-symmetric about y = 0, and about x = 0 except for
            the orientation marker on the +x end (with ``marker_height = 0``
            symmetric about both, hence also under the half turn about z).
        lens_face_mask: (F,) bool, the faces of the acoustic lens.
        marker_face_mask: (F,) bool, the faces of the orientation marker's
            footprint (all False without a marker); disjoint from the lens.
        corners_probe: (8, 3) float64, metres, probe frame: the tight
            axis-aligned box of the mesh (the marker stays inside the box of
            the sweep, so the box is centred on the long axis and also the
            minimum-volume oriented box), corner k at
            ``(x, y, z)[(min, max)[bit]]`` with bits ``CORNER_BITS[k]``, the
            ``itertools.product((min, max), repeat=3)`` order of
            :mod:`hupbench.core.keypoints`.
        region_z: :class:`RegionZ`, z ranges of lens, head, neck, handle and
            strain relief, metres, probe frame.
        sdf_grid: (nx, ny, nz) float64 exact signed distances (metres,
            negative inside) at the grid nodes ``sdf_origin + sdf_spacing *
            (i, j, k)``.
        sdf_origin: (3,) float64, metres, probe frame: the node (0, 0, 0).
        sdf_spacing: node spacing, metres.
    """

    def __init__(self, spec, mesh: trimesh.Trimesh, lens_face_mask: np.ndarray,
                 marker_face_mask: np.ndarray, region_z: RegionZ, distance,
                 sdf_axes: tuple[np.ndarray, np.ndarray, np.ndarray], sdf_grid: np.ndarray,
                 marker_patch: trimesh.Trimesh | None = None):
        self.spec = spec
        self.marker_patch = marker_patch
        self.mesh = mesh
        self.lens_face_mask = lens_face_mask
        self.marker_face_mask = marker_face_mask
        self.region_z = region_z
        self.corners_probe = box_corners(mesh.bounds)
        self._distance = distance
        xs, ys, zs = sdf_axes
        self.sdf_grid = sdf_grid
        self.sdf_origin = np.array([xs[0], ys[0], zs[0]])
        self.sdf_spacing = float(spec.sdf_spacing)
        self._sdf_upper = np.array([xs[-1], ys[-1], zs[-1]])
        for arr in (self.lens_face_mask, self.marker_face_mask, self.corners_probe, self.sdf_grid, self.sdf_origin,
                    self._sdf_upper):
            arr.flags.writeable = False
        self._torch_cache: dict[tuple[str, torch.dtype], tuple[torch.Tensor, ...]] = {}

    @property
    def record(self) -> dict:
        """Which probe this is, as a dataset's manifest and a grasps file record it: ``{"kind": "procedural"}``
        or ``{"kind": "mesh", "path", "sha256" (of the file), "unit", "align", "geometry_sha256"}``."""
        if isinstance(self.spec, ProbeSpec):
            return {"kind": "procedural"} if self.spec == ProbeSpec() else {"kind": "procedural", "spec": asdict(self.spec)}
        return mesh_probe_record(self.spec, self.mesh.vertices, self.mesh.faces)

    # ---------------------------------------------------------------- numpy

    def _cell(self, points: np.ndarray):
        """Clamp to the grid box; cell indices, fractions and the offset to the box."""
        clamped = np.clip(points, self.sdf_origin, self._sdf_upper)
        u = (clamped - self.sdf_origin) / self.sdf_spacing
        n = np.array(self.sdf_grid.shape)
        i0 = np.clip(np.floor(u).astype(np.int64), 0, n - 2)
        return i0, u - i0, points - clamped

    def _corner_values(self, i0: np.ndarray) -> np.ndarray:
        """(..., 2, 2, 2) grid values around the cells ``i0`` (..., 3), indexed [dx, dy, dz]."""
        g = self.sdf_grid
        d = np.array(CORNER_BITS).T  # (3, 8): the 8 offsets in (dx, dy, dz) binary order
        ix, iy, iz = (i0[..., a, None] + d[a] for a in range(3))
        return g[ix, iy, iz].reshape(i0.shape[:-1] + (2, 2, 2))

    def signed_distance(self, points_probe: np.ndarray) -> np.ndarray:
        """Signed distance to the probe surface, negative inside.

        Trilinear interpolation of exact signed distances at the grid nodes
        (exact at the nodes; between them off by at most a few tenths of a
        millimetre, where the field bends: near the medial surface inside and
        on tight curves). Outside the grid box the point is clamped to the
        box and its distance from the box added: an upper bound of the true
        distance there (up to the interpolation error on the box face, which
        lies ``sdf_margin`` from the surface); exact when the direction to the
        closest surface point is normal to that face.

        Args:
            points_probe: (..., 3) float, metres, probe frame.

        Returns:
            (...) float64, metres: negative inside, positive outside.
        """
        p = _as_points(points_probe)
        i0, f, outside = self._cell(p)
        w = np.stack([1.0 - f, f], axis=-1)  # (..., 3, 2) weights of the low and high node per axis
        corners = self._corner_values(i0)
        value = np.einsum("...abc,...a,...b,...c->...", corners, w[..., 0, :], w[..., 1, :], w[..., 2, :])
        return value + np.linalg.norm(outside, axis=-1)

    def signed_distance_gradient(self, points_probe: np.ndarray) -> np.ndarray:
        """Gradient of :meth:`signed_distance` (the analytic trilinear gradient).

        Args:
            points_probe: (..., 3) float, metres, probe frame.

        Returns:
            (..., 3) float64, metres per metre, probe frame. Inside the grid
            it is piecewise smooth (it jumps across cell faces); outside, the
            interpolant's gradient along the box face plus the unit vector
            away from the box.
        """
        p = _as_points(points_probe)
        i0, f, outside = self._cell(p)
        c = self._corner_values(i0)  # (..., 2, 2, 2) over (x, y, z)
        w = np.stack([1 - f, f], axis=-1)  # (..., 3, 2) interpolation weights per axis
        diff = np.array([-1.0, 1.0])
        gx = np.einsum("...abc,a,...b,...c->...", c, diff, w[..., 1, :], w[..., 2, :])
        gy = np.einsum("...abc,...a,b,...c->...", c, w[..., 0, :], diff, w[..., 2, :])
        gz = np.einsum("...abc,...a,...b,c->...", c, w[..., 0, :], w[..., 1, :], diff)
        grad = np.stack([gx, gy, gz], axis=-1) / self.sdf_spacing
        # the clamped coordinates do not move with the point
        grad = np.where(outside != 0, 0.0, grad)
        dist_out = np.linalg.norm(outside, axis=-1, keepdims=True)
        return grad + np.divide(outside, dist_out, out=np.zeros_like(outside), where=dist_out > 0)

    def surface_normal(self, points_probe: np.ndarray) -> np.ndarray:
        """Unit outward normal field: the normalised gradient of the signed distance.

        Args:
            points_probe: (..., 3) float, metres, probe frame.

        Returns:
            (..., 3) float64 unit vectors, probe frame; (0, 0, 0) where the
            gradient vanishes (below ``tol.PROBE_SDF_MIN_GRADIENT``, e.g.
            exactly on a symmetry plane deep inside, where the field has no
            direction).
        """
        g = self.signed_distance_gradient(points_probe)
        n = np.linalg.norm(g, axis=-1, keepdims=True)
        return np.divide(g, n, out=np.zeros_like(g), where=n > tol.PROBE_SDF_MIN_GRADIENT)

    def signed_distance_exact(self, points_probe: np.ndarray) -> np.ndarray:
        """Exact signed distance to the mesh, without the grid (slower: about 0.1 ms a point).

        Args:
            points_probe: (..., 3) float, metres, probe frame.

        Returns:
            (...) float64, metres, negative inside.
        """
        p = _as_points(points_probe)
        return self._distance.signed(p.reshape(-1, 3)).reshape(p.shape[:-1])

    # ---------------------------------------------------------------- torch

    def _torch_grid(self, device: torch.device, dtype: torch.dtype) -> tuple[torch.Tensor, ...]:
        key = (str(device), dtype)
        if key not in self._torch_cache:
            # copies: the numpy arrays are read-only, which torch cannot share
            self._torch_cache[key] = (
                torch.tensor(self.sdf_grid.reshape(-1).copy(), dtype=dtype, device=device),
                torch.tensor(self.sdf_origin.copy(), dtype=dtype, device=device),
                torch.tensor(self._sdf_upper.copy(), dtype=dtype, device=device),
                torch.tensor(self.sdf_grid.shape, dtype=torch.int64, device=device),
            )
        return self._torch_cache[key]

    def signed_distance_torch(self, points_probe: torch.Tensor) -> torch.Tensor:
        """:meth:`signed_distance` in torch, differentiable with respect to the points.

        Runs on the points' device and in their dtype (float32 or float64);
        the grid is copied there once and cached.

        Args:
            points_probe: (..., 3) float32 or float64 tensor, metres, probe frame.

        Returns:
            (...) tensor of the same dtype and device, metres, negative inside.
        """
        assert points_probe.dtype in (torch.float32, torch.float64) and points_probe.shape[-1] == 3, points_probe.shape
        values, lo, hi, shape = self._torch_grid(points_probe.device, points_probe.dtype)
        clamped = torch.maximum(torch.minimum(points_probe, hi), lo)
        u = (clamped - lo) / self.sdf_spacing
        i0 = torch.minimum(torch.floor(u.detach()).to(torch.int64).clamp_min(0), shape - 2)
        f = u - i0.to(u.dtype)
        stride_y, stride_x = shape[2], shape[1] * shape[2]
        base = i0[..., 0] * stride_x + i0[..., 1] * stride_y + i0[..., 2]
        fx, fy, fz = f[..., 0], f[..., 1], f[..., 2]

        def at(dx: int, dy: int, dz: int) -> torch.Tensor:
            return values[base + dx * stride_x + dy * stride_y + dz]

        c00 = at(0, 0, 0) * (1 - fx) + at(1, 0, 0) * fx
        c10 = at(0, 1, 0) * (1 - fx) + at(1, 1, 0) * fx
        c01 = at(0, 0, 1) * (1 - fx) + at(1, 0, 1) * fx
        c11 = at(0, 1, 1) * (1 - fx) + at(1, 1, 1) * fx
        c0 = c00 * (1 - fy) + c10 * fy
        c1 = c01 * (1 - fy) + c11 * fy
        value = c0 * (1 - fz) + c1 * fz
        sq_out = ((points_probe - clamped) ** 2).sum(dim=-1)
        # sqrt has an infinite derivative at 0: only take it where the point is outside the box
        positive = sq_out > 0
        dist_out = torch.where(positive, torch.sqrt(torch.where(positive, sq_out, torch.ones_like(sq_out))),
                               torch.zeros_like(sq_out))
        return value + dist_out


# --------------------------------------------------------------------------- build


def _sdf_axes(spec: ProbeSpec, bounds: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Grid node coordinates: bounding box + margin, a node at the origin, symmetric in x and y."""
    h, m = spec.sdf_spacing, spec.sdf_margin
    nx = int(np.ceil((np.abs(bounds[:, 0]).max() + m) / h))
    ny = int(np.ceil((np.abs(bounds[:, 1]).max() + m) / h))
    k_lo = int(np.ceil((m - bounds[0, 2]) / h))
    k_hi = int(np.ceil((bounds[1, 2] + m) / h))
    return h * np.arange(-nx, nx + 1), h * np.arange(-ny, ny + 1), h * np.arange(-k_lo, k_hi + 1)


@functools.lru_cache(maxsize=8)
def _build_probe_cached(spec: ProbeSpec) -> Probe:
    rings, n_lens = build_rings(spec)
    n_rings, m, _ = rings.shape
    vertices = np.concatenate([[[0.0, 0.0, 0.0]], rings.reshape(-1, 3), [[0.0, 0.0, spec.length]]])
    faces, rows, cols = ring_faces(n_rings, m)
    # the apex fan and the bands between lens rings: faces come bottom-up, band by band
    lens = np.zeros(len(faces), dtype=bool)
    lens[: m + 2 * m * (n_lens - 1)] = True
    lens_top = float(lens_sag(spec.head_width / 2 - spec.lens_edge_radius, spec.lens_radius))
    handle_end = spec.length - spec.strain_relief_length
    neck_top = spec.head_height + spec.neck_length
    region_z = RegionZ(
        lens=(0.0, lens_top),
        head=(0.0, spec.head_height),
        neck=(spec.head_height, neck_top),
        handle=(neck_top, handle_end),
        strain_relief=(handle_end, spec.length),
    )
    # the sweep is exactly mirror-symmetric, so its grid is computed on one quadrant of nodes and mirrored
    distance = MeshDistance(vertices, faces, rows, cols)
    axes = _sdf_axes(spec, np.stack([vertices.min(axis=0), vertices.max(axis=0)]))
    grid = distance.signed_grid(*axes)
    marker = np.zeros(len(faces), dtype=bool)
    if spec.marker_height > 0:
        marked = add_marker(spec, vertices, faces, rows, cols, lens, n_rings)
        vertices, faces, lens, marker = marked.vertices, marked.faces, marked.lens, marked.marker
        distance = MeshDistance(vertices, faces, marked.rows, marked.cols)
        grid = _patch_grid(grid, axes, distance, marked.changed_lo, marked.changed_hi)
    mesh = trimesh.Trimesh(vertices=vertices, faces=faces, process=False)
    return Probe(spec, mesh, lens, marker, region_z, distance, axes, grid)


def build_probe(spec: ProbeSpec = ProbeSpec()) -> Probe:
    """Build (or fetch from the cache) the probe for a spec.

    Takes about 3 s on a laptop core, most of it the exact signed-distance
    grid; later calls with an equal spec return the same object.

    Args:
        spec: dimensions and tessellation; the default is the C1-5-D estimate.

    Returns:
        :class:`Probe`, shared between callers: do not modify it.

    Raises:
        ValueError: the spec gives a self-folding surface or a marker off the head.
    """
    return _build_probe_cached(spec)


# --------------------------------------------------------------------------- mesh probes


_MESH_PROBES: dict[tuple[str, ProbeMeshSpec], Probe] = {}


def probe_from_geometry(vertices: np.ndarray, faces: np.ndarray, spec: ProbeMeshSpec) -> Probe:
    """The probe of a closed, outward-wound mesh already in the probe frame (cached by geometry and spec).

    Everything is derived from the mesh (:mod:`hupbench.datagen.assets.probe_mesh`): corners, regions, lens,
    marker patch and the signed-distance grid (about 2 s for a few thousand triangles).

    Args:
        vertices: (V, 3) float64, metres, probe frame. faces: (F, 3) int64.
        spec: the file it came from and the grid.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    key = (probe_geometry_sha256(vertices, faces), spec)
    if key not in _MESH_PROBES:
        mesh = trimesh.Trimesh(vertices, faces, process=False)
        region_z, lens = regions(mesh)
        distance = TriangleDistance(vertices, faces)
        axes = _sdf_axes(spec, np.asarray(mesh.bounds))
        grid = signed_grid(distance, axes, spec.sdf_spacing)
        _MESH_PROBES[key] = Probe(spec, mesh, lens, np.zeros(len(faces), dtype=bool), region_z, distance, axes, grid,
                                  marker_patch=marker_patch(mesh))
    return _MESH_PROBES[key]


def build_mesh_probe(spec: ProbeMeshSpec) -> Probe:
    """Read a probe mesh file (:func:`hupbench.datagen.assets.probe_mesh.load_probe_mesh`) and build its probe.

    Raises:
        BadValueError: the file cannot be used (one line naming why).
    """
    vertices, faces = read_cached(spec)
    return probe_from_geometry(vertices, faces, spec)


def probe_of(source: ProbeSource) -> Probe:
    """The probe a ``probe`` config node names: the procedural one, or its mesh."""
    spec = source.spec
    return build_probe() if spec is None else build_mesh_probe(spec)
