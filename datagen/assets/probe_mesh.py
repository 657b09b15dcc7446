"""Your own probe: a triangle mesh (STL, OBJ, PLY) read, checked, repaired and turned into a :class:`Probe`.

A mesh probe carries everything the pipeline takes from the procedural one, derived from the mesh:

- box corners (keypoints 21-28): the axis-aligned box of the vertices in the probe frame;
- z-offset (the grasp generator's Delta z): the height of the volume centroid above the origin;
- signed distance: a grid like the procedural probe's (``sdf_spacing``, ``sdf_margin``), exact at the
  nodes within ``SDF_EXACT_BAND`` grid steps of the surface, elsewhere the distance to a dense sample of
  the surface (at most half a grid step too far), signed by flood fill from the exact band;
- regions (:class:`RegionZ`): fractions of the length L along +z, those of the procedural probe
  (:data:`REGION_FRACTIONS`); the lens faces are the faces of the bottom ``LENS_DEPTH_FRACTION`` L whose
  outward normal points down (within 60 degrees of -z): the transducer face;
- marker: a round patch (radius ``MARKER_RADIUS_M``) laid on the surface, ``MARKER_LIFT_M`` above it, where
  a ray along -x at height ``MARKER_Z_FRACTION`` L in the plane y = 0 first meets the mesh: the +x end of
  the head, where the procedural probe has its pad. It is drawn in the marker's green and labelled probe
  in the segmentation; it is not part of the signed distance. A mesh with no surface there gets no marker.

Convention:
    The probe frame of :mod:`hupbench.datagen.assets.probe`: metres; origin at the centre of the transducer face
    (the lowest point on the long axis); +z along the long axis from the face towards the cable end;
    +x along the transducer face (its longer side); +y across it; right-handed. A mesh is taken in its
    own coordinates, which must be that frame (checked: the longest side of its box along z, the lowest
    z at 0, x at least as wide as y), unless ``align`` turns it by its principal axes
    (:func:`align_principal_axes`). Units: ``unit`` says what one file unit is (m, cm or mm).
"""

from __future__ import annotations

import functools
import hashlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh
from scipy import ndimage
from scipy.spatial import cKDTree

from hupbench.datagen.assets.probe_shape import RegionZ
from hupbench.core.errors import BadValueError, MissingFileError
from hupbench.core.keypoints import CORNER_BITS
from hupbench.core.io import file_sha256
from hupbench.datagen.mesh_distance import (
    FEATURE_EAB,
    FEATURE_EBC,
    FEATURE_ECA,
    FEATURE_VA,
    FEATURE_VB,
    FEATURE_VC,
    _pack_triangles,
    _pseudo_normals,
    _sq_dist_packed,
    closest_points_on_triangles,
)

__all__ = [
    "MESH_SUFFIXES",
    "MESH_UNITS",
    "ProbeMeshSpec",
    "ProbeSource",
    "align_principal_axes",
    "box_corners",
    "linear_probe_mesh",
    "load_probe_mesh",
    "mesh_probe_record",
    "probe_geometry_sha256",
]

MESH_SUFFIXES = (".stl", ".obj", ".ply")
#: metres per file unit
MESH_UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}
#: a probe longer than this (metres) is a mesh in another unit: a hand-held tool is 0.05 to 0.5 m long
MAX_LENGTH_M = 1.0
MIN_LENGTH_M = 0.02
#: (start, end) of each region as fractions of the length: the procedural probe's (48, 66, 148 of 165 mm)
REGION_FRACTIONS = {"head": (0.0, 0.29), "neck": (0.29, 0.40), "handle": (0.40, 0.90), "strain_relief": (0.90, 1.0)}
LENS_DEPTH_FRACTION = 0.15
#: a lens face's outward normal has z below this (within 60 degrees of -z)
LENS_NORMAL_Z = -0.5
MARKER_Z_FRACTION = 0.2
MARKER_RADIUS_M = 0.006
MARKER_LIFT_M = 0.0005
#: nodes within this many grid steps of the surface get exact distances
SDF_EXACT_BAND = 3.0
#: the most triangles a probe mesh may have. Deriving its signed distance takes time in proportion to them
#: (on two busy cores about 4 min for 20,000 and 10 min for 50,000), and finer ones do not reach the
#: grasps: on the procedural probe's surface (0.021 m^2, 13,012 triangles) 20,000 triangles are 1 mm^2
#: each, under half a face of the signed-distance grid's 1.5 mm cells (:attr:`ProbeMeshSpec.sdf_spacing`)
MAX_FACES = 20_000
#: the lowest z (metres) of a mesh taken as it is may miss 0 by this much
ORIGIN_TOLERANCE_M = 1e-4


@dataclass(frozen=True)
class ProbeSource:
    """The ``probe`` config node: which probe the grasps and the dataset use.

    Attributes:
        mesh: an .stl, .obj or .ply file; None for the procedural GE Voluson C1-5-D.
        mesh_unit: what one unit of the file is: "m", "cm" or "mm".
        align: turn the mesh into the probe frame by its principal axes (:func:`align_principal_axes`);
            False takes its coordinates as the probe frame (checked).
    """

    mesh: str | None = None
    mesh_unit: str = "m"
    align: bool = False

    def __post_init__(self) -> None:
        if self.mesh_unit not in MESH_UNITS:
            raise BadValueError(f"probe.mesh_unit must be one of {', '.join(MESH_UNITS)}, got {self.mesh_unit!r}")
        if not isinstance(self.align, bool):
            raise BadValueError(f"probe.align must be true or false, got {self.align!r}")
        if self.mesh is not None:
            check_mesh_path(self.mesh)

    @property
    def spec(self) -> ProbeMeshSpec | None:
        """The mesh probe's spec, None for the procedural probe."""
        if self.mesh is None:
            return None
        return ProbeMeshSpec(str(Path(self.mesh).resolve()), self.mesh_unit, self.align, file_sha256(self.mesh))


def check_mesh_path(path) -> Path:
    """``path`` when it names an existing .stl, .obj or .ply file; else one line saying what is wrong."""
    if not isinstance(path, (str, Path)) or not str(path):
        raise BadValueError(f"probe.mesh must be the path of an .stl, .obj or .ply file, got {path!r}")
    path = Path(path)
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise BadValueError(f"probe.mesh {path} must be an .stl, .obj or .ply file, got a {path.suffix or 'suffix-less'} "
                            "file")
    if not path.is_file():
        raise MissingFileError(f"probe.mesh {path} not found")
    return path


@dataclass(frozen=True)
class ProbeMeshSpec:
    """A mesh probe: the file, how it is read and the signed-distance grid (metres).

    Attributes:
        path: the mesh file (absolute). unit: metres per file unit, by name (:data:`MESH_UNITS`).
        align: turned by its principal axes. sha256: of the file's bytes.
        sdf_spacing, sdf_margin: the grid, as in :class:`hupbench.datagen.assets.probe_shape.ProbeSpec`.
    """

    path: str
    unit: str = "m"
    align: bool = False
    sha256: str = ""
    sdf_spacing: float = 0.0015
    sdf_margin: float = 0.03

    def record(self) -> dict:
        """What a grasps file and a dataset's manifest record of the probe."""
        return {"kind": "mesh", "path": self.path, "sha256": self.sha256, "unit": self.unit, "align": self.align}


# --------------------------------------------------------------------------- reading and checking


def _read(path: Path) -> trimesh.Trimesh:
    try:
        loaded = trimesh.load(str(path), force="mesh", process=False)
    except (ValueError, KeyError, IndexError, TypeError, AttributeError, UnicodeDecodeError, OSError,
            NotImplementedError) as exc:
        raise BadValueError(f"probe.mesh {path} cannot be read as {path.suffix[1:].upper()} ({type(exc).__name__}: "
                            f"{exc})") from None
    faces = getattr(loaded, "faces", None)
    if not isinstance(loaded, trimesh.Trimesh) or faces is None or len(faces) == 0:
        raise BadValueError(f"probe.mesh {path} holds no triangles (an empty or unreadable "
                            f"{path.suffix[1:].upper()} file)")
    if not np.isfinite(loaded.vertices).all():
        raise BadValueError(f"probe.mesh {path} has vertices that are NaN or infinite")
    if len(faces) > MAX_FACES:
        simplified = path.with_name(f"{path.stem}_{MAX_FACES // 1000}k{path.suffix}")
        raise BadValueError(f"probe.mesh {path} has {len(faces):,} triangles, more than the {MAX_FACES:,} a probe may "
                            "have (its signed distance takes minutes per 10,000 triangles): simplify it first, e.g. "
                            f"python -c \"import trimesh; trimesh.load('{path}').simplify_quadric_decimation("
                            f"face_count={MAX_FACES}).export('{simplified}')\"")
    return loaded


def _repair(mesh: trimesh.Trimesh, path: Path) -> trimesh.Trimesh:
    """Merge vertices, drop degenerate and repeated faces, fill holes, wind outwards; or refuse."""
    mesh = trimesh.Trimesh(mesh.vertices, mesh.faces, process=True)  # merges duplicate vertices
    mesh.update_faces(mesh.nondegenerate_faces())
    mesh.update_faces(mesh.unique_faces())
    mesh.remove_unreferenced_vertices()
    if len(mesh.faces) == 0:
        raise BadValueError(f"probe.mesh {path} has only degenerate triangles (no area)")
    edges = np.sort(mesh.edges, axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    shared = int((counts > 2).sum())
    if shared:
        raise BadValueError(f"probe.mesh {path} is non-manifold: {shared} edge(s) are shared by more than two "
                            "triangles; export it as one closed surface")
    if not mesh.is_watertight:
        trimesh.repair.fill_holes(mesh)
    if not mesh.is_watertight:
        open_edges = int((counts == 1).sum())
        raise BadValueError(f"probe.mesh {path} is not closed: {open_edges} open edge(s) that trimesh could not fill; "
                            "close the surface (a probe must have an inside)")
    trimesh.repair.fix_winding(mesh)
    if not mesh.is_winding_consistent:
        raise BadValueError(f"probe.mesh {path} cannot be wound consistently (a one-sided surface such as a "
                            "Moebius strip)")
    if mesh.volume < 0:
        mesh.invert()
    if not mesh.volume > 0:
        raise BadValueError(f"probe.mesh {path} encloses no volume")
    return mesh


def align_principal_axes(mesh: trimesh.Trimesh) -> tuple[trimesh.Trimesh, np.ndarray]:
    """Turn a closed mesh into the probe frame by its principal axes.

    The axes are those of the surface's area-weighted covariance: the longest becomes +z, the second +x,
    the shortest +y. +z points away from the wider end (the wider of the two end slabs, each
    ``LENS_DEPTH_FRACTION`` of the length, along x: the transducer head is at the bottom); +x is then
    chosen so that the frame is right-handed with +y = z x x, +x towards the side with more volume above
    the head's middle (a tie keeps the covariance's sign). The origin is put at the lowest z on the long
    axis's centre line: the centre of the box's bottom in x and y, z = min.

    Args:
        mesh: closed, outward-wound, metres, any frame.

    Returns:
        (the turned copy, (4, 4) float64 ``T_probe_file``: file coordinates, in metres, -> probe frame).
    """
    tri = mesh.triangles
    area = mesh.area_faces
    centre = (tri.mean(axis=1) * area[:, None]).sum(axis=0) / area.sum()
    d = tri - centre  # (F, 3, 3)
    # the covariance of a triangle's uniform area: (sum_i d_i d_i^T + (sum d)(sum d)^T) / 12
    cov = (np.einsum("fki,fkj->fij", d, d) + np.einsum("fi,fj->fij", d.sum(1), d.sum(1))) / 12.0
    cov = (cov * area[:, None, None]).sum(axis=0) / area.sum()
    _, vectors = np.linalg.eigh(cov)  # ascending eigenvalues
    y_axis, x_axis, z_axis = vectors[:, 0], vectors[:, 1], vectors[:, 2]
    z = (mesh.vertices - centre) @ z_axis
    x = (mesh.vertices - centre) @ x_axis
    span = z.max() - z.min()
    low, high = z <= z.min() + LENS_DEPTH_FRACTION * span, z >= z.max() - LENS_DEPTH_FRACTION * span
    if np.ptp(x[high]) > np.ptp(x[low]):
        z_axis, x_axis = -z_axis, -x_axis  # the wider end is the head: it goes to the bottom
    y_axis = np.cross(z_axis, x_axis)
    R = np.stack([x_axis, y_axis, z_axis])  # rows: probe axes in file coordinates
    turned = (mesh.vertices - centre) @ R.T
    lo, hi = turned.min(axis=0), turned.max(axis=0)
    origin = np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2]])
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = -R @ centre - origin
    out = mesh.copy()
    out.apply_transform(T)
    return out, T


def load_probe_mesh(spec: ProbeMeshSpec) -> trimesh.Trimesh:
    """Read, scale, repair, check (and with ``spec.align`` turn) a probe mesh.

    Returns:
        Closed, outward-wound ``trimesh.Trimesh`` in the probe frame, metres.

    Raises:
        BadValueError: one line naming what is wrong: unreadable, empty, non-manifold, open beyond repair,
            the wrong size for its unit, or (without align) not in the probe frame.
    """
    path = Path(spec.path)
    mesh = _read(path)
    mesh.apply_scale(MESH_UNITS[spec.unit])
    length = float(mesh.extents.max())
    if length > MAX_LENGTH_M:
        raise BadValueError(f"probe.mesh {path} is {length:g} m long in {spec.unit} (its longest side): a hand-held "
                            f"probe is under {MAX_LENGTH_M:g} m; if the file is in millimetres pass "
                            "probe.mesh_unit=mm, or scale it to metres")
    if length < MIN_LENGTH_M:
        raise BadValueError(f"probe.mesh {path} is {length:g} m long in {spec.unit} (its longest side): too small for "
                            f"a hand to hold (under {MIN_LENGTH_M:g} m); check probe.mesh_unit")
    mesh = _repair(mesh, path)
    if spec.align:
        mesh, _ = align_principal_axes(mesh)
    else:
        check_probe_frame(mesh, path)
    return mesh


def check_probe_frame(mesh: trimesh.Trimesh, path) -> None:
    """A mesh taken as it is lies in the probe frame: longest along z, bottom at z = 0, x >= y."""
    ext = mesh.extents
    hint = "; turn it or pass probe.align=true"
    if np.argmax(ext) != 2:
        raise BadValueError(f"probe.mesh {path}: +z must run along the handle, the longest side, but the mesh's box "
                            f"is {ext[0]:.3f} x {ext[1]:.3f} x {ext[2]:.3f} m (x y z){hint}")
    if ext[0] < ext[1] * (1 - 1e-6):
        raise BadValueError(f"probe.mesh {path}: +x must run along the transducer face, the wider side across the "
                            f"handle, but the box is {ext[0]:.3f} m along x and {ext[1]:.3f} m along y{hint}")
    z_min = float(mesh.bounds[0, 2])
    if abs(z_min) > ORIGIN_TOLERANCE_M:
        raise BadValueError(f"probe.mesh {path}: the origin must be on the transducer face (the lowest z = 0), but "
                            f"the lowest z is {z_min:.4f} m{hint}")


def linear_probe_mesh(head=(0.056, 0.016, 0.045), handle=(0.032, 0.026, 0.100), taper_m: float = 0.010
                      ) -> trimesh.Trimesh:
    """An example tool: a linear-array probe, a flat head under a box handle, in the probe frame.

    Sized like a real linear probe (a 56 mm wide, 16 mm thick head, 45 mm tall; a 32 x 26 mm handle,
    100 mm long, joined by a ``taper_m`` taper; 155 mm in all). Used by the tests and
    ``scripts/custom_probe_picture.py`` as a tool unlike the procedural probe.

    Args:
        head, handle: (x, y, z) full extents, metres.

    Returns:
        Closed, outward-wound ``trimesh.Trimesh``, metres, probe frame (the face's centre at the origin).
    """
    def ring(x: float, y: float, z: float) -> np.ndarray:
        return np.array([[x / 2, -y / 2, z], [x / 2, y / 2, z], [-x / 2, y / 2, z], [-x / 2, -y / 2, z]])

    top = head[2] + taper_m + handle[2]
    rings = np.stack([ring(head[0], head[1], 0.0), ring(head[0], head[1], head[2]),
                      ring(handle[0], handle[1], head[2] + taper_m), ring(handle[0], handle[1], top)])
    vertices = np.concatenate([[[0.0, 0.0, 0.0]], rings.reshape(-1, 3), [[0.0, 0.0, top]]])
    last = len(vertices) - 1
    faces = [[0, 1 + (k + 1) % 4, 1 + k] for k in range(4)]
    for r in range(3):
        a, b = 1 + 4 * r, 1 + 4 * (r + 1)
        for k in range(4):
            j = (k + 1) % 4
            faces += [[a + k, a + j, b + j], [a + k, b + j, b + k]]
    faces += [[last, 13 + k, 13 + (k + 1) % 4] for k in range(4)]
    return trimesh.Trimesh(vertices, np.array(faces), process=False)


# --------------------------------------------------------------------------- derived geometry


def probe_geometry_sha256(vertices: np.ndarray, faces: np.ndarray) -> str:
    """sha256 of a probe's geometry as used (float64 vertices, int64 faces)."""
    h = hashlib.sha256(np.ascontiguousarray(vertices, dtype=np.float64).tobytes())
    h.update(np.ascontiguousarray(faces, dtype=np.int64).tobytes())
    return h.hexdigest()


def mesh_probe_record(spec: ProbeMeshSpec, vertices: np.ndarray, faces: np.ndarray) -> dict:
    """What a grasps file and a dataset's manifest record of a mesh probe
    (:attr:`hupbench.datagen.assets.probe.Probe.record`): its file's record and the sha256 of its geometry as used."""
    return {**spec.record(), "geometry_sha256": probe_geometry_sha256(vertices, faces)}


def box_corners(bounds: np.ndarray) -> np.ndarray:
    """(8, 3) float64: the corners of the axis-aligned box ``bounds`` ((2, 3): min, max), in the order of the
    probe's corner keypoints (:data:`hupbench.core.keypoints.CORNER_BITS`)."""
    bounds = np.asarray(bounds, dtype=np.float64)
    return np.array([[bounds[b, axis] for axis, b in enumerate(bits)] for bits in CORNER_BITS])


def regions(mesh: trimesh.Trimesh) -> tuple[RegionZ, np.ndarray]:
    """The regions (:data:`REGION_FRACTIONS`) and the (F,) bool lens faces of a mesh in the probe frame."""
    length = float(mesh.bounds[1, 2])
    centre_z = mesh.triangles_center[:, 2]
    lens = (mesh.face_normals[:, 2] < LENS_NORMAL_Z) & (centre_z <= LENS_DEPTH_FRACTION * length)
    lens_top = float(mesh.triangles[lens][..., 2].max()) if lens.any() else 0.0
    spans = {name: (a * length, b * length) for name, (a, b) in REGION_FRACTIONS.items()}
    return RegionZ(lens=(0.0, lens_top), **spans), lens


def marker_patch(mesh: trimesh.Trimesh) -> trimesh.Trimesh | None:
    """The orientation marker of a mesh probe: a disc laid on the surface (module docstring), or None.

    Returns:
        ``trimesh.Trimesh`` in the probe frame, metres, outward-facing, or None when no surface lies
        on the +x side at the marker's height.
    """
    from trimesh.ray.ray_triangle import RayMeshIntersector

    rays = RayMeshIntersector(mesh)
    length = float(mesh.bounds[1, 2])
    start = np.array([[mesh.bounds[1, 0] + 0.05, 0.0, MARKER_Z_FRACTION * length]])
    hit, _, tri = rays.intersects_location(start, np.array([[-1.0, 0.0, 0.0]]))
    if not len(hit):
        return None
    first = int(np.argmax(hit[:, 0]))
    centre, normal = hit[first], mesh.face_normals[tri[first]]
    t1 = np.cross(normal, [0.0, 0.0, 1.0])
    t1 = t1 / np.linalg.norm(t1) if np.linalg.norm(t1) > 1e-6 else np.array([0.0, 1.0, 0.0])
    t2 = np.cross(normal, t1)
    n_rings, n_around = 4, 24
    radii = MARKER_RADIUS_M * np.arange(1, n_rings + 1) / n_rings
    phi = 2 * np.pi * np.arange(n_around) / n_around
    disc = np.concatenate([[[0.0, 0.0]], (radii[:, None, None] * np.stack([np.cos(phi), np.sin(phi)], -1)).reshape(-1, 2)])
    origins = centre + disc[:, :1] * t1 + disc[:, 1:] * t2 + 0.02 * normal
    locations, index_ray, _ = rays.intersects_location(origins, np.repeat(-normal[None], len(origins), 0))
    points = np.full((len(origins), 3), np.nan)
    for k in range(len(origins)):
        mine = locations[index_ray == k]
        if len(mine):
            points[k] = mine[np.argmax(mine @ normal)]  # the first surface the ray meets
    # triangles: the centre fan, then the bands between rings (counter-clockwise seen from outside)
    faces = [[0, 1 + j, 1 + (j + 1) % n_around] for j in range(n_around)]
    for r in range(n_rings - 1):
        a, b = 1 + r * n_around, 1 + (r + 1) * n_around
        for j in range(n_around):
            k = (j + 1) % n_around
            faces += [[a + j, b + j, b + k], [a + j, b + k, a + k]]
    faces = np.array(faces)
    faces = faces[np.isfinite(points[faces]).all(axis=(1, 2))]
    if not len(faces):
        return None
    patch = trimesh.Trimesh(points + MARKER_LIFT_M * normal, faces, process=False)
    if (patch.face_normals @ normal).mean() < 0:
        patch.invert()
    return patch


class TriangleDistance:
    """Exact signed distance (negative inside) to a closed, outward-wound triangle mesh of any layout.

    Each point's search is bounded by its distance to the nearest face centre; the faces whose bounding
    sphere lies within that bound are checked exactly and the sign comes from the angle-weighted
    pseudo-normal of the closest feature (as :class:`hupbench.datagen.mesh_distance.MeshDistance`).

    Args:
        vertices: (V, 3) float64, metres. faces: (F, 3) int64.
    """

    def __init__(self, vertices: np.ndarray, faces: np.ndarray) -> None:
        self.faces = faces
        self.tri = vertices[faces]
        self.packed = _pack_triangles(self.tri)
        self.pseudo = _pseudo_normals(vertices, faces)
        self.centre = self.tri.mean(axis=1)
        self.radius = np.linalg.norm(self.tri - self.centre[:, None], axis=-1).max(axis=1)
        self.tree = cKDTree(self.centre)

    def _closest(self, points: np.ndarray, bound: np.ndarray):
        """Per point: the squared distance, face, barycentric weights and feature of the closest point."""
        r_max = float(self.radius.max())
        lists = self.tree.query_ball_point(points, bound + r_max + 1e-12)
        owner = np.repeat(np.arange(len(points)), [len(v) for v in lists])
        face = np.concatenate([np.asarray(v, dtype=np.int64) for v in lists]) if len(owner) else np.zeros(0, np.int64)
        sq = _sq_dist_packed(points[owner], self.packed[face])
        order = np.lexsort((sq, owner))
        first = order[np.r_[True, owner[order][1:] != owner[order][:-1]]]
        assert len(first) == len(points), "every point has a face within its bound"
        best = face[first]
        t = self.tri[best]
        sq_best, bary, feature = closest_points_on_triangles(points, t[:, 0], t[:, 1], t[:, 2])
        return sq_best, best, bary, feature

    def _sign(self, points, best, bary, feature) -> np.ndarray:
        closest = np.einsum("nk,nki->ni", bary, self.tri[best])
        normal = self.pseudo.face[best].copy()
        for code, corner in ((FEATURE_VA, 0), (FEATURE_VB, 1), (FEATURE_VC, 2)):
            sel = feature == code
            normal[sel] = self.pseudo.vertex[self.faces[best[sel], corner]]
        for code, edge in ((FEATURE_EAB, 0), (FEATURE_EBC, 1), (FEATURE_ECA, 2)):
            sel = feature == code
            normal[sel] = self.pseudo.edge[best[sel], edge]
        return np.where(np.einsum("ni,ni->n", points - closest, normal) < 0, -1.0, 1.0)

    def signed(self, points: np.ndarray, bound: np.ndarray | None = None, chunk: int = 2048) -> np.ndarray:
        """(N,) float64 exact signed distance of points (N, 3), metres; ``bound`` (N,) an upper bound of
        each point's distance (default: the distance to the nearest face centre)."""
        points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        if bound is None:
            bound = self.tree.query(points)[0]
        out = np.empty(len(points))
        for s in range(0, len(points), chunk):
            p = points[s : s + chunk]
            sq, best, bary, feature = self._closest(p, bound[s : s + chunk])
            out[s : s + chunk] = self._sign(p, best, bary, feature) * np.sqrt(sq)
        return out


def _surface_samples(tri: np.ndarray, step: float) -> np.ndarray:
    """(S, 3) points on every triangle, no surface point farther than ``step`` from one of them."""
    out = []
    longest = np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=-1).max(axis=1)
    n_of = np.maximum(1, np.ceil(longest / step).astype(np.int64))
    for n in np.unique(n_of):
        i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
        keep = i + j <= n
        w = np.stack([n - i[keep] - j[keep], i[keep], j[keep]], axis=1) / n  # (K, 3) barycentric
        out.append(np.einsum("kc,fci->fki", w, tri[n_of == n]).reshape(-1, 3))
    return np.concatenate(out)


def signed_grid(distance: TriangleDistance, axes: tuple[np.ndarray, np.ndarray, np.ndarray], spacing: float
                ) -> np.ndarray:
    """Signed distances at the grid nodes: exact within ``SDF_EXACT_BAND`` steps of the surface (module docstring).

    Returns:
        (nx, ny, nz) float64, metres, negative inside.
    """
    xs, ys, zs = axes
    nodes = np.stack(np.meshgrid(xs, ys, zs, indexing="ij"), axis=-1).reshape(-1, 3)
    step = spacing / 2
    samples = _surface_samples(distance.tri, step)
    upper = cKDTree(samples).query(nodes)[0]  # distance to the nearest sample: within `step` of the true one
    band = upper <= SDF_EXACT_BAND * spacing
    grid = np.empty(len(nodes))
    grid[band] = distance.signed(nodes[band], upper[band])
    # outside the band |d| > (band - 1/2) steps: a node and its neighbour lie on one side, so the sign
    # of each connected far region is that of the band nodes next to it
    shape = (len(xs), len(ys), len(zs))
    far = ~band.reshape(shape)
    labels, n_labels = ndimage.label(far)
    sign_of = np.ones(n_labels + 1)
    band_sign = np.sign(np.where(band, grid, 0.0)).reshape(shape)
    for axis in range(3):
        for a, b in ((slice(None, -1), slice(1, None)), (slice(1, None), slice(None, -1))):
            sa = [slice(None)] * 3
            sb = [slice(None)] * 3
            sa[axis], sb[axis] = a, b
            pair = far[tuple(sa)] & ~far[tuple(sb)]
            sign_of[labels[tuple(sa)][pair]] = band_sign[tuple(sb)][pair]
    far_flat = far.reshape(-1)
    grid[far_flat] = sign_of[labels.reshape(-1)[far_flat]] * (upper[far_flat] - step / 2)
    return grid.reshape(shape)


@functools.lru_cache(maxsize=4)
def read_cached(spec: ProbeMeshSpec) -> tuple[np.ndarray, np.ndarray]:
    """(vertices (V, 3) float64 metres probe frame, faces (F, 3) int64) of a mesh probe's file (cached)."""
    mesh = load_probe_mesh(spec)
    vertices, faces = np.array(mesh.vertices, dtype=np.float64), np.array(mesh.faces, dtype=np.int64)
    vertices.flags.writeable = faces.flags.writeable = False
    return vertices, faces


#: a grasps file made for a probe mesh (``hupbench grasps probe.mesh=PATH``) carries that probe: its
#: geometry as used (probe frame, metres) and a JSON record of where it came from
#: (:attr:`hupbench.datagen.assets.probe.Probe.record`); without them the grasps are the procedural probe's
PROBE_MESH_FIELDS = ("probe_mesh_vertices", "probe_mesh_faces", "probe_mesh_record")


def probe_arrays(probe) -> dict[str, np.ndarray]:
    """The arrays a grasps file carries for its probe (a :class:`hupbench.datagen.assets.probe.Probe`, or what has
    its ``spec``, ``mesh`` and ``record``): none for the procedural probe, else :data:`PROBE_MESH_FIELDS`
    ((V, 3) float64 metres probe frame, (F, 3) int64, a JSON string)."""
    import json

    if not isinstance(probe.spec, ProbeMeshSpec):
        return {}
    return {"probe_mesh_vertices": np.array(probe.mesh.vertices, dtype=np.float64),
            "probe_mesh_faces": np.array(probe.mesh.faces, dtype=np.int64),
            "probe_mesh_record": np.array(json.dumps(probe.record, sort_keys=True))}
