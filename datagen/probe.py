"""A procedural convex-array abdominal ultrasound probe and its signed distance.

The shape follows the GE Voluson C1-5-D: a wide, thin, fan-shaped head with a
convex cylindrical acoustic lens at the bottom, a smooth waist (the neck), a
rounded handle that flares slightly at its end, and a round strain relief
where the cable leaves. No CAD model of the real probe is used: every
dimension is an estimate from product photographs and data sheets (lens
radius about 55 mm, head about 72 x 22 mm, handle about 38 x 28 mm, about
165 mm long) and can be changed in :class:`ProbeSpec`.

The surface is a sweep of closed rounded-rectangle rings (one topological sphere:
a pole at the lens apex, rings up the body, a pole at the cable end), so the
mesh is watertight and consistently wound by construction. The lens is the
cap of concentric rings lying on the cylinder ``z = R - sqrt(R^2 - x^2)``;
a small fillet joins it to the housing. Near the lens the housing rings are
sheared along z by the same lens sag, so the lower edge of the housing
follows the lens arc and the head reads as a fan; the shear fades out
towards the neck.

An orientation marker (a raised green pad on the +x end of the head, see
:class:`ProbeSpec`) is moulded into the sweep by refining the quads under it
and pushing them out, so the mesh stays one closed surface. Without it the
probe would be exactly mirror-symmetric about x = 0 and y = 0, hence
unchanged by a half turn about its long axis; with it only the mirror
y -> -y remains, which no rigid motion can produce.

The signed distance is gridded: exact point-to-triangle distances (our own
vectorised closest-point computation, not trimesh's) at the nodes of a
regular grid, signed with angle-weighted pseudo-normals, then interpolated
trilinearly (numpy and differentiable torch versions of the same formula).
The grid of the symmetric sweep is computed on one quadrant and mirrored;
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
import math
from dataclasses import dataclass, fields
from typing import NamedTuple

import numpy as np
import torch
import trimesh
from scipy.interpolate import PchipInterpolator
from scipy.spatial import cKDTree

from datagen import tolerances as tol
from datagen.keypoints import CORNER_BITS

__all__ = [
    "ProbeSpec",
    "Probe",
    "RegionZ",
    "build_probe",
    "closest_points_on_triangles",
    "FEATURE_FACE",
    "FEATURE_VA",
    "FEATURE_VB",
    "FEATURE_VC",
    "FEATURE_EAB",
    "FEATURE_EBC",
    "FEATURE_ECA",
]


# --------------------------------------------------------------------------- spec


@dataclass(frozen=True)
class ProbeSpec:
    """Dimensions and tessellation of the procedural probe (metres unless noted).

    All dimensions are estimates of the GE Voluson C1-5-D, not measurements
    of a real unit. Widths are full extents along x, thicknesses full
    extents along y of the probe frame; heights are z of the probe frame on
    the long axis (x = y = 0), measured from the lens apex.

    Orientation marker (the ``marker_*`` fields): like every convex probe,
    the real one carries a mark at one end of its transducer array (a raised
    ridge or dot, on some probes a light) that matches the orientation mark
    on the scanner's screen; it is what tells the two ends of the array
    apart. Here it is a raised pad moulded into the **+x** end of the head
    (the end of the array on the probe frame's +x axis), centred on y = 0,
    on the shoulder where the head narrows towards the neck (z about 30 to
    38 mm): 14 mm along the shoulder by 20 mm around the end (the end is
    about 23 mm thick, so the pad covers its narrow face and wraps onto
    both rounded edges, to y = +-9.3 mm), its height rising smoothly over
    3 mm from its outline to 2 mm above the housing. It is drawn in its own
    bright green, glowing a little like a marker light
    (``datagen.scene.PROBE_MARKER_RGB`` and ``PROBE_MARKER_EMISSIVE``), and
    labelled probe (3) in the segmentation. It makes the probe no longer
    symmetric under the half turn about its long axis (x, y) -> (-x, -y),
    which otherwise maps the picture onto itself and swaps the 8 box corners
    in pairs, so the corner labels can be read from the image.

    Why this size and place: real marks are ridges of 2-3 mm or dots and
    lights of 3-5 mm; no CAD drawing of the C1-5-D's mark was available, so
    only its kind and place (one end of the array, on the head) follow the
    real probe, and it is made larger so that the models' 128 px input can
    see it. At the HUP-3D camera (f = 480 px at 256 px) 1 mm is 0.96 px at
    0.5 m and 0.6 px at 0.8 m of the stored 256 px image, half that at
    128 px: the pad spans up to about 7 x 10 px at 0.5 m and 4 x 6 px at
    0.8 m of a 128 px input. Wrapping it round the end's edges lets views of
    the head's broad faces see it too: on 160 frames of 3 grasps rendered
    by ``hupbench generate`` (40 views, 2 backgrounds) it showed at least
    8 green pixels of the 256 px image in 45 % of frames, against 26 % for
    an 8 mm wide pad with the same glow (24 mm: 52 %); a one-sided mark cannot show in views of
    the other end, where its absence is the cue. Its green differs from the
    grey housing, the dark lens, both gloves and the arm. It sits on the
    shoulder rather than on the flat end face because the flat end
    (x = 36 mm) is what bounds the box: the shoulder falls away from it
    there, so the raised pad stays inside the box (its outermost point at
    x = 34.4 mm, y = 9.3 mm of the box's 36 and 15 mm) and the 8 box corners
    (keypoints 21-28) do not move (the build refuses a spec whose marker
    leaves the box). Fingers of the grasps rest on the neck and the handle,
    above it.

    Attributes:
        lens_radius: radius of curvature of the cylindrical acoustic lens
            (its axis is parallel to y).
        head_width: x extent of the head at the lens.
        head_thickness: y extent of the head at the lens.
        lens_edge_radius: radius of the rounded edge between lens and housing.
        head_height: height at which the fan-shaped head meets the neck.
        neck_length: length of the neck (the waist) above the head.
        neck_width: x extent at the narrowest point of the neck.
        neck_thickness: y extent at the narrowest point of the neck.
        handle_width: x extent of the handle (grip).
        handle_thickness: y extent of the handle.
        handle_flare: how much wider and thicker the handle gets just before
            its cable-end shoulder.
        handle_end_radius: radius of the rounded shoulder at the handle's end.
        length: total length, lens apex to cable end.
        strain_relief_length: length of the cable strain relief, measured
            from the handle's end face to the cable end.
        strain_relief_diameter: diameter of the strain relief at its root; it
            tapers to 85 % of that at the cable end.
        marker_height: how far the orientation marker stands out of the
            housing (along the surface normal); 0 builds the probe without a
            marker, exactly mirror-symmetric about x = 0 and y = 0.
        marker_length: length of the marker along the +x side's meridian
            (the profile line y = 0 of the head's +x end, running up the
            shoulder from the lens edge towards the neck).
        marker_width: width of the marker across it, measured around the
            head's end (arc length towards +y and -y); its footprint is a
            stadium (a rectangle with semicircular ends) of ``marker_length``
            x ``marker_width``.
        marker_edge: width of the smooth ramp from the housing up to the
            marker's flat top, inside the footprint.
        marker_z: height z (probe frame) of the marker's centre on the +x
            meridian.
        marker_subdivisions: each quad of the sweep under the marker is split
            into this many x this many, so that its outline is resolved to
            about 0.7 mm (the sweep's quads there are about 2 mm).
        n_around: vertices per ring (a multiple of 4, so that rings are
            sampled symmetrically about the x and y axes).
        n_lens_rings: rings on the lens cap, apex excluded.
        n_fillet_rings: rings on the lens-edge fillet.
        n_body_rings: rings from the fillet to the end of the strain relief.
        n_cap_rings: rings on the dome that closes the cable end.
        sdf_spacing: node spacing of the signed-distance grid (a node sits
            on the lens apex, and the grid is symmetric about x = 0 and y = 0).
        sdf_margin: how far the grid extends beyond the mesh's bounding box;
            beyond it :meth:`Probe.signed_distance` returns an upper bound.
    """

    lens_radius: float = 0.055
    head_width: float = 0.072
    head_thickness: float = 0.022
    lens_edge_radius: float = 0.003
    head_height: float = 0.048
    neck_length: float = 0.018
    neck_width: float = 0.034
    neck_thickness: float = 0.025
    handle_width: float = 0.038
    handle_thickness: float = 0.028
    handle_flare: float = 0.002
    handle_end_radius: float = 0.004
    length: float = 0.165
    strain_relief_length: float = 0.017
    strain_relief_diameter: float = 0.015
    marker_height: float = 0.002
    marker_length: float = 0.014
    marker_width: float = 0.020
    marker_edge: float = 0.003
    marker_z: float = 0.034
    marker_subdivisions: int = 3
    n_around: int = 80
    n_lens_rings: int = 10
    n_fillet_rings: int = 4
    n_body_rings: int = 52
    n_cap_rings: int = 5
    sdf_spacing: float = 0.0015
    sdf_margin: float = 0.03

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if f.type in ("int", int):
                if isinstance(v, bool) or not isinstance(v, (int, np.integer)):
                    raise ValueError(f"ProbeSpec.{f.name} must be an int, got {v!r}")
            else:
                if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)):
                    raise ValueError(f"ProbeSpec.{f.name} must be a number (metres), got {v!r}")
                if not math.isfinite(v):
                    raise ValueError(f"ProbeSpec.{f.name} must be finite, got {v!r}")
            if f.name in ("sdf_margin", "marker_height"):
                if v < 0:
                    raise ValueError(f"ProbeSpec.{f.name} must be >= 0, got {v!r}")
            elif f.name == "handle_flare":
                if v < 0:
                    raise ValueError(f"ProbeSpec.handle_flare must be >= 0, got {v!r}")
            elif v <= 0:
                raise ValueError(f"ProbeSpec.{f.name} must be positive, got {v!r}")
        if self.n_around % 4 or self.n_around < 16:
            raise ValueError(f"ProbeSpec.n_around must be a multiple of 4 and >= 16, got {self.n_around}")
        if self.n_lens_rings < 2 or self.n_fillet_rings < 2 or self.n_body_rings < 8 or self.n_cap_rings < 2:
            raise ValueError(
                "ProbeSpec ring counts too small: need n_lens_rings >= 2, n_fillet_rings >= 2, "
                f"n_body_rings >= 8, n_cap_rings >= 2, got {self.n_lens_rings}, {self.n_fillet_rings}, "
                f"{self.n_body_rings}, {self.n_cap_rings}"
            )
        if min(self.marker_length, self.marker_width) <= 2 * self.marker_edge:
            raise ValueError(
                f"ProbeSpec marker footprint must have marker_length and marker_width > 2 * marker_edge, got "
                f"length {self.marker_length}, width {self.marker_width}, edge {self.marker_edge}"
            )
        r = self.lens_edge_radius
        if r >= _HEAD_CORNER * self.head_thickness / 2:
            raise ValueError(
                f"ProbeSpec.lens_edge_radius ({r}) must be less than the head's corner radius "
                f"({_HEAD_CORNER} * head_thickness / 2 = {_HEAD_CORNER * self.head_thickness / 2})"
            )
        if self.lens_radius <= self.head_width / 2:
            raise ValueError(
                f"ProbeSpec.lens_radius ({self.lens_radius}) must exceed half the head width "
                f"({self.head_width / 2}): the lens arc must span the head"
            )
        if self.neck_width > min(self.head_width, self.handle_width + self.handle_flare):
            raise ValueError(
                f"ProbeSpec.neck_width ({self.neck_width}) must not exceed the head width or the handle width"
            )
        if self.neck_thickness > self.handle_thickness:
            raise ValueError(
                f"ProbeSpec.neck_thickness ({self.neck_thickness}) must not exceed the handle thickness "
                f"({self.handle_thickness})"
            )
        lens_edge_top = float(_lens_sag(self.head_width / 2, self.lens_radius)) + r
        if self.head_height <= lens_edge_top:
            raise ValueError(
                f"ProbeSpec.head_height ({self.head_height}) is too small: it must exceed the height of the "
                f"lens edge (lens sagitta over the head width plus lens_edge_radius = {lens_edge_top:.4f})"
            )
        root = self.strain_relief_diameter / 2
        fillet = _boot_fillet(self)
        shoulder_in = (min(self.handle_width, self.handle_thickness) + self.handle_flare) / 2 - self.handle_end_radius
        if root + fillet >= shoulder_in:
            raise ValueError(
                f"ProbeSpec.strain_relief_diameter ({self.strain_relief_diameter}) and handle_end_radius "
                f"({self.handle_end_radius}) leave no flat end face on the handle "
                f"(handle {self.handle_width} x {self.handle_thickness})"
            )
        handle_end = self.length - self.strain_relief_length
        handle_start = self.head_height + self.neck_length
        if handle_end - handle_start < 4 * self.handle_end_radius:
            raise ValueError(
                f"ProbeSpec.length ({self.length}) leaves no handle: head_height + neck_length = "
                f"{handle_start}, handle end at length - strain_relief_length = {handle_end}"
            )
        if self.strain_relief_length < fillet + 0.85 * root + 1e-3:
            raise ValueError(
                f"ProbeSpec.strain_relief_length ({self.strain_relief_length}) is too short for its "
                f"diameter ({self.strain_relief_diameter})"
            )


def _lens_sag(x: np.ndarray | float, lens_radius: float) -> np.ndarray:
    """Height of the lens cylinder above its apex, ``R - sqrt(R^2 - x^2)`` (metres)."""
    x = np.asarray(x, dtype=np.float64)
    return lens_radius - np.sqrt(lens_radius**2 - x**2)


def _boot_fillet(spec: ProbeSpec) -> float:
    """Radius of the concave fillet where the strain relief meets the handle's end face."""
    return 0.15 * spec.strain_relief_diameter


# --------------------------------------------------------------------------- regions


class RegionZ(NamedTuple):
    """z ranges (z_min, z_max) in metres, probe frame, of the probe's parts.

    ``lens`` is the z range of the acoustic face; ``head`` runs from the
    apex to where the head meets the neck; ``neck`` is the waist; ``handle``
    the grip up to its end face; ``strain_relief`` the cable boot. Fingers
    of a plausible grasp lie on ``neck`` and ``handle``.
    """

    lens: tuple[float, float]
    head: tuple[float, float]
    neck: tuple[float, float]
    handle: tuple[float, float]
    strain_relief: tuple[float, float]


# --------------------------------------------------------------------------- geometry helpers


def _rounded_rect_ring(a: float, b: float, c: float, m: int) -> np.ndarray:
    """m points on a rounded rectangle, equally spaced in arc length.

    The rectangle spans [-a, a] x [-b, b] with quarter-circle corners of
    radius c (c = a = b is a circle). Point 0 lies on +x and the points run
    counter-clockwise seen from +z. One quadrant is sampled and mirrored,
    so the ring is exactly symmetric about the x and y axes, and points on
    the flat sides lie exactly on them (the signed-distance grid and the
    box corners rely on both).

    Args:
        a, b: half-extents along x and y, metres.
        c: corner radius, metres, 0 < c <= min(a, b).
        m: number of points, a multiple of 4.

    Returns:
        (m, 2) float64 (x, y), metres.
    """
    q = m // 4
    side_x, arc, side_y = b - c, 0.5 * np.pi * c, a - c  # quadrant pieces: x = a, the corner, y = b
    s = np.arange(q + 1) * ((side_x + arc + side_y) / q)
    angle = np.clip((s - side_x) / c, 0.0, 0.5 * np.pi)
    x = np.where(s <= side_x, a, np.where(s < side_x + arc, a - c + c * np.cos(angle), a - c - (s - side_x - arc)))
    y = np.where(s <= side_x, s, np.where(s < side_x + arc, b - c + c * np.sin(angle), b))
    quad = np.stack([x, y], axis=-1)  # (q+1, 2), +x axis to +y axis
    quad[0], quad[q] = (a, 0.0), (0.0, b)
    q2 = quad[::-1][1:] * [-1.0, 1.0]  # +y to -x
    q3 = quad[1:] * [-1.0, -1.0]  # -x to -y
    q4 = quad[::-1][1:-1] * [1.0, -1.0]  # -y to just before +x
    return np.concatenate([quad, q2, q3, q4])


def _smoothstep(t: np.ndarray) -> np.ndarray:
    t = np.clip(t, 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


#: The head keeps its full width, with its lower edge following the lens
#: arc, over this fraction of its height above the edge fillet; then it
#: tapers to the neck. The straight sides also keep the axis-aligned box the
#: minimum-volume box: without them, tilting the box about y trades a little
#: width for the height of the curved lens and finds a smaller, tilted box
#: (about 0.2 % smaller with a 7 degree tilt). The flat sides of the
#: rounded-rectangle sections make that side an exact plane x = +-a, so that
#: oriented-box searches that try hull face normals find the axis-aligned box.
_HEAD_STRAIGHT_FRACTION = 0.22


#: corner radius of the head's cross-section as a fraction of its half-thickness
_HEAD_CORNER = 0.75


class _Meridian(NamedTuple):
    """Dense body profile from the lens fillet to the end of the strain relief."""

    zc: np.ndarray  # (P,) axial height before the lens shear, metres
    a: np.ndarray  # (P,) ring half-width along x, metres
    b: np.ndarray  # (P,) ring half-thickness along y, metres
    corner: np.ndarray  # (P,) corner radius of the ring's rounded rectangle, as a fraction of min(a, b)


def _body_meridian(spec: ProbeSpec) -> _Meridian:
    """The body's ring parameters as a dense polyline (fillet end -> boot end)."""
    r = spec.lens_edge_radius
    A, B = spec.head_width / 2, spec.head_thickness / 2
    Nw, Nt = spec.neck_width / 2, spec.neck_thickness / 2
    Hw, Ht = spec.handle_width / 2, spec.handle_thickness / 2
    flare = spec.handle_flare / 2
    h0, h1 = spec.head_height, spec.head_height + spec.neck_length
    z_end_face = spec.length - spec.strain_relief_length
    rs = spec.handle_end_radius
    L = h0 - r
    dA, dB = A - Nw, Nt - B
    handle_len = z_end_face - rs - h1
    k_head, k_handle, k_boot = _HEAD_CORNER, 0.7, 1.0

    # free-form part: the fan-shaped head (full width for a while, then
    # converging shoulders), the waist, the grip and its flare; PCHIP keeps
    # it C1 with no overshoot, and flat at the extremes of the waist and flare
    key = np.array(
        [
            # zc, a (half-width), b (half-thickness), corner radius / min(a, b)
            (r, A, B, k_head),
            (r + _HEAD_STRAIGHT_FRACTION * L, A, B + 0.05 * dB, k_head),
            (r + 0.52 * L, A - 0.28 * dA, B + 0.40 * dB, 0.8),
            (r + 0.80 * L, A - 0.75 * dA, B + 0.85 * dB, 0.8),
            (h0, Nw + 0.15 * (Hw - Nw), Nt, 0.8),
            ((h0 + h1) / 2, Nw, Nt, 0.8),
            (h1, Nw + 0.6 * (Hw - Nw), Nt + 0.6 * (Ht - Nt), 0.75),
            (h1 + 0.25 * handle_len, Hw, Ht, k_handle),
            (h1 + 0.65 * handle_len, Hw, Ht, k_handle),
            (z_end_face - rs, Hw + flare, Ht + flare, k_handle),
        ]
    )
    zc_free = np.linspace(key[0, 0], key[-1, 0], 900)
    a_free = PchipInterpolator(key[:, 0], key[:, 1])(zc_free)
    b_free = PchipInterpolator(key[:, 0], key[:, 2])(zc_free)
    k_free = PchipInterpolator(key[:, 0], key[:, 3])(zc_free)

    # rounded shoulder onto the handle's flat end face
    phi = np.linspace(0.0, np.pi / 2, 40)[1:]
    zc_sh = z_end_face - rs + rs * np.sin(phi)
    a_sh = Hw + flare - rs + rs * np.cos(phi)
    b_sh = Ht + flare - rs + rs * np.cos(phi)
    k_sh = np.full_like(phi, k_handle)

    # flat end face, inwards to the root of the strain relief's fillet
    root = spec.strain_relief_diameter / 2
    fr = _boot_fillet(spec)
    t = np.linspace(0.0, 1.0, 30)[1:]
    a_face = a_sh[-1] + (root + fr - a_sh[-1]) * t
    b_face = b_sh[-1] + (root + fr - b_sh[-1]) * t
    zc_face = np.full_like(t, z_end_face)
    k_face = k_handle + (k_boot - k_handle) * t

    # concave fillet up into the strain relief
    psi = np.linspace(0.0, np.pi / 2, 30)[1:]
    zc_fi = z_end_face + fr - fr * np.cos(psi)
    a_fi = root + fr - fr * np.sin(psi)
    k_fi = np.full_like(psi, k_boot)

    # the strain relief tapers slightly towards the cable
    end_radius = 0.85 * root
    t = np.linspace(0.0, 1.0, 60)[1:]
    zc_boot = zc_fi[-1] + (spec.length - end_radius - zc_fi[-1]) * t
    a_boot = root + (end_radius - root) * t
    k_boot_arr = np.full_like(t, k_boot)

    return _Meridian(
        zc=np.concatenate([zc_free, zc_sh, zc_face, zc_fi, zc_boot]),
        a=np.concatenate([a_free, a_sh, a_face, a_fi, a_boot]),
        b=np.concatenate([b_free, b_sh, b_face, a_fi, a_boot]),
        corner=np.concatenate([k_free, k_sh, k_face, k_fi, k_boot_arr]),
    )


def _resample_meridian(mer: _Meridian, count: int, bend_weight_m: float = 0.008) -> _Meridian:
    """``count`` samples along the meridian, denser where it bends.

    Samples are equally spaced in ``arc length + bend_weight_m * turning
    angle`` so that the tight shoulder and fillets get rings, not just the
    long straight grip. The first dense point (the fillet's end ring) is
    excluded; the last is included.
    """
    pts_a = np.stack([mer.zc, mer.a], axis=-1)
    pts_b = np.stack([mer.zc, mer.b], axis=-1)
    d_a, d_b = np.diff(pts_a, axis=0), np.diff(pts_b, axis=0)
    ds = 0.5 * (np.linalg.norm(d_a, axis=-1) + np.linalg.norm(d_b, axis=-1))
    ang_a = np.unwrap(np.arctan2(d_a[:, 1], d_a[:, 0]))
    ang_b = np.unwrap(np.arctan2(d_b[:, 1], d_b[:, 0]))
    turn = 0.5 * (np.abs(np.diff(ang_a, prepend=ang_a[0])) + np.abs(np.diff(ang_b, prepend=ang_b[0])))
    cost = np.concatenate([[0.0], np.cumsum(ds + bend_weight_m * turn)])
    target = np.linspace(0.0, cost[-1], count + 1)[1:]
    return _Meridian(*(np.interp(target, cost, arr) for arr in mer))


# --------------------------------------------------------------------------- mesh

class _Rings(NamedTuple):
    vertices: np.ndarray  # (K, M, 3) ring vertices, probe frame, metres, from the lens apex up
    n_lens: int  # the first n_lens rings lie on the lens


def _build_rings(spec: ProbeSpec) -> _Rings:
    """Ring vertices from the lens apex to the cable end (poles excluded)."""
    m = spec.n_around
    R = spec.lens_radius
    r = spec.lens_edge_radius
    A, B = spec.head_width / 2, spec.head_thickness / 2
    shear_full = r + _HEAD_STRAIGHT_FRACTION * (spec.head_height - r)

    def shear(zc: float) -> float:
        return float(1.0 - _smoothstep((zc - shear_full) / (spec.head_height - shear_full)))

    rings = []
    # lens cap: scaled copies of its outline (the head's section shrunk by the
    # edge radius), lying on the lens cylinder
    c = _HEAD_CORNER * B
    outline = _rounded_rect_ring(A - r, B - r, c - r, m)
    for rho in np.arange(1, spec.n_lens_rings + 1) / spec.n_lens_rings:
        xy = rho * outline
        rings.append(np.column_stack([xy, _lens_sag(xy[:, 0], R)]))
    # edge fillet: a quarter round in the sheared frame, tangent to lens and
    # housing; offsets of a rounded rectangle are rounded rectangles
    for phi in np.arange(1, spec.n_fillet_rings + 1) * (np.pi / 2 / spec.n_fillet_rings):
        grow = r * np.sin(phi) if phi < np.pi / 2 else r
        xy = _rounded_rect_ring(A - r + grow, B - r + grow, c - r + grow, m)
        zc = r * (1.0 - np.cos(phi))
        rings.append(np.column_stack([xy, zc + shear(zc) * _lens_sag(xy[:, 0], R)]))
    # body, up to the end of the strain relief
    mer = _resample_meridian(_body_meridian(spec), spec.n_body_rings)
    for zc, a, b, corner in zip(*mer):
        xy = _rounded_rect_ring(a, b, corner * min(a, b), m)
        rings.append(np.column_stack([xy, zc + shear(zc) * _lens_sag(xy[:, 0], R)]))
    # dome closing the cable end
    end_radius = mer.a[-1]
    z0 = spec.length - end_radius
    for phi in np.arange(1, spec.n_cap_rings + 1) * (np.pi / 2 / (spec.n_cap_rings + 1)):
        rho = end_radius * np.cos(phi)
        xy = _rounded_rect_ring(rho, rho, rho, m)
        rings.append(np.column_stack([xy, np.full(m, z0 + end_radius * np.sin(phi))]))
    rings = np.stack(rings)

    # A spec far from the defaults could fold the sweep onto itself; every
    # ring must lie above the previous one, or (lens cap, flat end face) at
    # the same height and further in.
    rad = np.hypot(rings[..., 0], rings[..., 1])
    dz = np.diff(rings[..., 2], axis=0)
    dr = np.diff(rad, axis=0)
    ok = (dz > tol.PROBE_RING_STEP_M) | ((dz > -tol.PROBE_RING_STEP_M) & (dr < -tol.PROBE_RING_STEP_M))
    ok[: spec.n_lens_rings - 1] = np.all(dr[: spec.n_lens_rings - 1] > 0)  # the lens cap grows outwards
    if not np.all(ok):
        k = int(np.argmin(ok.all(axis=1)))
        raise ValueError(
            f"ProbeSpec gives a self-folding surface between rings {k} and {k + 1} "
            f"(z about {1e3 * rings[k, :, 2].mean():.1f} mm); make the head taller or the tapers gentler"
        )
    return _Rings(rings, spec.n_lens_rings)


def _ring_faces(n_rings: int, m: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Faces of a closed surface: bottom pole, ``n_rings`` rings of ``m``, top pole.

    Vertex 0 is the bottom pole, ring k vertex j is ``1 + k*m + j``, the top
    pole is ``1 + n_rings*m``. Winding is outward for rings that run
    counter-clockwise seen from +z and go upwards. Quads are split along
    mirrored diagonals in alternate quadrants, so the triangulation is
    exactly symmetric about the xz and yz planes (as the rings are).

    Returns:
        faces: (2 * m * n_rings, 3) int64: the bottom fan, the ring bands
            from the bottom up, the top fan.
        rows: (F,) int64 band of each face (0 = bottom fan, n_rings = top fan).
        cols: (F,) int64 ring segment of each face (0..m-1).
    """
    j = np.arange(m)
    jn = (j + 1) % m
    bottom = np.column_stack([np.zeros(m, dtype=np.int64), 1 + jn, 1 + j])
    k = np.arange(n_rings - 1)[:, None]
    lo, lo_n = 1 + k * m + j, 1 + k * m + jn
    hi, hi_n = lo + m, lo_n + m
    # quadrants 1 and 3 cut along lo_n-hi, quadrants 2 and 4 along lo-hi_n
    odd_quadrant = ((j // (m // 4)) % 2 == 1)[None, :]
    t1 = np.where(odd_quadrant[..., None], np.stack([lo, lo_n, hi_n], -1), np.stack([lo, lo_n, hi], -1))
    t2 = np.where(odd_quadrant[..., None], np.stack([lo, hi_n, hi], -1), np.stack([lo_n, hi_n, hi], -1))
    band = np.stack([t1, t2], axis=2).reshape(-1, 3)
    top_pole = 1 + n_rings * m
    last = 1 + (n_rings - 1) * m
    top = np.column_stack([np.full(m, top_pole), last + j, last + jn])
    faces = np.concatenate([bottom, band, top]).astype(np.int64)
    rows = np.concatenate([np.zeros(m), np.repeat(np.arange(1, n_rings), 2 * m), np.full(m, n_rings)])
    cols = np.concatenate([j, np.tile(np.repeat(j, 2), n_rings - 1), j])
    return faces, rows.astype(np.int64), cols.astype(np.int64)


# --------------------------------------------------------------------------- orientation marker


class _MarkedMesh(NamedTuple):
    """The swept mesh with the orientation marker moulded into it."""

    vertices: np.ndarray  # (V, 3) float64, probe frame, metres
    faces: np.ndarray  # (F, 3) int64, outward-wound
    rows: np.ndarray  # (F,) int64 band of each face in the sweep layout (see _ring_faces)
    cols: np.ndarray  # (F,) int64 ring segment of each face
    lens: np.ndarray  # (F,) bool, faces of the acoustic lens
    marker: np.ndarray  # (F,) bool, faces of the marker's footprint (drawn in the marker colour)
    changed_lo: np.ndarray  # (3,) lower corner of a box holding every surface point that differs from the sweep
    changed_hi: np.ndarray  # (3,) upper corner of that box


def _marker_profile(t: np.ndarray, s: np.ndarray, spec: ProbeSpec, t0: float) -> tuple[np.ndarray, np.ndarray]:
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
    rim = _marker_rim(spec)
    dt = np.maximum(np.abs(t - t0) - (0.5 * spec.marker_length - rim), 0.0)
    ds = np.maximum(np.abs(s) - (0.5 * spec.marker_width - rim), 0.0)
    core_distance = np.hypot(dt, ds)
    height = spec.marker_height * _smoothstep((rim - core_distance) / spec.marker_edge)
    return height, core_distance


def _marker_rim(spec: ProbeSpec) -> float:
    """Radius of the footprint's rounded ends: half its shorter extent, metres."""
    return 0.5 * min(spec.marker_length, spec.marker_width)


def _add_marker(spec: ProbeSpec, vertices: np.ndarray, faces: np.ndarray, rows: np.ndarray, cols: np.ndarray,
                lens: np.ndarray, n_rings: int) -> _MarkedMesh:
    """Mould the orientation marker into the +x end of the head.

    The quads of the sweep under the marker (a block of whole ring bands and
    segments centred on the +x meridian) are replaced by a finer grid, each
    quad split into ``marker_subdivisions`` x ``marker_subdivisions`` by
    bilinear interpolation of its corners, and that grid is pushed out along
    the interpolated vertex normals by :func:`_marker_profile`. The height is
    0 on the block's outline, whose edges keep their straight shape; the
    neighbouring triangles that share an outline edge are split into fans
    that take the outline's new vertices, so the surface stays one closed,
    consistently wound 2-manifold (no booleans, no T-junctions). New faces
    keep the (band, segment) layout of the quad they came from.

    Args:
        spec: the probe spec (``marker_height > 0``).
        vertices: (V, 3) float64 vertices of the sweep (:func:`_build_probe_cached` layout).
        faces, rows, cols: (F, 3), (F,), (F,) int64 from :func:`_ring_faces`.
        lens: (F,) bool lens faces.
        n_rings: number of rings of the sweep.

    Returns:
        :class:`_MarkedMesh`.

    Raises:
        ValueError: the spec places the marker off the head's housing, or it would stick out of the
            probe's bounding box (whose corners are keypoints).
    """
    m, n = spec.n_around, spec.marker_subdivisions
    ring = vertices[1 : 1 + n_rings * m].reshape(n_rings, m, 3)
    normals = trimesh.Trimesh(vertices, faces, process=False).vertex_normals[1 : 1 + n_rings * m].reshape(n_rings, m, 3)

    # surface coordinates: t = arc length along the +x meridian (vertex 0 of every ring, on y = 0),
    # s = signed arc length around each ring from that vertex (+y positive)
    meridian = ring[:, 0]
    t_ring = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(meridian, axis=0), axis=-1))])
    seg = np.linalg.norm(np.roll(ring, -1, axis=1) - ring, axis=-1)  # (K, m): segment j runs from j to j + 1
    around = np.concatenate([np.zeros((n_rings, 1)), np.cumsum(seg, axis=1)[:, :-1]], axis=1)
    perimeter = seg.sum(axis=1, keepdims=True)
    j = np.arange(m)
    s_ring = np.where(j <= m // 2, around, around - perimeter)  # (K, m)

    first_body = spec.n_lens_rings + spec.n_fillet_rings
    head_top = int(np.searchsorted(meridian[:, 2], spec.head_height))
    above = np.flatnonzero(meridian[first_body:, 2] >= spec.marker_z)
    if not len(above) or first_body + above[0] == first_body:
        raise ValueError(f"ProbeSpec.marker_z ({spec.marker_z}) must lie on the housing of the head, above the "
                         f"lens edge (z {meridian[first_body, 2]:.4f} m on the +x side) and below head_height")
    k = first_body + int(above[0])
    w = (spec.marker_z - meridian[k - 1, 2]) / (meridian[k, 2] - meridian[k - 1, 2])
    t0 = float(t_ring[k - 1] + w * (t_ring[k] - t_ring[k - 1]))
    k_lo = int(np.searchsorted(t_ring, t0 - 0.5 * spec.marker_length, side="right")) - 1
    k_hi = int(np.searchsorted(t_ring, t0 + 0.5 * spec.marker_length, side="left"))
    if k_lo < first_body or k_hi > head_top:
        raise ValueError(
            f"the orientation marker (marker_z {spec.marker_z}, marker_length {spec.marker_length}) must lie on the "
            f"head's housing between the lens edge and head_height ({spec.head_height}): it spans rings {k_lo}-{k_hi}, "
            f"the housing of the head rings {first_body}-{head_top}"
        )
    half_w = 0.5 * spec.marker_width
    reach = s_ring[k_lo : k_hi + 1, : m // 4].min(axis=0)  # the least arc length to segment j over the rings
    if reach[-1] < half_w:
        raise ValueError(f"ProbeSpec.marker_width ({spec.marker_width}) is wider than the head's end")
    big_j = int(np.argmax(reach >= half_w))  # the block spans segments -big_j .. big_j - 1

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
    height, core = _marker_profile(t_fine, s_fine, spec, t0)
    outline = np.zeros(height.shape, dtype=bool)
    outline[[0, -1], :] = outline[:, [0, -1]] = True
    if np.any(height[outline] != 0.0):
        raise RuntimeError("orientation marker: the block under the marker does not contain its footprint")
    moved = base + height[..., None] * normal

    # vertex indices: fine points on coarse vertices reuse them, the others are appended
    index = np.empty((u_count, v_count), dtype=np.int64)
    on_coarse = (a % n == 0) & (b % n == 0)
    index[on_coarse] = 1 + (k_lo + a[on_coarse] // n) * m + (b[on_coarse] // n - big_j) % m
    fresh = ~on_coarse
    index[fresh] = len(vertices) + np.arange(int(fresh.sum()))
    out_vertices = np.concatenate([vertices, moved[fresh]])
    out_vertices[index[on_coarse]] = moved[on_coarse]

    # patch faces, split along mirrored diagonals on either side of y = 0 like the sweep (_ring_faces)
    lo, lo_n, hi, hi_n = index[:-1, :-1], index[:-1, 1:], index[1:, :-1], index[1:, 1:]
    plus_y = (b[:-1, :-1] >= big_j * n)[..., None]
    t1 = np.where(plus_y, np.stack([lo, lo_n, hi], -1), np.stack([lo, lo_n, hi_n], -1))
    t2 = np.where(plus_y, np.stack([lo_n, hi_n, hi], -1), np.stack([lo, hi_n, hi], -1))
    patch = np.stack([t1, t2], axis=2).reshape(-1, 3)
    patch_rows = np.repeat((k0[:-1, :-1] + 1).reshape(-1), 2)
    patch_cols = np.repeat(j0[:-1, :-1].reshape(-1), 2)
    cell_core = np.stack([core[:-1, :-1], core[:-1, 1:], core[1:, :-1], core[1:, 1:]]).mean(axis=0)
    patch_marker = np.repeat((cell_core < _marker_rim(spec)).reshape(-1), 2)

    block_cols = (np.arange(-big_j, big_j)) % m
    block = (rows >= k_lo + 1) & (rows <= k_hi) & np.isin(cols, block_cols)
    if block.sum() != 2 * (k_hi - k_lo) * 2 * big_j:
        raise RuntimeError("orientation marker: the block under the marker is not whole quads of the sweep")

    # the outline's edges, each with the fine vertices along it
    chains = [index[0, q * n : q * n + n + 1] for q in range(2 * big_j)]
    chains += [index[-1, q * n : q * n + n + 1] for q in range(2 * big_j)]
    chains += [index[q * n : q * n + n + 1, 0] for q in range(k_hi - k_lo)]
    chains += [index[q * n : q * n + n + 1, -1] for q in range(k_hi - k_lo)]
    keep = ~block
    fans, fan_rows, fan_cols, fan_lens = [], [], [], []
    for chain in chains:
        v0, v1 = int(chain[0]), int(chain[-1])
        hit = np.flatnonzero(keep & (faces == v0).any(axis=1) & (faces == v1).any(axis=1))
        if len(hit) != 1:
            raise RuntimeError(f"orientation marker: outline edge ({v0}, {v1}) has {len(hit)} outer faces, not 1")
        f = hit[0]
        tri = list(faces[f])
        i0 = tri.index(v0)
        # walk the face's own winding: it runs (v1 -> v0) or (v0 -> v1) along the shared edge
        path = chain[::-1] if tri[(i0 + 2) % 3] == v1 else chain
        if not (tri.index(int(path[0])) + 1) % 3 == tri.index(int(path[-1])):
            raise RuntimeError("orientation marker: an outline face is not wound consistently")
        apex = tri[(tri.index(int(path[-1])) + 1) % 3]
        fans.append(np.column_stack([path[:-1], path[1:], np.full(len(path) - 1, apex)]))
        fan_rows.append(np.full(len(path) - 1, rows[f]))
        fan_cols.append(np.full(len(path) - 1, cols[f]))
        fan_lens.append(np.full(len(path) - 1, lens[f]))
        keep[f] = False

    out_faces = np.concatenate([faces[keep], *fans, patch]).astype(np.int64)
    out_rows = np.concatenate([rows[keep], *fan_rows, patch_rows]).astype(np.int64)
    out_cols = np.concatenate([cols[keep], *fan_cols, patch_cols]).astype(np.int64)
    out_lens = np.concatenate([lens[keep], *fan_lens, np.zeros(len(patch), dtype=bool)])
    out_marker = np.concatenate([np.zeros(int(keep.sum()) + sum(len(x) for x in fans), dtype=bool), patch_marker])

    body_lo, body_hi = vertices.min(axis=0), vertices.max(axis=0)
    if np.any(moved < body_lo) or np.any(moved > body_hi):
        raise ValueError(
            "the orientation marker sticks out of the probe's bounding box (its corners are keypoints 21-28 and "
            f"must not move): marker spans {moved.reshape(-1, 3).min(axis=0)} .. {moved.reshape(-1, 3).max(axis=0)} m, "
            f"the box {body_lo} .. {body_hi} m; lower marker_height or move marker_z"
        )
    old = vertices[faces[block].reshape(-1)]
    changed = np.concatenate([old, moved.reshape(-1, 3)])
    return _MarkedMesh(out_vertices, out_faces, out_rows, out_cols, out_lens, out_marker,
                       changed.min(axis=0), changed.max(axis=0))


def _patch_grid(grid: np.ndarray, axes: tuple[np.ndarray, np.ndarray, np.ndarray], distance: "_MeshDistance",
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


# --------------------------------------------------------------------------- distance to triangles

#: closest-feature codes returned by :func:`closest_points_on_triangles`
FEATURE_FACE, FEATURE_VA, FEATURE_VB, FEATURE_VC, FEATURE_EAB, FEATURE_EBC, FEATURE_ECA = range(7)


def _dot(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    return np.einsum("...i,...i->...", u, v)


def closest_points_on_triangles(
    points: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact closest points on triangles (Ericson, Real-Time Collision Detection, 5.1.5).

    Broadcasts over leading dimensions. Degenerate triangles fall into the
    vertex and edge cases and stay exact.

    Args:
        points: (..., 3) float64 query points, metres, any common frame.
        a, b, c: (..., 3) float64 triangle corners in the same frame.

    Returns:
        sq_dist: (...) float64 squared distance, m^2.
        bary: (..., 3) float64 barycentric weights of the closest point on (a, b, c).
        feature: (...) int8 closest feature: ``FEATURE_FACE`` (interior),
            ``FEATURE_VA/VB/VC`` (a corner) or ``FEATURE_EAB/EBC/ECA`` (an edge).
    """
    ab, ac = b - a, c - a
    ap, bp, cp = points - a, points - b, points - c
    d1, d2 = _dot(ab, ap), _dot(ac, ap)
    d3, d4 = _dot(ab, bp), _dot(ac, bp)
    d5, d6 = _dot(ab, cp), _dot(ac, cp)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2

    # Ericson's tests run in a fixed order and the first that holds wins;
    # assigning masks in reverse order lets earlier tests overwrite later ones.
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = va + vb + vc
        safe = np.where(denom != 0, denom, 1.0)
        v, w = vb / safe, vc / safe
        feature = np.full(d1.shape, FEATURE_FACE, dtype=np.int8)

        def assign(mask, code, v_new, w_new):
            # the closest point is a + v ab + w ac
            nonlocal v, w
            v, w = np.where(mask, v_new, v), np.where(mask, w_new, w)
            feature[mask] = code

        t = np.clip(np.nan_to_num((d4 - d3) / ((d4 - d3) + (d5 - d6))), 0.0, 1.0)
        assign((va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0), FEATURE_EBC, 1.0 - t, t)
        t = np.clip(np.nan_to_num(d2 / (d2 - d6)), 0.0, 1.0)
        assign((vb <= 0) & (d2 >= 0) & (d6 <= 0), FEATURE_ECA, 0.0, t)
        assign((d6 >= 0) & (d5 <= d6), FEATURE_VC, 0.0, 1.0)
        t = np.clip(np.nan_to_num(d1 / (d1 - d3)), 0.0, 1.0)
        assign((vc <= 0) & (d1 >= 0) & (d3 <= 0), FEATURE_EAB, t, 0.0)
        assign((d3 >= 0) & (d4 <= d3), FEATURE_VB, 1.0, 0.0)
        assign((d1 <= 0) & (d2 <= 0), FEATURE_VA, 0.0, 0.0)

    bary = np.stack([1.0 - v - w, v, w], axis=-1)
    diff = points - (a + v[..., None] * ab + w[..., None] * ac)
    return _dot(diff, diff), bary, feature


def _pack_triangles(tri: np.ndarray) -> np.ndarray:
    """Per-face constants for :func:`_sq_dist_packed`: (F, 13) float64.

    Columns: a (3), ab (3), ac (3), |ab|^2, |ac|^2, ab.ac, |bc|^2.
    """
    a, ab, ac = tri[:, 0], tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    aa, cc, abac = _dot(ab, ab), _dot(ac, ac), _dot(ab, ac)
    return np.column_stack([a, ab, ac, aa, cc, abac, aa + cc - 2.0 * abac])


def _sq_dist_packed(points: np.ndarray, packed: np.ndarray) -> np.ndarray:
    """Exact squared distance from points (P, 3) to packed triangles (P, 13): (P,) float64, m^2.

    The same regions as :func:`closest_points_on_triangles`, but only the
    distance: inside the face's prism it is the distance to the plane,
    otherwise the nearest of the three edges (clamped segments), all from
    the scalars ``ab.ap`` and ``ac.ap``. About three times faster; the full
    version then runs on the winning face only.
    """
    ap = points - packed[:, 0:3]
    app = _dot(ap, ap)
    d1, d2 = _dot(packed[:, 3:6], ap), _dot(packed[:, 6:9], ap)
    aa, cc, abac, bb = packed[:, 9], packed[:, 10], packed[:, 11], packed[:, 12]
    d3, d4, d5, d6 = d1 - aa, d2 - abac, d1 - abac, d2 - cc
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    denom = va + vb + vc
    inside = (va >= 0) & (vb >= 0) & (vc >= 0) & (denom > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        safe = np.where(denom > 0, denom, 1.0)
        sq_face = app - (vb * d1 + vc * d2) / safe
        t = np.clip(np.nan_to_num(d1 / aa), 0.0, 1.0)
        sq = app - t * (2.0 * d1 - t * aa)
        t = np.clip(np.nan_to_num(d2 / cc), 0.0, 1.0)
        sq = np.minimum(sq, app - t * (2.0 * d2 - t * cc))
        e = d4 - d3  # bc . bp
        t = np.clip(np.nan_to_num(e / bb), 0.0, 1.0)
        sq = np.minimum(sq, (app - 2.0 * d1 + aa) - t * (2.0 * e - t * bb))
    return np.maximum(np.where(inside, sq_face, sq), 0.0)


class _PseudoNormals(NamedTuple):
    face: np.ndarray  # (F, 3) unit face normals
    edge: np.ndarray  # (F, 3, 3) per face and edge (ab, bc, ca): sum of the two adjacent face normals
    vertex: np.ndarray  # (V, 3) angle-weighted vertex normals


def _pseudo_normals(vertices: np.ndarray, faces: np.ndarray) -> _PseudoNormals:
    """Angle-weighted pseudo-normals (Baerentzen and Aanaes 2005) of a closed mesh.

    With q the exact closest point to p and n the pseudo-normal of q's
    feature (face, edge or vertex), ``sign((p - q) . n)`` is the
    inside/outside sign of p for any watertight, outward-wound mesh,
    concave parts included.
    """
    tri = vertices[faces]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    norm = np.linalg.norm(cross, axis=-1, keepdims=True)
    face_n = cross / np.where(norm > 0, norm, 1.0)

    # edge (f, k) runs from corner k to corner k+1; its twin is in the neighbouring face
    edge_v = np.stack([faces, np.roll(faces, -1, axis=1)], axis=-1).reshape(-1, 2)
    lo, hi = edge_v.min(axis=1), edge_v.max(axis=1)
    key = lo * (len(vertices) + 1) + hi
    order = np.argsort(key, kind="stable")
    sk = key[order]
    if len(sk) % 2 or np.any(sk[0::2] != sk[1::2]) or np.any(sk[1:-1:2] == sk[2::2]):
        raise ValueError("mesh is not a closed 2-manifold: every edge needs exactly two faces")
    twin = np.empty_like(order)
    twin[order[0::2]], twin[order[1::2]] = order[1::2], order[0::2]
    edge_face = np.repeat(np.arange(len(faces)), 3)
    edge_n = (face_n[edge_face] + face_n[edge_face[twin]]).reshape(-1, 3, 3)

    angles = np.empty((len(faces), 3))
    for k in range(3):
        e1 = tri[:, (k + 1) % 3] - tri[:, k]
        e2 = tri[:, (k + 2) % 3] - tri[:, k]
        # atan2 of |cross| and dot is accurate for thin triangles, unlike arccos
        angles[:, k] = np.arctan2(np.linalg.norm(np.cross(e1, e2), axis=-1), _dot(e1, e2))
    vertex_n = np.zeros_like(vertices)
    np.add.at(vertex_n, faces.reshape(-1), (angles[..., None] * face_n[:, None, :]).reshape(-1, 3))
    return _PseudoNormals(face_n, edge_n, vertex_n)


#: elements per vectorised batch: small enough that numpy's temporaries stay in cache
_BATCH = 16384


def _chunked(fn, points: np.ndarray, index: np.ndarray) -> np.ndarray:
    """``fn(points, index)`` evaluated in batches of ``_BATCH`` rows."""
    if len(index) <= _BATCH:
        return fn(points, index)
    out = np.empty(len(index))
    for s in range(0, len(index), _BATCH):
        out[s : s + _BATCH] = fn(points[s : s + _BATCH], index[s : s + _BATCH])
    return out


class _Cylinders(NamedTuple):
    """Bounding cylinders of face groups.

    Every point x of group g satisfies ``lo[g] <= axis[g] . (x - centre[g]) <= hi[g]``
    and ``|tangential part of (x - centre[g])| <= radius[g]``. Packed as
    (G, 9) float64: centre (3), unit axis (3), lo, hi, radius.
    """

    packed: np.ndarray

    def lower_bound(self, points: np.ndarray, group: np.ndarray) -> np.ndarray:
        """Distance from points (P, 3) to the cylinders of ``group`` (P,): (P,) float64.

        A cylinder contains its faces, so this never exceeds the distance
        to any face of the group.
        """
        return _chunked(self._lower_bound, points, group)

    def _lower_bound(self, points: np.ndarray, group: np.ndarray) -> np.ndarray:
        g = self.packed[group]
        rel = points - g[:, 0:3]
        along = _dot(rel, g[:, 3:6])
        axial = np.maximum(np.maximum(along - g[:, 7], g[:, 6] - along), 0.0)
        radial = np.maximum(np.sqrt(np.maximum(_dot(rel, rel) - along * along, 0.0)) - g[:, 8], 0.0)
        return np.sqrt(axial * axial + radial * radial)


def _group_cylinders(tri: np.ndarray, group: np.ndarray) -> _Cylinders:
    """Bounding cylinders, axis along the area-weighted mean normal, of faces grouped by ``group``.

    Args:
        tri: (F, 3, 3) float64 face corners.
        group: (F,) int64 group of each face, 0..G-1, every group non-empty.
    """
    order = np.argsort(group, kind="stable")
    g = group[order]
    starts = np.flatnonzero(np.r_[True, g[1:] != g[:-1]])
    t = tri[order]
    axis = np.add.reduceat(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), starts)
    norm = np.linalg.norm(axis, axis=-1, keepdims=True)
    # a group whose normals cancel still gets a valid (if loose) cylinder about z
    axis = np.where(norm > 0, axis / np.where(norm > 0, norm, 1.0), [0.0, 0.0, 1.0])
    corners = t.reshape(-1, 3)
    cg = np.repeat(g, 3)
    cstarts = 3 * starts
    centre = np.add.reduceat(corners, cstarts) / np.diff(np.r_[cstarts, len(corners)])[:, None]
    rel = corners - centre[cg]
    along = _dot(rel, axis[cg])
    radial = np.linalg.norm(rel - along[:, None] * axis[cg], axis=-1)
    packed = np.column_stack(
        [
            centre,
            axis,
            np.minimum.reduceat(along, cstarts),
            np.maximum.reduceat(along, cstarts),
            np.maximum.reduceat(radial, cstarts),
        ]
    )
    return _Cylinders(packed)


class _Closest(NamedTuple):
    """Closest points on a mesh for a set of query points (N of them)."""

    sq_dist: np.ndarray  # (N,) m^2
    face: np.ndarray  # (N,) int64
    bary: np.ndarray  # (N, 3) barycentric weights on the face
    feature: np.ndarray  # (N,) int8 FEATURE_* code


class _MeshDistance:
    """Exact signed distance from points to a closed triangle mesh with a (band, segment) layout.

    Culling uses a bounding-volume hierarchy over the layout: blocks of
    16 x 16 cells, then 4 x 4, then single cells (1 or 2 faces), each bounded
    by a cylinder along its mean normal. A block is opened only if its
    cylinder is nearer than a distance already achieved by some face. The
    cylinder never lies farther than any face inside it, so no face that
    could be closest is skipped: results are exact up to floating-point
    rounding (``tol.PROBE_SDF_PRUNE_SLACK_M`` keeps borderline blocks), not a
    nearest-candidates guess. Signs come from the angle-weighted
    pseudo-normal of the closest feature.

    For a regular grid, whole boxes of nodes are culled at once before the
    per-node search, with a reference point q on the surface (the closest
    point to the box centre): a block whose cylinder C satisfies
    ``|p - q| < dist(p, C)`` at the 8 corners of the box satisfies it in the
    whole box (the set of such p is an intersection of half-spaces, hence
    convex), so for every node in the box the face holding q beats every
    face in C and C can be skipped.
    """

    _BLOCKS = (16, 4, 1)
    #: nodes per side of the boxes culled together on a grid
    _GRID_BOX = 4
    #: for points off the grid: faces (nearest by centroid) whose exact distance seeds the search's bound
    _FIRST_K = 4

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, rows: np.ndarray, cols: np.ndarray):
        self.faces = faces
        self.tri = vertices[faces]
        self.packed = _pack_triangles(self.tri)
        self.pseudo = _pseudo_normals(vertices, faces)
        self.first_k = int(min(self._FIRST_K, len(faces)))
        self.tree = cKDTree(self.tri.mean(axis=1))
        self.levels: list[_Cylinders] = []
        self.children: list[np.ndarray] = []  # per level: (G, C) next-level groups (faces last), -1 padded
        member = []
        for s in self._BLOCKS:
            raw = (rows // s) * (cols.max() // s + 1) + cols // s
            _, gid = np.unique(raw, return_inverse=True)
            member.append(gid)
            self.levels.append(_group_cylinders(self.tri, gid))
        member.append(np.arange(len(faces)))
        for parent, child in zip(member[:-1], member[1:]):
            # blocks are nested, so each child group sits in exactly one parent
            n_child = child.max() + 1
            child_parent = np.empty(n_child, dtype=np.int64)
            child_parent[child] = parent
            order = np.argsort(child_parent, kind="stable")
            counts = np.bincount(child_parent, minlength=parent.max() + 1)
            table = np.full((len(counts), counts.max()), -1, dtype=np.int64)
            slot = np.arange(n_child) - np.repeat(np.cumsum(counts) - counts, counts)
            table[child_parent[order], slot] = order
            self.children.append(table)

    # ---------------------------------------------------------------- per point

    def _sq(self, points: np.ndarray, node: np.ndarray, face: np.ndarray) -> np.ndarray:
        return _chunked(lambda p, f: _sq_dist_packed(p, self.packed[f]), points[node], face)

    def _expand(self, level: int, owner: np.ndarray, group: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Replace (owner, group) pairs by (owner, child) pairs; pairs stay sorted by owner."""
        table = self.children[level]
        owner = np.repeat(owner, table.shape[1])
        group = table[group].reshape(-1)
        valid = group >= 0
        return owner[valid], group[valid]

    def _closest(self, points: np.ndarray, node: np.ndarray | None = None, group: np.ndarray | None = None,
                 level: int = 0) -> _Closest:
        """Exact closest points for points (N, 3).

        ``node``/``group`` optionally give the (point, group at ``level``)
        pairs to search, sorted by point; by default every point searches
        the whole hierarchy. The pairs must hold every group that could
        contain a closest face.
        """
        n = len(points)
        rows = np.arange(n)
        if node is None:
            # a distance every point achieves: the faces with the nearest centroids
            _, cand = self.tree.query(points, k=self.first_k)
            cand = cand.reshape(n, self.first_k)
            sq = self._sq(points, np.repeat(rows, self.first_k), cand.reshape(-1)).reshape(n, -1)
            arg = np.argmin(sq, axis=1)
            best_sq, best_face = sq[rows, arg], cand[rows, arg]
            n_top = len(self.levels[0].packed)
            node, group, level = np.repeat(rows, n_top), np.tile(np.arange(n_top), n), 0
            lower = None
        else:
            # a distance every point achieves: the faces of its group with the smallest lower bound
            # (cheaper than a k-d tree query, and almost always the closest face already)
            lower = self.levels[level].lower_bound(points[node], group)
            starts = np.flatnonzero(np.r_[True, node[1:] != node[:-1]])
            if len(starts) != n:
                raise ValueError("every point needs at least one (point, group) pair")
            seg = np.minimum.reduceat(lower, starts)
            hit = np.flatnonzero(lower == np.repeat(seg, np.diff(np.r_[starts, len(node)])))
            seed = hit[np.r_[True, node[hit][1:] != node[hit][:-1]]]
            seed_node, seed_group = node[seed], group[seed]
            for lev in range(level, len(self.levels)):
                seed_node, seed_group = self._expand(lev, seed_node, seed_group)
            sq = self._sq(points, seed_node, seed_group)
            starts = np.flatnonzero(np.r_[True, seed_node[1:] != seed_node[:-1]])
            best_sq = np.minimum.reduceat(sq, starts)
            hit = np.flatnonzero(sq == np.repeat(best_sq, np.diff(np.r_[starts, len(seed_node)])))
            best_face = seed_group[hit[np.r_[True, seed_node[hit][1:] != seed_node[hit][:-1]]]]
        bound = np.sqrt(best_sq) + tol.PROBE_SDF_PRUNE_SLACK_M

        for lev in range(level, len(self.levels)):
            if lower is None:
                lower = self.levels[lev].lower_bound(points[node], group)
            keep = lower <= bound[node]
            node, group = self._expand(lev, node[keep], group[keep])
            lower = None
        if len(node):
            sq = self._sq(points, node, group)
            # per-point minimum over the surviving faces (pairs are sorted by point)
            starts = np.flatnonzero(np.r_[True, node[1:] != node[:-1]])
            seg_min = np.minimum.reduceat(sq, starts)
            hit = np.flatnonzero(sq == np.repeat(seg_min, np.diff(np.r_[starts, len(node)])))
            win = hit[np.r_[True, node[hit][1:] != node[hit][:-1]]]
            owner = node[win]
            improve = sq[win] < best_sq[owner]
            best_sq[owner[improve]], best_face[owner[improve]] = sq[win][improve], group[win][improve]
        t = self.tri[best_face]
        sq, bary, feature = closest_points_on_triangles(points, t[:, 0], t[:, 1], t[:, 2])
        return _Closest(sq, best_face, bary, feature)

    def _sign(self, points: np.ndarray, c: _Closest) -> np.ndarray:
        """(N,) +1 outside, -1 inside, from the pseudo-normal of each closest feature."""
        closest = np.einsum("nk,nki->ni", c.bary, self.tri[c.face])
        normal = self.pseudo.face[c.face]
        for code, corner in ((FEATURE_VA, 0), (FEATURE_VB, 1), (FEATURE_VC, 2)):
            sel = c.feature == code
            normal[sel] = self.pseudo.vertex[self.faces[c.face[sel], corner]]
        for code, edge in ((FEATURE_EAB, 0), (FEATURE_EBC, 1), (FEATURE_ECA, 2)):
            sel = c.feature == code
            normal[sel] = self.pseudo.edge[c.face[sel], edge]
        return np.where(_dot(points - closest, normal) < 0, -1.0, 1.0)

    def signed(self, points: np.ndarray, chunk: int = 4096) -> np.ndarray:
        """(N,) float64 exact signed distance (negative inside) of points (N, 3), metres."""
        out = np.empty(len(points))
        for s in range(0, len(points), chunk):
            p = points[s : s + chunk]
            c = self._closest(p)
            out[s : s + chunk] = self._sign(p, c) * np.sqrt(c.sq_dist)
        return out

    # ---------------------------------------------------------------- grid

    def _keep_for_boxes(self, lev, box, group, corners, centre, radius, q) -> np.ndarray:
        """(P,) bool: may group ``group`` (at level ``lev``) hold a closest face for some point of ``box``?

        Args:
            lev: hierarchy level of the groups (len(levels) means single faces).
            box, group: (P,) int64 pairs.
            corners: (B, 8, 3) box corners; centre: (B, 3); radius: (B,) half-diagonals.
            q: (B, 3) a surface point per box (the closest point to its centre).
        """
        cyl = self.levels[lev]
        slack = tol.PROBE_SDF_PRUNE_SLACK_M
        # cheap test first: the whole ball around the centre is nearer q than the cylinder
        ref = np.linalg.norm(centre[box] - q[box], axis=-1)
        culled = ref + 2.0 * radius[box] < cyl.lower_bound(centre[box], group) - slack
        rest = np.flatnonzero(~culled)
        ok = np.ones(len(rest), dtype=bool)
        box_r, group_r = box[rest], group[rest]
        q_r = q[box_r]
        for k in range(8):
            pc = corners[box_r, k]
            ok &= np.linalg.norm(pc - q_r, axis=-1) < cyl.lower_bound(pc, group_r) - slack
        culled[rest] = ok
        return ~culled

    @staticmethod
    def _inherit(child_parent: np.ndarray, parent: np.ndarray, item: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Give every child the items of its parent.

        Args:
            child_parent: (C,) int64 parent of each child.
            parent, item: (P,) int64 (parent, item) pairs sorted by parent.

        Returns:
            (child, item) pairs sorted by child.
        """
        n_parent = int(max(child_parent.max(initial=-1), parent.max(initial=-1))) + 1
        counts = np.bincount(parent, minlength=n_parent)
        first = np.cumsum(counts) - counts
        per_child = counts[child_parent]
        child = np.repeat(np.arange(len(child_parent)), per_child)
        offset = np.arange(per_child.sum()) - np.repeat(np.cumsum(per_child) - per_child, per_child)
        return child, item[np.repeat(first[child_parent], per_child) + offset]

    def signed_grid(self, xs: np.ndarray, ys: np.ndarray, zs: np.ndarray) -> np.ndarray:
        """Exact signed distance at the nodes of a grid, for a mesh symmetric about x = 0 and y = 0.

        Boxes of 8^3 nodes are culled against the whole hierarchy, their 4^3
        sub-boxes against the cells their parent kept, and each node then
        searches the cells its 4^3 box kept.

        Args:
            xs: (2 i + 1,) float64 node x, metres, ``h * arange(-i, i + 1)``.
            ys: (2 j + 1,) float64 node y, metres, ``h * arange(-j, j + 1)``.
            zs: (nz,) float64 node z, metres.

        Returns:
            (len(xs), len(ys), nz) float64 signed distance, metres, negative inside.
        """
        # the mesh is exactly mirror-symmetric, so one quadrant of nodes is computed and mirrored
        cx, cy = len(xs) // 2, len(ys) // 2
        axes = (xs[cx:], ys[cy:], zs)
        shape = np.array([len(a) for a in axes])
        last = len(self.levels) - 1

        def pos(ijk: np.ndarray) -> np.ndarray:
            return np.stack([axes[a][ijk[..., a]] for a in range(3)], axis=-1)

        def boxes(size: int):
            grid = [np.arange(0, n, size) for n in shape]
            lo = np.stack(np.meshgrid(*grid, indexing="ij"), axis=-1).reshape(-1, 3)
            hi = np.minimum(lo + size - 1, shape - 1)
            p_lo, p_hi = pos(lo), pos(hi)
            corners = np.where(np.array(CORNER_BITS, dtype=bool)[None], p_hi[:, None], p_lo[:, None])
            return lo, (p_lo + p_hi) / 2, np.linalg.norm(p_hi - p_lo, axis=-1) / 2, corners

        def surface_point(points: np.ndarray, closest: _Closest) -> np.ndarray:
            return np.einsum("nk,nki->ni", closest.bary, self.tri[closest.face])

        # coarse boxes: the whole hierarchy
        big = 2 * self._GRID_BOX
        lo_b, centre_b, radius_b, corners_b = boxes(big)
        q_b = surface_point(centre_b, self._closest(centre_b))
        n_top = len(self.levels[0].packed)
        box = np.repeat(np.arange(len(centre_b)), n_top)
        group = np.tile(np.arange(n_top), len(centre_b))
        for lev in range(len(self.levels)):
            keep = self._keep_for_boxes(lev, box, group, corners_b, centre_b, radius_b, q_b)
            box, group = box[keep], group[keep]
            if lev < last:
                box, group = self._expand(lev, box, group)

        # fine boxes: the cells of their coarse box
        lo_s, centre_s, radius_s, corners_s = boxes(self._GRID_BOX)
        nb = -(-shape // big)
        coarse = lo_s // big
        parent = (coarse[:, 0] * nb[1] + coarse[:, 1]) * nb[2] + coarse[:, 2]
        box, group = self._inherit(parent, box, group)
        q_s = surface_point(centre_s, self._closest(centre_s, box, group, level=last))
        keep = self._keep_for_boxes(last, box, group, corners_s, centre_s, radius_s, q_s)
        box, group = box[keep], group[keep]

        # nodes: the cells of their fine box, a batch of boxes at a time to bound memory
        out = np.empty(tuple(shape))
        b = self._GRID_BOX
        local = np.stack(np.meshgrid(*[np.arange(b)] * 3, indexing="ij"), axis=-1).reshape(-1, 3)
        counts = np.bincount(box, minlength=len(lo_s))
        # small batches keep the temporaries in cache, which is worth 2-3x here
        batch_pairs = 1 << 17
        start = 0
        while start < len(lo_s):
            pairs_per_box = counts[start:] * len(local)
            stop = start + max(1, int(np.searchsorted(np.cumsum(pairs_per_box), batch_pairs)))
            stop = min(stop, len(lo_s))
            ijk = (lo_s[start:stop, None] + local[None]).reshape(-1, 3)
            node_box = np.repeat(np.arange(start, stop), len(local))
            inside = np.all(ijk < shape, axis=1)  # boxes at the far faces are partial
            ijk, node_box = ijk[inside], node_box[inside]
            pts = pos(ijk)
            sel = (box >= start) & (box < stop)
            node, cell = self._inherit(node_box - start, box[sel] - start, group[sel])
            closest = self._closest(pts, node, cell, level=last)
            out[ijk[:, 0], ijk[:, 1], ijk[:, 2]] = self._sign(pts, closest) * np.sqrt(closest.sq_dist)
            start = stop

        full = np.empty((len(xs), len(ys), len(zs)))
        full[cx:, cy:] = out
        full[:cx, cy:] = out[cx:0:-1]  # x = -i h mirrors x = +i h
        full[:, :cy] = full[:, 2 * cy : cy : -1]
        return full


# --------------------------------------------------------------------------- the probe


def _check_points(points: np.ndarray, name: str = "points_probe") -> np.ndarray:
    if isinstance(points, torch.Tensor):
        raise ValueError(f"{name} must be a numpy array; use signed_distance_torch for tensors")
    arr = np.asarray(points)
    if arr.dtype == object or not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)):
        raise ValueError(f"{name} must be a real array, got dtype {arr.dtype}")
    if arr.ndim < 1 or arr.shape[-1] != 3:
        raise ValueError(f"{name} must be (..., 3), got {tuple(arr.shape)}")
    arr = arr.astype(np.float64, copy=False)
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} contains NaN or inf")
    return arr


class Probe:
    """The procedural probe: mesh, lens faces, box corners, regions and signed distance.

    Build it with :func:`build_probe` (cached: the same spec gives the same
    object, so treat every attribute as read-only; copy the mesh before
    changing it).

    Attributes:
        spec: the :class:`ProbeSpec` it was built from.
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
            :mod:`datagen.keypoints`.
        region_z: :class:`RegionZ`, z ranges of lens, head, neck, handle and
            strain relief, metres, probe frame.
        sdf_grid: (nx, ny, nz) float64 exact signed distances (metres,
            negative inside) at the grid nodes ``sdf_origin + sdf_spacing *
            (i, j, k)``.
        sdf_origin: (3,) float64, metres, probe frame: the node (0, 0, 0).
        sdf_spacing: node spacing, metres.
    """

    def __init__(self, spec: ProbeSpec, mesh: trimesh.Trimesh, lens_face_mask: np.ndarray,
                 marker_face_mask: np.ndarray, region_z: RegionZ, distance: _MeshDistance,
                 sdf_axes: tuple[np.ndarray, np.ndarray, np.ndarray], sdf_grid: np.ndarray):
        self.spec = spec
        self.mesh = mesh
        self.lens_face_mask = lens_face_mask
        self.marker_face_mask = marker_face_mask
        self.region_z = region_z
        bounds = np.asarray(mesh.bounds, dtype=np.float64)  # (2, 3) min, max
        self.corners_probe = np.array([[bounds[b, axis] for axis, b in enumerate(bits)] for bits in CORNER_BITS])
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

        Raises:
            ValueError: wrong shape, non-real dtype, NaN or inf.
        """
        p = _check_points(points_probe)
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

        Raises:
            ValueError: wrong shape, non-real dtype, NaN or inf.
        """
        p = _check_points(points_probe)
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
        p = _check_points(points_probe)
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

        Raises:
            ValueError: not a floating tensor, wrong shape, NaN or inf.
        """
        if not isinstance(points_probe, torch.Tensor):
            raise ValueError(f"points_probe must be a torch.Tensor, got {type(points_probe).__name__}")
        if points_probe.dtype not in (torch.float32, torch.float64):
            raise ValueError(f"points_probe must be float32 or float64, got {points_probe.dtype}")
        if points_probe.ndim < 1 or points_probe.shape[-1] != 3:
            raise ValueError(f"points_probe must be (..., 3), got {tuple(points_probe.shape)}")
        if not bool(torch.isfinite(points_probe).all()):
            raise ValueError("points_probe contains NaN or inf")
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
    rings, n_lens = _build_rings(spec)
    n_rings, m, _ = rings.shape
    vertices = np.concatenate([[[0.0, 0.0, 0.0]], rings.reshape(-1, 3), [[0.0, 0.0, spec.length]]])
    faces, rows, cols = _ring_faces(n_rings, m)
    # the apex fan and the bands between lens rings: faces come bottom-up, band by band
    lens = np.zeros(len(faces), dtype=bool)
    lens[: m + 2 * m * (n_lens - 1)] = True
    lens_top = float(_lens_sag(spec.head_width / 2 - spec.lens_edge_radius, spec.lens_radius))
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
    distance = _MeshDistance(vertices, faces, rows, cols)
    axes = _sdf_axes(spec, np.stack([vertices.min(axis=0), vertices.max(axis=0)]))
    grid = distance.signed_grid(*axes)
    marker = np.zeros(len(faces), dtype=bool)
    if spec.marker_height > 0:
        marked = _add_marker(spec, vertices, faces, rows, cols, lens, n_rings)
        vertices, faces, lens, marker = marked.vertices, marked.faces, marked.lens, marked.marker
        distance = _MeshDistance(vertices, faces, marked.rows, marked.cols)
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
        TypeError: ``spec`` is not a :class:`ProbeSpec`.
        ValueError: the spec gives a self-folding surface.
    """
    if not isinstance(spec, ProbeSpec):
        raise TypeError(f"spec must be a ProbeSpec, got {type(spec).__name__}")
    return _build_probe_cached(spec)
