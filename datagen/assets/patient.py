"""The patient under the probe: a late-pregnancy abdomen, its signed distance, its mesh and its placement.

The body is a torso (an ellipsoid lying on a bed) with the gravid abdomen on it, a sphere of radius R
whose cap rises above the torso, joined by a smooth union (Quilez, "smooth minimum",
https://iquilezles.org/articles/smin/). The probe's lens rests on the sphere's cap, where the skin's
radius of curvature is exactly R.

Why R in 15-25 cm: the symphysis-fundal height, the arc over the uterus from the pubic symphysis to the
fundus, is about 30-36 cm in the last ten weeks of pregnancy (INTERGROWTH-21st standards, Papageorghiou
et al., "International standards for symphysis-fundal height based on serial measurements from the
Fetal Growth Longitudinal Study of the INTERGROWTH-21st Project", BMJ 2016;355:i5662). The supine
anterior abdomen spans some 90-120 degrees of arc between those two points, so an arc of 30-36 cm over
90-120 degrees has a radius of 0.30 / (2 pi / 3) = 0.14 m to 0.36 / (pi / 2) = 0.23 m; an abdominal
girth of about 1 m at term, a circle of radius 0.16 m, flattened at the front, agrees.

Convention:
    Metres. Body frame: origin on the bed's top surface under the abdomen; +z up, away from the bed
    (the room's vertical, where a sonographer's head is); +x from the head towards the feet; +y to the
    patient's left. World = the probe frame of :mod:`hupbench.datagen.assets.probe` (origin at the
    lens apex, +z from the lens towards the cable); ``T_world_body`` maps body points into it. Signed
    distances are NEGATIVE INSIDE the body, as for the probe.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import trimesh

from hupbench.core.input_checks import check_int, check_interval, check_number

__all__ = ["PLACEMENT_FIELDS", "PatientPlacement", "PatientSpec", "below_skin", "body_mesh", "body_sdf", "body_sdf_local",
           "place_patient",
           "placement_arrays", "placement_from_arrays", "SKIN_RGB", "skin_rgb", "sphere_centre"]

#: the radii a config may ask for: below 0.1 m the bump is no longer star-shaped from the body's core
#: (its mesh, :func:`body_mesh`, is cast from there); above 0.5 m it overhangs the bed
RADIUS_LIMITS_M = (0.1, 0.5)
#: torso ellipsoid semi-axes (x, y, z), metres: half of a supine adult woman's trunk length from pubis to
#: chest, of her hip breadth (about 0.37 m at the 50th percentile: Pheasant & Haslegrave, Bodyspace,
#: 3rd ed., 2006) and of a non-pregnant abdominal depth (about 0.24 m)
TORSO_SEMI_AXES_M = np.array([0.38, 0.19, 0.12])
#: torso centre in the body frame: 2 cm towards the head from the abdomen, sunk 1 cm into the mattress
TORSO_CENTRE_M = np.array([-0.02, 0.0, 0.11])
#: height of the abdomen's apex above the bed: a term abdomen's supine anterior-posterior depth
APEX_HEIGHT_M = 0.30
#: width of the smooth union between the abdomen's sphere and the torso, metres
BLEND_M = 0.04
#: the mesh's rays start here (inside the torso and every allowed sphere); the body is star-shaped from it
MESH_ORIGIN_M = np.array([-0.02, 0.0, 0.14])
#: icosphere subdivisions of the mesh: 5,120 triangles
MESH_SUBDIVISIONS = 4
#: rounds of evening out the mesh's triangles (:func:`_body_mesh_local`)
MESH_RELAX_ROUNDS = 15
#: the contact lies on the cap within this angle of the abdomen's apex, so its skin normal is within this
#: angle of the vertical and it stays clear of the union with the torso
CONTACT_MAX_POLAR_DEG = 40.0
#: the deepest any probe point may sink into the skin, metres
PROBE_MAX_DEPTH_M = 0.002
#: the deepest a hand or forearm vertex may be inside the body or below the bed's top by default, metres
MAX_PENETRATION_M = 0.003


@dataclass(frozen=True)
class PatientSpec:
    """The patient under the probe (config node ``patient`` of ``hupbench grasps +subjects=clinic``,
    conf/subjects/clinic.yaml).

    Attributes:
        radius_m: (low, high) metres, the range the abdomen's radius of curvature is drawn from, uniformly,
            per placement (see the module docstring for 0.15-0.25 m).
        max_tilt_deg: degrees, the largest angle between the probe's long axis and the skin normal.
        press_m: metres, how deep the deepest lens point sits in the skin (lens-skin contact).
        max_penetration_m: metres, the deepest any hand or forearm vertex may be inside the body or below
            the bed's top.
        attempts: placements drawn before :func:`place_patient` gives up on a grasp.
    """

    radius_m: Sequence[float] = (0.15, 0.25)
    max_tilt_deg: float = 15.0
    press_m: float = 0.0005
    max_penetration_m: float = MAX_PENETRATION_M
    attempts: int = 16

    def __post_init__(self) -> None:
        object.__setattr__(self, "radius_m", check_interval(self.radius_m, "radius_m", *RADIUS_LIMITS_M,
                                                           unit="m"))
        object.__setattr__(self, "max_tilt_deg", check_number(self.max_tilt_deg, "max_tilt_deg", 0, 45))
        object.__setattr__(self, "press_m", check_number(self.press_m, "press_m", 0, PROBE_MAX_DEPTH_M))
        object.__setattr__(self, "max_penetration_m",
                           check_number(self.max_penetration_m, "max_penetration_m", 0, 0.01))
        object.__setattr__(self, "attempts", check_int(self.attempts, "attempts", 1, 1000))


@dataclass(frozen=True)
class PatientPlacement:
    """Where the patient lies for one grasp; plain numpy, stored in a grasps file (:func:`placement_arrays`).

    Attributes:
        T_world_body: (4, 4) float64, the body frame in the world (probe) frame, metres.
        radius_m: float, the abdomen's radius of curvature.
        vertical_world: (3,) float64 unit, the room's up (the bed's outward normal) in the world frame.
        normal_world: (3,) float64 unit, the skin's outward normal at the contact, world frame.
        lens_skin_m: float, the signed distance of the deepest lens vertex (negative: pressed into the skin).
        penetration_m: float >= 0, the deepest hand or forearm vertex inside the body or below the bed top.
    """

    T_world_body: np.ndarray
    radius_m: float
    vertical_world: np.ndarray
    normal_world: np.ndarray
    lens_skin_m: float
    penetration_m: float

    def to_body(self, points_world: np.ndarray) -> np.ndarray:
        """(..., 3) float64 world points (metres) in the body frame."""
        T = self.T_world_body
        return (np.asarray(points_world, dtype=np.float64) - T[:3, 3]) @ T[:3, :3]


def moved_placement(placement: PatientPlacement, T_world_body: np.ndarray) -> PatientPlacement:
    """``placement`` with the body moved to the pose ``T_world_body`` ((4, 4), world frame; a clip's frame): its
    vertical and contact normal turned with it."""
    T = np.asarray(T_world_body, dtype=np.float64)
    R = T[:3, :3] @ placement.T_world_body[:3, :3].T  # the body's turn since the placement's pose, world frame
    return dataclasses.replace(placement, T_world_body=T, vertical_world=R @ placement.vertical_world,
                               normal_world=R @ placement.normal_world)


# --------------------------------------------------------------------------- the body's shape


def sphere_centre(radius_m: float) -> np.ndarray:
    """(3,) the abdomen sphere's centre in the body frame: its apex at ``APEX_HEIGHT_M`` above the bed."""
    return np.array([0.0, 0.0, APEX_HEIGHT_M - radius_m])


def _ellipsoid_sdf(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Approximate signed distance to the torso ellipsoid and its gradient.

    Quilez's bound ``k0 (k0 - 1) / k1`` (https://iquilezles.org/articles/ellipsoids/): zero on the
    surface with a unit gradient there, so it errs by O(d^2 / r) at a distance d from it.

    Returns:
        (N,) metres and (N, 3) its gradient.
    """
    q = points - TORSO_CENTRE_M
    u, v = q / TORSO_SEMI_AXES_M, q / TORSO_SEMI_AXES_M ** 2
    k0 = np.maximum(np.linalg.norm(u, axis=-1), 1e-12)[:, None]
    k1 = np.maximum(np.linalg.norm(v, axis=-1), 1e-12)[:, None]
    gradient = ((2.0 * k0 - 1.0) * k1 * v / k0 - k0 * (k0 - 1.0) * (v / TORSO_SEMI_AXES_M ** 2) / k1) / k1 ** 2
    return (k0 * (k0 - 1.0) / k1)[:, 0], gradient


def body_sdf_local(radius_m: float, points_body: np.ndarray) -> np.ndarray:
    """Signed distance to the body in its own frame.

    The smooth union ``f = h s + (1 - h) t - k h (1 - h)`` of the sphere's distance s and the torso's t
    (Quilez's polynomial smooth minimum, width k = ``BLEND_M``) has the gradient ``h grad s + (1 - h)
    grad t`` but not a unit one where the two meet; ``f / |grad f|`` is its distance to first order
    there too.

    Args:
        radius_m: the abdomen's radius of curvature, metres.
        points_body: (N, 3) float64, metres, body frame.

    Returns:
        (N,) float64, metres, negative inside. Exact on and around the abdomen's cap (where the torso is
        more than ``BLEND_M`` farther than the sphere); elsewhere first-order accurate near the surface.
    """
    to_centre = points_body - sphere_centre(radius_m)
    length = np.maximum(np.linalg.norm(to_centre, axis=-1), 1e-12)
    sphere, sphere_gradient = length - radius_m, to_centre / length[:, None]
    torso, torso_gradient = _ellipsoid_sdf(points_body)
    h = np.clip(0.5 + 0.5 * (torso - sphere) / BLEND_M, 0.0, 1.0)
    union = h * sphere + (1.0 - h) * torso - BLEND_M * h * (1.0 - h)
    gradient = h[:, None] * sphere_gradient + (1.0 - h)[:, None] * torso_gradient
    return union / np.maximum(np.linalg.norm(gradient, axis=-1), 1e-12)


def below_skin(radius_m: float, points_body: np.ndarray) -> np.ndarray:
    """How deep points lie inside the body or below the bed's top (the body frame's z = 0), metres.

    Args:
        radius_m: the abdomen's radius of curvature, metres.
        points_body: (..., 3) float64, metres, body frame.

    Returns:
        (...) float64: the larger of the depth inside the body and below the bed; negative where a point is
        clear of both.
    """
    points = np.asarray(points_body, dtype=np.float64)
    flat = points.reshape(-1, 3)
    return np.maximum(-body_sdf_local(radius_m, flat), -flat[:, 2]).reshape(points.shape[:-1])


def body_sdf(placement: PatientPlacement, points_world: np.ndarray) -> np.ndarray:
    """Signed distance to the placed body.

    Args:
        placement: where the body lies.
        points_world: (N, 3) float64, metres, world frame.

    Returns:
        (N,) float64, metres, negative inside (see :func:`body_sdf_local`).
    """
    return body_sdf_local(placement.radius_m, placement.to_body(points_world))


def _cast(radius_m: float, directions: np.ndarray) -> np.ndarray:
    """(N, 3) where the rays from ``MESH_ORIGIN_M`` along (N, 3) unit ``directions`` leave the body.

    Bisection to 2 m / 2^36 = 0.03 um: the points lie on the zero level of :func:`body_sdf_local`.
    """
    inner, outer = np.zeros(len(directions)), np.full(len(directions), 2.0)
    for _ in range(36):
        middle = 0.5 * (inner + outer)
        inside = body_sdf_local(radius_m, MESH_ORIGIN_M + middle[:, None] * directions) < 0
        inner, outer = np.where(inside, middle, inner), np.where(inside, outer, middle)
    return MESH_ORIGIN_M + (0.5 * (inner + outer))[:, None] * directions


@functools.lru_cache(maxsize=64)
def _body_mesh_local(radius_m: float) -> trimesh.Trimesh:
    """The body's mesh in its own frame: an icosphere cast onto the zero level from ``MESH_ORIGIN_M``.

    Casting alone stretches the triangles where the surface turns away from the rays (the abdomen's
    flanks); a few rounds of moving each vertex to its neighbours' mean and casting it back even out
    the edge lengths (umbrella-operator smoothing, Taubin, "A signal processing approach to fair surface
    design", SIGGRAPH 1995), so that the flat triangles stay within 1 mm of the skin above the bed.
    """
    assert (body_sdf_local(radius_m, MESH_ORIGIN_M[None]) < 0).all()
    sphere = trimesh.creation.icosphere(subdivisions=MESH_SUBDIVISIONS)
    edges = sphere.edges_unique
    degree = np.bincount(edges.ravel(), minlength=len(sphere.vertices)).astype(np.float64)
    # stretched by the torso's axes, the unit directions start near evenly spread over its flat surface
    directions = sphere.vertices * TORSO_SEMI_AXES_M
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    for _ in range(MESH_RELAX_ROUNDS + 1):
        vertices = _cast(radius_m, directions)
        mean = np.zeros_like(vertices)
        np.add.at(mean, edges[:, 0], vertices[edges[:, 1]])
        np.add.at(mean, edges[:, 1], vertices[edges[:, 0]])
        directions = mean / degree[:, None] - MESH_ORIGIN_M
        directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    mesh = trimesh.Trimesh(vertices, sphere.faces, process=False)
    assert mesh.is_watertight and mesh.volume > 0
    return mesh


def body_mesh(placement: PatientPlacement) -> trimesh.Trimesh:
    """The placed body's surface: watertight, outward-wound, 5,120 triangles, world frame, metres.

    Its vertices lie on the zero level of :func:`body_sdf`; its flat triangles cut under the curved skin
    by (edge length)^2 / (8 R): under 1 mm above the bed (0.5-1 mm on the abdomen's cap, with R from 0.25
    to 0.1 m).
    """
    mesh = _body_mesh_local(float(placement.radius_m)).copy()
    mesh.apply_transform(placement.T_world_body)
    return mesh


# --------------------------------------------------------------------------- skin tones

#: the ten sRGB colours of the Monk Skin Tone scale (Monk, "The Monk Skin Tone Scale", 2023,
#: https://skintone.google/the-scale; published as hex #f6ede4 ... #292420), in [0, 1]
SKIN_RGB = tuple(tuple(int(code[i:i + 2], 16) / 255.0 for i in (0, 2, 4)) for code in (
    "f6ede4", "f3e7db", "f7ead0", "eadaba", "d7bd96", "a07e56", "825c43", "604134", "3a312a", "292420"))


def skin_rgb(index: int) -> tuple[float, float, float]:
    """(3,) sRGB in [0, 1]: Monk skin tone ``index % 10`` (0 the lightest, 9 the darkest)."""
    return SKIN_RGB[index % len(SKIN_RGB)]


# --------------------------------------------------------------------------- placement


def _frame(normal: np.ndarray, spin: float) -> np.ndarray:
    """(3, 3) a right-handed orthonormal frame whose third column is ``normal``, turned by ``spin`` about it."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(normal[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(normal, helper)
    u /= np.linalg.norm(u)
    v = np.cross(normal, u)
    c, s = math.cos(spin), math.sin(spin)
    return np.column_stack([c * u + s * v, -s * u + c * v, normal])


def _cap_direction(rng: np.random.Generator, max_polar_rad: float) -> np.ndarray:
    """(3,) a unit vector drawn uniformly over the cap within ``max_polar_rad`` of +z."""
    cos_polar = rng.uniform(math.cos(max_polar_rad), 1.0)
    azimuth = rng.uniform(0.0, 2.0 * math.pi)
    sin_polar = math.sqrt(max(0.0, 1.0 - cos_polar ** 2))
    return np.array([sin_polar * math.cos(azimuth), sin_polar * math.sin(azimuth), cos_polar])


def _draw_pose(spec: PatientSpec, rng: np.random.Generator) -> tuple[float, np.ndarray, np.ndarray]:
    """One draw of the radius, the body's rotation and the body-frame contact point.

    Returns:
        radius_m; R_world_body (3, 3); contact_body (3,) metres, on the abdomen's cap.
    """
    radius = rng.uniform(*spec.radius_m)
    normal_body = _cap_direction(rng, math.radians(CONTACT_MAX_POLAR_DEG))
    normal_world = _cap_direction(rng, math.radians(spec.max_tilt_deg))  # the skin's outward normal: +z tilted
    R_world_body = _frame(normal_world, rng.uniform(0.0, 2.0 * math.pi)) @ _frame(normal_body, 0.0).T
    return radius, R_world_body, sphere_centre(radius) + radius * normal_body


def _pressed(radius: float, R_world_body: np.ndarray, contact_body: np.ndarray, lens_world: np.ndarray,
             press_m: float) -> np.ndarray:
    """(4, 4) T_world_body that puts the deepest lens vertex ``press_m`` inside the skin.

    The body starts with its contact point on the lens apex and moves along the contact's normal; a
    step of s changes the lens's signed distances by about -s there, so a few Newton steps converge.
    """
    normal_world = R_world_body @ (contact_body - sphere_centre(radius)) / radius
    T = np.eye(4)
    T[:3, :3] = R_world_body
    T[:3, 3] = -R_world_body @ contact_body
    for _ in range(50):
        error = body_sdf_local(radius, (lens_world - T[:3, 3]) @ R_world_body).min() + press_m
        if abs(error) < 1e-9:
            break
        T[:3, 3] += error * normal_world
    return T


def place_patient(spec: PatientSpec, probe, hand_vertices_world: np.ndarray, arm_vertices_world: np.ndarray,
                  rng: np.random.Generator) -> PatientPlacement | None:
    """Lay the patient under a grasp's probe, with the lens pressed into the skin of the abdomen.

    Each attempt draws the radius R uniformly in ``spec.radius_m``, the skin's outward normal within
    ``spec.max_tilt_deg`` of the probe's +z axis (uniform over that cap), the contact on the abdomen's cap
    within ``CONTACT_MAX_POLAR_DEG`` of its apex (so the room's vertical is that close to the skin normal)
    and a spin of the body about the normal; then moves the body along the normal until the deepest lens
    vertex is ``spec.press_m`` inside. An attempt is kept when no probe vertex is deeper than
    ``PROBE_MAX_DEPTH_M`` and no hand or forearm vertex is more than ``spec.max_penetration_m`` inside the
    body or below the bed's top.

    Args:
        spec: the patient config.
        probe: the :class:`hupbench.datagen.assets.probe.Probe` the hand holds, at the world origin.
        hand_vertices_world: (V, 3) float64, metres, world frame, the posed hand mesh's vertices.
        arm_vertices_world: (A, 3) float64, metres, world frame, the forearm mesh's vertices.
        rng: the seeded generator the draws come from.

    Returns:
        The first kept placement, or None when ``spec.attempts`` attempts all failed.
    """
    vertices = np.asarray(probe.mesh.vertices, dtype=np.float64)
    lens_world = vertices[np.unique(probe.mesh.faces[probe.lens_face_mask])]
    body_parts = np.concatenate([hand_vertices_world, arm_vertices_world]).astype(np.float64)
    for _ in range(spec.attempts):
        radius, R_world_body, contact_body = _draw_pose(spec, rng)
        T = _pressed(radius, R_world_body, contact_body, lens_world, spec.press_m)
        if body_sdf_local(radius, (vertices - T[:3, 3]) @ R_world_body).min() < -PROBE_MAX_DEPTH_M:
            continue
        penetration = float(below_skin(radius, (body_parts - T[:3, 3]) @ R_world_body).max(initial=0.0))
        if penetration <= spec.max_penetration_m:
            lens_skin = float(body_sdf_local(radius, (lens_world - T[:3, 3]) @ R_world_body).min())
            normal_world = R_world_body @ (contact_body - sphere_centre(radius)) / radius
            return PatientPlacement(T, radius, R_world_body[:, 2].copy(), normal_world, lens_skin, penetration)
    return None


#: the grasps-file fields of a placement, each (G, ...) over the grasps
PLACEMENT_FIELDS = {"patient_T_world_body": "T_world_body", "patient_radius_m": "radius_m",
                    "patient_vertical_world": "vertical_world", "patient_normal_world": "normal_world",
                    "patient_lens_skin_m": "lens_skin_m", "patient_penetration_m": "penetration_m"}


def placement_arrays(placements: Sequence[PatientPlacement]) -> dict[str, np.ndarray]:
    """The placements of G grasps as grasps-file arrays.

    Returns:
        ``patient_T_world_body`` (G, 4, 4), ``patient_radius_m`` (G,), ``patient_vertical_world`` (G, 3),
        ``patient_normal_world`` (G, 3), ``patient_lens_skin_m`` (G,), ``patient_penetration_m`` (G,);
        float64, metres, world frame.
    """
    return {key: np.array([getattr(p, name) for p in placements], dtype=np.float64).reshape(
        (len(placements),) + np.shape(getattr(placements[0], name)) if placements else (0,))
        for key, name in PLACEMENT_FIELDS.items()}


def placement_from_arrays(arrays: dict[str, np.ndarray], i: int) -> PatientPlacement:
    """Grasp ``i``'s placement from the arrays of :func:`placement_arrays` (a read grasps file)."""
    values = {name: np.array(arrays[key][i], dtype=np.float64) for key, name in PLACEMENT_FIELDS.items()}
    for name in ("radius_m", "lens_skin_m", "penetration_m"):
        values[name] = float(values[name])
    return PatientPlacement(**values)
