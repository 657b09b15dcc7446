"""The probe's orientation marker, moulded into the swept mesh of :mod:`hupbench.datagen.assets.probe_shape`.

An orientation marker (a raised green pad on the +x end of the head, see
:class:`hupbench.datagen.assets.probe_shape.ProbeSpec`) is moulded into the sweep by refining the quads under it
and pushing them out, so the mesh stays one closed surface. Without it the
probe would be exactly mirror-symmetric about x = 0 and y = 0, hence
unchanged by a half turn about its long axis; with it only the mirror
y -> -y remains, which no rigid motion can produce.

Convention:
    Metres, probe frame (see :mod:`hupbench.datagen.assets.probe_shape`).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import trimesh

from hupbench.datagen.assets.probe_shape import ProbeSpec, smoothstep
from hupbench.core.errors import BadValueError


# --------------------------------------------------------------------------- orientation marker


class MarkedMesh(NamedTuple):
    """The swept mesh with the orientation marker moulded into it."""

    vertices: np.ndarray  # (V, 3) float64, probe frame, metres
    faces: np.ndarray  # (F, 3) int64, outward-wound
    rows: np.ndarray  # (F,) int64 band of each face in the sweep layout (see ring_faces)
    cols: np.ndarray  # (F,) int64 ring segment of each face
    lens: np.ndarray  # (F,) bool, faces of the acoustic lens
    marker: np.ndarray  # (F,) bool, faces of the marker's footprint (drawn in the marker colour)
    changed_lo: np.ndarray  # (3,) lower corner of a box holding every surface point that differs from the sweep
    changed_hi: np.ndarray  # (3,) upper corner of that box


def marker_profile(t: np.ndarray, s: np.ndarray, spec: ProbeSpec, t0: float) -> tuple[np.ndarray, np.ndarray]:
    """Height of the marker above the housing and the distance from its core.

    The footprint is a stadium in the surface coordinates (t along the +x
    meridian, s around the ring), ``marker_length`` along t by
    ``marker_width`` along s, centred at (``t0``, 0): its core segment (along
    the longer of the two) thickened by half the shorter extent. The height
    is ``marker_height`` on the plateau and falls to 0 with a smoothstep over
    the last ``marker_edge`` before the footprint's outline, so the surface
    stays C1.

    Args:
        t, s: (...) float64 surface coordinates, metres.
        spec: the probe spec.
        t0: t of the marker's centre, metres.

    Returns:
        height: (...) float64 metres, 0 outside the footprint.
        core_distance: (...) float64 metres; the footprint is ``core_distance < marker_rim(spec)``.
    """
    rim = marker_rim(spec)
    dt = np.maximum(np.abs(t - t0) - (0.5 * spec.marker_length - rim), 0.0)
    ds = np.maximum(np.abs(s) - (0.5 * spec.marker_width - rim), 0.0)
    core_distance = np.hypot(dt, ds)
    height = spec.marker_height * smoothstep((rim - core_distance) / spec.marker_edge)
    return height, core_distance


def marker_rim(spec: ProbeSpec) -> float:
    """Radius of the footprint's rounded ends: half its shorter extent, metres."""
    return 0.5 * min(spec.marker_length, spec.marker_width)


def add_marker(spec: ProbeSpec, vertices: np.ndarray, faces: np.ndarray, rows: np.ndarray, cols: np.ndarray,
                lens: np.ndarray, n_rings: int) -> MarkedMesh:
    """Mould the orientation marker into the +x end of the head.

    The quads of the sweep under the marker (a block of whole ring bands and
    segments centred on the +x meridian) are replaced by a finer grid, each
    quad split into ``marker_subdivisions`` x ``marker_subdivisions`` by
    bilinear interpolation of its corners, and that grid is pushed out along
    the interpolated vertex normals by :func:`marker_profile`. The height is
    0 on the block's outline, whose edges keep their straight shape; the
    neighbouring triangles that share an outline edge are split into fans
    that take the outline's new vertices, so the surface stays one closed,
    consistently wound 2-manifold (no booleans, no T-junctions). New faces
    keep the (band, segment) layout of the quad they came from.

    Args:
        spec: the probe spec (``marker_height > 0``).
        vertices: (V, 3) float64 vertices of the sweep (:func:`_build_probe_cached` layout).
        faces, rows, cols: (F, 3), (F,), (F,) int64 from :func:`ring_faces`.
        lens: (F,) bool lens faces.
        n_rings: number of rings of the sweep.

    Returns:
        :class:`MarkedMesh`.

    Raises:
        ValueError: the spec places the marker off the head's housing, or it would stick out of the
            probe's bounding box (whose corners are keypoints).
    """
    m, n = spec.n_around, spec.marker_subdivisions
    ring = vertices[1 : 1 + n_rings * m].reshape(n_rings, m, 3)
    normals = trimesh.Trimesh(vertices, faces, process=False).vertex_normals[1 : 1 + n_rings * m].reshape(n_rings, m, 3)
    t_ring, s_ring = surface_coordinates(ring)
    k_lo, k_hi, big_j, t0 = _marker_block(spec, ring[:, 0], t_ring, s_ring)

    # the fine grid over the block: (U, V) points, U along the rings, V around them
    u_count, v_count = (k_hi - k_lo) * n + 1, 2 * big_j * n + 1
    a, b = np.meshgrid(np.arange(u_count), np.arange(v_count), indexing="ij")
    kc = np.minimum(a // n, k_hi - k_lo - 1)  # coarse cell, relative to k_lo and -big_j
    jc = np.minimum(b // n, 2 * big_j - 1)
    fa, fb = (a - kc * n) / n, (b - jc * n) / n
    k0, j0 = k_lo + kc, (jc - big_j) % m
    j1 = (j0 + 1) % m

    def bilinear(field: np.ndarray) -> np.ndarray:
        fa_, fb_ = (fa, fb) if field.ndim == 2 else (fa[..., None], fb[..., None])
        return ((1 - fa_) * (1 - fb_) * field[k0, j0] + (1 - fa_) * fb_ * field[k0, j1]
                + fa_ * (1 - fb_) * field[k0 + 1, j0] + fa_ * fb_ * field[k0 + 1, j1])

    base = bilinear(ring)
    t_fine = bilinear(np.broadcast_to(t_ring[:, None], (n_rings, m)))
    s_fine = bilinear(s_ring)
    normal = bilinear(normals)
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    height, core = marker_profile(t_fine, s_fine, spec, t0)
    outline = np.zeros(height.shape, dtype=bool)
    outline[[0, -1], :] = outline[:, [0, -1]] = True
    assert not np.any(height[outline] != 0.0), "the block under the marker contains its footprint"
    moved = base + height[..., None] * normal

    # vertex indices: fine points on coarse vertices reuse them, the others are appended
    index = np.empty((u_count, v_count), dtype=np.int64)
    on_coarse = (a % n == 0) & (b % n == 0)
    index[on_coarse] = 1 + (k_lo + a[on_coarse] // n) * m + (b[on_coarse] // n - big_j) % m
    fresh = ~on_coarse
    index[fresh] = len(vertices) + np.arange(int(fresh.sum()))
    out_vertices = np.concatenate([vertices, moved[fresh]])
    out_vertices[index[on_coarse]] = moved[on_coarse]

    patch, patch_rows, patch_cols, patch_marker = _patch_faces(index, b[:-1, :-1] >= big_j * n, k0, j0, core,
                                                               marker_rim(spec))

    block_cols = (np.arange(-big_j, big_j)) % m
    block = (rows >= k_lo + 1) & (rows <= k_hi) & np.isin(cols, block_cols)
    assert block.sum() == 2 * (k_hi - k_lo) * 2 * big_j, "the block under the marker is whole quads of the sweep"
    keep, fans, fan_rows, fan_cols, fan_lens = _stitch_outline(faces, rows, cols, lens, ~block, index, n, big_j,
                                                               k_hi - k_lo)

    out_faces = np.concatenate([faces[keep], *fans, patch]).astype(np.int64)
    out_rows = np.concatenate([rows[keep], *fan_rows, patch_rows]).astype(np.int64)
    out_cols = np.concatenate([cols[keep], *fan_cols, patch_cols]).astype(np.int64)
    out_lens = np.concatenate([lens[keep], *fan_lens, np.zeros(len(patch), dtype=bool)])
    out_marker = np.concatenate([np.zeros(int(keep.sum()) + sum(len(x) for x in fans), dtype=bool), patch_marker])

    body_lo, body_hi = vertices.min(axis=0), vertices.max(axis=0)
    if np.any(moved < body_lo) or np.any(moved > body_hi):
        raise BadValueError(
            "the orientation marker sticks out of the probe's bounding box (its corners are keypoints 21-28 and "
            f"must not move): marker spans {moved.reshape(-1, 3).min(axis=0)} .. {moved.reshape(-1, 3).max(axis=0)} m, "
            f"the box {body_lo} .. {body_hi} m; lower marker_height or move marker_z"
        )
    old = vertices[faces[block].reshape(-1)]
    changed = np.concatenate([old, moved.reshape(-1, 3)])
    return MarkedMesh(out_vertices, out_faces, out_rows, out_cols, out_lens, out_marker,
                      changed.min(axis=0), changed.max(axis=0))


def surface_coordinates(ring: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Surface coordinates of the sweep's ring vertices.

    Args:
        ring: (K, m, 3) float64 ring vertices, metres; vertex 0 of every ring lies on the +x meridian (y = 0).

    Returns:
        t: (K,) float64 arc length along the +x meridian, metres.
        s: (K, m) float64 signed arc length around each ring from vertex 0 (+y positive), metres.
    """
    n_rings, m = ring.shape[:2]
    meridian = ring[:, 0]
    t_ring = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(meridian, axis=0), axis=-1))])
    seg = np.linalg.norm(np.roll(ring, -1, axis=1) - ring, axis=-1)  # (K, m): segment j runs from j to j + 1
    around = np.concatenate([np.zeros((n_rings, 1)), np.cumsum(seg, axis=1)[:, :-1]], axis=1)
    perimeter = seg.sum(axis=1, keepdims=True)
    j = np.arange(m)
    return t_ring, np.where(j <= m // 2, around, around - perimeter)


def _marker_block(spec: ProbeSpec, meridian: np.ndarray, t_ring: np.ndarray,
                  s_ring: np.ndarray) -> tuple[int, int, int, float]:
    """The block of whole quads under the marker: rings k_lo..k_hi, segments -big_j..big_j - 1.

    Returns:
        (k_lo, k_hi, big_j, t0), t0 the arc length of the marker's centre along the +x meridian, metres.
    """
    m = spec.n_around
    first_body = spec.n_lens_rings + spec.n_fillet_rings
    head_top = int(np.searchsorted(meridian[:, 2], spec.head_height))
    above = np.flatnonzero(meridian[first_body:, 2] >= spec.marker_z)
    if not len(above) or first_body + above[0] == first_body:
        raise BadValueError(f"ProbeSpec.marker_z ({spec.marker_z}) must lie on the housing of the head, above the "
                         f"lens edge (z {meridian[first_body, 2]:.4f} m on the +x side) and below head_height")
    k = first_body + int(above[0])
    w = (spec.marker_z - meridian[k - 1, 2]) / (meridian[k, 2] - meridian[k - 1, 2])
    t0 = float(t_ring[k - 1] + w * (t_ring[k] - t_ring[k - 1]))
    k_lo = int(np.searchsorted(t_ring, t0 - 0.5 * spec.marker_length, side="right")) - 1
    k_hi = int(np.searchsorted(t_ring, t0 + 0.5 * spec.marker_length, side="left"))
    if k_lo < first_body or k_hi > head_top:
        raise BadValueError(
            f"the orientation marker (marker_z {spec.marker_z}, marker_length {spec.marker_length}) must lie on the "
            f"head's housing between the lens edge and head_height ({spec.head_height}): it spans rings {k_lo}-{k_hi}, "
            f"the housing of the head rings {first_body}-{head_top}"
        )
    half_w = 0.5 * spec.marker_width
    reach = s_ring[k_lo : k_hi + 1, : m // 4].min(axis=0)  # the least arc length to segment j over the rings
    if reach[-1] < half_w:
        raise BadValueError(f"ProbeSpec.marker_width ({spec.marker_width}) is wider than the head's end")
    big_j = int(np.argmax(reach >= half_w))  # the block spans segments -big_j .. big_j - 1
    return k_lo, k_hi, big_j, t0


def _stitch_outline(faces, rows, cols, lens, keep, index, n, big_j, k_span):
    """Split each outer face along the block's outline into a fan over the outline's fine vertices.

    Returns:
        keep: (F,) bool, the sweep's faces that stay; fans, fan_rows, fan_cols, fan_lens: lists of
        the new faces (n, 3) int64 and their band, segment and lens flags.
    """
    keep = keep.copy()
    chains = [index[0, q * n : q * n + n + 1] for q in range(2 * big_j)]
    chains += [index[-1, q * n : q * n + n + 1] for q in range(2 * big_j)]
    chains += [index[q * n : q * n + n + 1, 0] for q in range(k_span)]
    chains += [index[q * n : q * n + n + 1, -1] for q in range(k_span)]
    fans, fan_rows, fan_cols, fan_lens = [], [], [], []
    for chain in chains:
        v0, v1 = int(chain[0]), int(chain[-1])
        hit = np.flatnonzero(keep & (faces == v0).any(axis=1) & (faces == v1).any(axis=1))
        assert len(hit) == 1, f"outline edge ({v0}, {v1}) has {len(hit)} outer faces, not 1"
        f = hit[0]
        tri = list(faces[f])
        i0 = tri.index(v0)
        # walk the face's own winding: it runs (v1 -> v0) or (v0 -> v1) along the shared edge
        path = chain[::-1] if tri[(i0 + 2) % 3] == v1 else chain
        assert (tri.index(int(path[0])) + 1) % 3 == tri.index(int(path[-1])), "outline faces are wound consistently"
        apex = tri[(tri.index(int(path[-1])) + 1) % 3]
        fans.append(np.column_stack([path[:-1], path[1:], np.full(len(path) - 1, apex)]))
        fan_rows.append(np.full(len(path) - 1, rows[f]))
        fan_cols.append(np.full(len(path) - 1, cols[f]))
        fan_lens.append(np.full(len(path) - 1, lens[f]))
        keep[f] = False
    return keep, fans, fan_rows, fan_cols, fan_lens


def _patch_faces(index: np.ndarray, plus_y: np.ndarray, k0: np.ndarray, j0: np.ndarray, core: np.ndarray,
                 rim: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Triangles of the fine grid, split along mirrored diagonals on either side of y = 0 like the sweep.

    Args:
        index: (U, V) int64 vertex index of each fine grid point.
        plus_y: (U - 1, V - 1) bool, cells on the +y side.
        k0, j0: (U, V) int64 coarse ring and segment of each point's cell.
        core: (U, V) float64 distance of each point from the footprint's core, metres; rim: the
            footprint's radius about its core (:func:`marker_rim`), metres.

    Returns:
        faces (2 (U-1)(V-1), 3) int64, their bands and segments (int64) and marker flags (bool: the mean
        core distance of the cell's corners is below the rim).
    """
    lo, lo_n, hi, hi_n = index[:-1, :-1], index[:-1, 1:], index[1:, :-1], index[1:, 1:]
    plus_y = plus_y[..., None]
    t1 = np.where(plus_y, np.stack([lo, lo_n, hi], -1), np.stack([lo, lo_n, hi_n], -1))
    t2 = np.where(plus_y, np.stack([lo_n, hi_n, hi], -1), np.stack([lo, hi_n, hi], -1))
    patch = np.stack([t1, t2], axis=2).reshape(-1, 3)
    patch_rows = np.repeat((k0[:-1, :-1] + 1).reshape(-1), 2)
    patch_cols = np.repeat(j0[:-1, :-1].reshape(-1), 2)
    cell_core = np.stack([core[:-1, :-1], core[:-1, 1:], core[1:, :-1], core[1:, 1:]]).mean(axis=0)
    return patch, patch_rows, patch_cols, np.repeat((cell_core < rim).reshape(-1), 2)
