"""The shape of the procedural probe: its spec, regions and the swept surface mesh.

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
towards the neck. The orientation marker is moulded in by
:mod:`hupbench.datagen.assets.probe_marker`; :mod:`hupbench.datagen.assets.probe` assembles the probe.

Convention:
    Metres. Probe frame: origin at the lens apex (the centre of the curved
    acoustic face, the point that touches the patient); +z along the long
    axis from the lens towards the cable end; +x along the transducer array
    (the 72 mm head width); +y across the head (the 22 mm head thickness);
    right-handed.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import NamedTuple

import numpy as np
from scipy.interpolate import PchipInterpolator

from hupbench.core import tolerances as tol
from hupbench.core.input_checks import check_int, check_number
from hupbench.core.errors import BadValueError


# --------------------------------------------------------------------------- spec


#: the ProbeSpec sizes that may be zero (metres); every other size and count is positive
_MAY_BE_ZERO = ("sdf_margin", "marker_height", "handle_flare")


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
    (``hupbench.datagen.render.scene.PROBE_MARKER_RGB`` and ``PROBE_MARKER_EMISSIVE``), and
    labelled probe (3) in the segmentation. It makes the probe no longer
    symmetric under the half turn about its long axis (x, y) -> (-x, -y),
    which otherwise maps the picture onto itself and swaps the 8 box corners
    in pairs, so the corner labels can be read from the image.

    Why this size and place: real marks are 2-5 mm ridges, dots or lights; this one is larger so
    that the models' 128 px input sees it, wraps round the end's edges so that views of the head's
    broad faces see it too, and sits on the shoulder, where the pad stays inside the box of the sweep
    (outermost point x = 34.4 mm, y = 9.3 mm of the box's 36 and 15 mm) and the 8 box corners
    (keypoints 21-28) do not move (the build refuses a spec whose marker leaves the box). Fingers of
    the grasps rest on the neck and the handle, above it. How often it shows: docs/rendering.md.

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
            value, name = getattr(self, f.name), f"ProbeSpec.{f.name}"
            if f.type in ("int", int):
                check_int(value, name, 1)
            else:  # metres: positive, but for the three that may be zero
                check_number(value, name, 0, low_open=f.name not in _MAY_BE_ZERO)
        if self.n_around % 4 or self.n_around < 16:
            raise BadValueError(f"ProbeSpec.n_around must be a multiple of 4 and >= 16, got {self.n_around}")
        if self.n_lens_rings < 2 or self.n_fillet_rings < 2 or self.n_body_rings < 8 or self.n_cap_rings < 2:
            raise BadValueError(
                "ProbeSpec ring counts too small: need n_lens_rings >= 2, n_fillet_rings >= 2, "
                f"n_body_rings >= 8, n_cap_rings >= 2, got {self.n_lens_rings}, {self.n_fillet_rings}, "
                f"{self.n_body_rings}, {self.n_cap_rings}"
            )
        if min(self.marker_length, self.marker_width) <= 2 * self.marker_edge:
            raise BadValueError(
                f"ProbeSpec marker footprint must have marker_length and marker_width > 2 * marker_edge, got "
                f"length {self.marker_length}, width {self.marker_width}, edge {self.marker_edge}"
            )
        r = self.lens_edge_radius
        if r >= _HEAD_CORNER * self.head_thickness / 2:
            raise BadValueError(
                f"ProbeSpec.lens_edge_radius ({r}) must be less than the head's corner radius "
                f"({_HEAD_CORNER} * head_thickness / 2 = {_HEAD_CORNER * self.head_thickness / 2})"
            )
        if self.lens_radius <= self.head_width / 2:
            raise BadValueError(
                f"ProbeSpec.lens_radius ({self.lens_radius}) must exceed half the head width "
                f"({self.head_width / 2}): the lens arc must span the head"
            )
        if self.neck_width > min(self.head_width, self.handle_width + self.handle_flare):
            raise BadValueError(
                f"ProbeSpec.neck_width ({self.neck_width}) must not exceed the head width or the handle width"
            )
        if self.neck_thickness > self.handle_thickness:
            raise BadValueError(
                f"ProbeSpec.neck_thickness ({self.neck_thickness}) must not exceed the handle thickness "
                f"({self.handle_thickness})"
            )
        lens_edge_top = float(lens_sag(self.head_width / 2, self.lens_radius)) + r
        if self.head_height <= lens_edge_top:
            raise BadValueError(
                f"ProbeSpec.head_height ({self.head_height}) is too small: it must exceed the height of the "
                f"lens edge (lens sagitta over the head width plus lens_edge_radius = {lens_edge_top:.4f})"
            )
        root = self.strain_relief_diameter / 2
        fillet = _boot_fillet(self)
        shoulder_in = (min(self.handle_width, self.handle_thickness) + self.handle_flare) / 2 - self.handle_end_radius
        if root + fillet >= shoulder_in:
            raise BadValueError(
                f"ProbeSpec.strain_relief_diameter ({self.strain_relief_diameter}) and handle_end_radius "
                f"({self.handle_end_radius}) leave no flat end face on the handle "
                f"(handle {self.handle_width} x {self.handle_thickness})"
            )
        handle_end = self.length - self.strain_relief_length
        handle_start = self.head_height + self.neck_length
        if handle_end - handle_start < 4 * self.handle_end_radius:
            raise BadValueError(
                f"ProbeSpec.length ({self.length}) leaves no handle: head_height + neck_length = "
                f"{handle_start}, handle end at length - strain_relief_length = {handle_end}"
            )
        if self.strain_relief_length < fillet + 0.85 * root + 1e-3:
            raise BadValueError(
                f"ProbeSpec.strain_relief_length ({self.strain_relief_length}) is too short for its "
                f"diameter ({self.strain_relief_diameter})"
            )


def lens_sag(x: np.ndarray | float, lens_radius: float) -> np.ndarray:
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


def smoothstep(t: np.ndarray) -> np.ndarray:
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


def build_rings(spec: ProbeSpec) -> _Rings:
    """Ring vertices from the lens apex to the cable end (poles excluded)."""
    m = spec.n_around
    R = spec.lens_radius
    r = spec.lens_edge_radius
    A, B = spec.head_width / 2, spec.head_thickness / 2
    shear_full = r + _HEAD_STRAIGHT_FRACTION * (spec.head_height - r)

    def shear(zc: float) -> float:
        return float(1.0 - smoothstep((zc - shear_full) / (spec.head_height - shear_full)))

    rings = []
    # lens cap: scaled copies of its outline (the head's section shrunk by the
    # edge radius), lying on the lens cylinder
    c = _HEAD_CORNER * B
    outline = _rounded_rect_ring(A - r, B - r, c - r, m)
    for rho in np.arange(1, spec.n_lens_rings + 1) / spec.n_lens_rings:
        xy = rho * outline
        rings.append(np.column_stack([xy, lens_sag(xy[:, 0], R)]))
    # edge fillet: a quarter round in the sheared frame, tangent to lens and
    # housing; offsets of a rounded rectangle are rounded rectangles
    for phi in np.arange(1, spec.n_fillet_rings + 1) * (np.pi / 2 / spec.n_fillet_rings):
        grow = r * np.sin(phi) if phi < np.pi / 2 else r
        xy = _rounded_rect_ring(A - r + grow, B - r + grow, c - r + grow, m)
        zc = r * (1.0 - np.cos(phi))
        rings.append(np.column_stack([xy, zc + shear(zc) * lens_sag(xy[:, 0], R)]))
    # body, up to the end of the strain relief
    mer = _resample_meridian(_body_meridian(spec), spec.n_body_rings)
    for zc, a, b, corner in zip(*mer):
        xy = _rounded_rect_ring(a, b, corner * min(a, b), m)
        rings.append(np.column_stack([xy, zc + shear(zc) * lens_sag(xy[:, 0], R)]))
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
        raise BadValueError(
            f"ProbeSpec gives a self-folding surface between rings {k} and {k + 1} "
            f"(z about {1e3 * rings[k, :, 2].mean():.1f} mm); make the head taller or the tapers gentler"
        )
    return _Rings(rings, spec.n_lens_rings)


def ring_faces(n_rings: int, m: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
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
