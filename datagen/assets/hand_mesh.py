"""The hand's rest mesh: implicit surface -> marching cubes -> decimation -> skin weights.

Capsules along the bones and a rounded palm slab, blended by smooth minimum, meshed by marching
cubes on a narrow band, decimated to under 8k triangles, and skinned by linear blend skinning with
compact blend zones at the joints.

Convention:
    Metres, hand frame of the rest pose (see :mod:`hupbench.datagen.assets.hand_anatomy`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hupbench.core import keypoints as kp
from hupbench.datagen.assets.hand_anatomy import (
    FINGER_RADII_MM,
    MM,
    NUM_JOINTS,
    THUMB_RADII_MM,
    HandSpec,
    child_of_joint,
    rest_skeleton,
    unit_vector,
)

def segment_distance(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distance from points (N, 3) to segment ab, and the segment parameter t in [0, 1]."""
    ab = b - a
    t = np.clip((points - a) @ ab / max(ab @ ab, 1e-18), 0.0, 1.0)
    return np.linalg.norm(points - (a + t[:, None] * ab), axis=1), t


def _smin(a: np.ndarray, b: np.ndarray, k: float) -> np.ndarray:
    """Polynomial smooth minimum: blends surfaces within ~k of each other."""
    h = np.clip(0.5 + 0.5 * (b - a) / k, 0.0, 1.0)
    return b * (1 - h) + a * h - k * h * (1.0 - h)


def _polygon_sdf_2d(points: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """Signed distance (negative inside) from (N, 2) points to a convex CCW polygon (M, 2)."""
    d = np.full(len(points), np.inf)
    inside = np.ones(len(points), dtype=bool)
    for i in range(len(polygon)):
        a, b = polygon[i], polygon[(i + 1) % len(polygon)]
        e = b - a
        w = points - a
        t = np.clip(w @ e / (e @ e), 0.0, 1.0)
        d = np.minimum(d, np.linalg.norm(w - t[:, None] * e, axis=1))
        inside &= (e[0] * w[:, 1] - e[1] * w[:, 0]) >= 0
    return np.where(inside, -d, d)


@dataclass
class _Primitive:
    bone: int  # MANO joint whose transform moves it
    sdf: callable


def _primitives(spec: HandSpec) -> list[_Primitive]:
    """Implicit pieces of the rest hand, each tied to the joint that moves it.

    The palm's and wrist's table points (mm) stretch with the spec's proportions: x with ``palm``, y with
    ``thickness``, z with ``breadth``; radii and the slab's thickness with ``thickness``.
    """
    s = spec.scale * MM
    t = spec.thickness

    def at(x, y, z):
        return np.array([x * spec.palm, y * t, z * spec.breadth]) * s
    joints, tips = rest_skeleton(spec)
    prims: list[_Primitive] = []

    def capsule(a, b, r, bone):
        prims.append(_Primitive(bone, lambda p, a=a, b=b, r=r: segment_distance(p, a, b)[0] - r))

    for i, finger in enumerate(kp.MANO_FINGER_ORDER):
        j0 = 1 + 3 * i
        chain = [joints[j0], joints[j0 + 1], joints[j0 + 2], tips[i]]
        radii = np.array(THUMB_RADII_MM if finger == "thumb" else FINGER_RADII_MM[finger]) * t * s
        for k in range(3):
            a, b = chain[k], chain[k + 1]
            if k == 2:  # the tip keypoint sits on the surface at the end of the pad
                b = b - unit_vector(b - a) * radii[k]
            capsule(a, b, radii[k], j0 + k)
        if finger != "thumb":
            # knuckle: the metacarpal head, a little dorsal of the MCP centre
            head = joints[j0] + np.array([-4.0, 2.5 * t, 0.0]) * s
            prims.append(_Primitive(0, lambda p, c=head, r=radii[0] + 1.2 * t * s: np.linalg.norm(p - c, axis=1) - r))

    # palm: a rounded slab over the convex polygon of wrist corners and MCP heads (x-z plane)
    mcps = {f: joints[1 + 3 * i] for i, f in enumerate(kp.MANO_FINGER_ORDER)}
    poly = np.array(
        [
            [mcps["index"][0] - 6 * s, mcps["index"][2] + 2 * s],
            [5 * spec.palm * s, -21 * spec.breadth * s],
            [5 * spec.palm * s, 21 * spec.breadth * s],
            [mcps["little"][0] - 6 * s, mcps["little"][2] - 1 * s],
            [mcps["ring"][0] - 5 * s, mcps["ring"][2]],
            [mcps["middle"][0] - 5 * s, mcps["middle"][2]],
        ]
    )
    # order counter-clockwise in the (x, z) plane
    centre = poly.mean(axis=0)
    poly = poly[np.argsort(np.arctan2(poly[:, 1] - centre[1], poly[:, 0] - centre[0]))]
    half_thickness, rounding = 12.0 * t * s, 9.0 * t * s
    palm_y = -3.0 * t * s

    def palm(p):
        d2 = _polygon_sdf_2d(p[:, [0, 2]], poly) + rounding
        dy = np.abs(p[:, 1] - palm_y) - half_thickness + rounding
        w = np.stack([d2, dy], axis=1)
        return np.minimum(w.max(axis=1), 0.0) + np.linalg.norm(np.maximum(w, 0.0), axis=1) - rounding

    prims.append(_Primitive(0, palm))
    # hypothenar pad along the ulnar edge of the palm
    capsule(at(14.0, -6.0, 20.0), at(52.0, -6.0, 26.0), 10.0 * t * s, 0)
    # wrist: an oval bar across, carrying the hand into the forearm
    capsule(at(-2.0, -2.0, -19.0), at(-2.0, -2.0, 19.0), 14.5 * t * s, 0)
    return prims


def build_mesh(spec: HandSpec) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    import fast_simplification
    from skimage.measure import marching_cubes

    prims = _primitives(spec)
    joints, tips = rest_skeleton(spec)
    pad = 20.0 * MM * spec.scale
    lo = np.minimum(joints.min(0), tips.min(0)) - pad
    step = spec.voxel_m
    extent = np.maximum(joints.max(0), tips.max(0)) + pad - lo
    block = 8
    nblocks = np.ceil(extent / (step * block)).astype(int)
    field = _narrow_band_field(prims, spec, lo, step, block, nblocks)
    verts, faces, _, _ = marching_cubes(field, level=0.0, spacing=(step, step, step))
    verts = verts + lo
    verts, faces = _decimate(verts, faces, spec.max_faces, fast_simplification)
    faces = orient_outward(verts, faces)
    weights = _skin_weights(verts, faces, prims, spec)
    return verts, faces.astype(np.int64), weights


def _narrow_band_field(prims, spec, lo, step, block, nblocks) -> np.ndarray:
    """Sample the blended field on the grid, exactly only in blocks the surface can cross.

    The blended field is 1-Lipschitz (a distance bound), so a block whose centre
    value exceeds its half-diagonal holds no surface; such blocks get the centre
    value (right sign, no zero crossing) instead of a full evaluation.
    """
    half_diag = 0.5 * np.sqrt(3.0) * block * step
    centres = lo + (np.stack(np.meshgrid(*[np.arange(n) for n in nblocks], indexing="ij"), -1) + 0.5) * block * step
    coarse = _blend_points(centres.reshape(-1, 3), prims, spec).reshape(tuple(nblocks))
    near = np.abs(coarse) <= half_diag + step
    field = np.repeat(np.repeat(np.repeat(coarse, block, 0), block, 1), block, 2).astype(np.float64)
    offsets = np.stack(np.meshgrid(*[np.arange(block)] * 3, indexing="ij"), -1).reshape(-1, 3)
    idx = np.argwhere(near)  # (Bn, 3) block indices
    cells = (idx[:, None, :] * block + offsets[None]).reshape(-1, 3)  # (Bn * block^3, 3)
    values = _blend_points(lo + cells * step, prims, spec)
    field[cells[:, 0], cells[:, 1], cells[:, 2]] = values
    return field


def _blend_points(points: np.ndarray, prims: list[_Primitive], spec: HandSpec) -> np.ndarray:
    """Blended field at (N, 3) points."""
    return _blend(np.stack([p.sdf(points) for p in prims], axis=1), prims, spec)


def _blend(values: np.ndarray, prims: list[_Primitive], spec: HandSpec) -> np.ndarray:
    """Smooth union: tight within a finger (joints), wide into the palm (webs, thenar)."""
    s = spec.scale * MM
    bones = np.array([p.bone for p in prims])
    palm_like = bones == 0
    thumb_base = bones == 13
    field_palm = values[:, palm_like][:, 0]
    for k in np.flatnonzero(palm_like)[1:]:
        field_palm = _smin(field_palm, values[:, k], 6.0 * s)
    field = _smin(field_palm, values[:, thumb_base].min(axis=1), 9.0 * s)
    for i in range(5):
        j0 = 1 + 3 * i
        if j0 == 13:
            finger = values[:, bones == 14][:, 0]
            finger = _smin(finger, values[:, bones == 15][:, 0], 2.0 * s)
            field = _smin(field, finger, 3.0 * s)
            continue
        finger = values[:, bones == j0][:, 0]
        for j in (j0 + 1, j0 + 2):
            finger = _smin(finger, values[:, bones == j][:, 0], 2.0 * s)
        field = _smin(field, finger, 4.0 * s)
    return field


def _decimate(verts, faces, max_faces, fast_simplification):
    if len(faces) <= max_faces:
        return verts, faces
    reduction = 1.0 - max_faces / len(faces)
    v, f = fast_simplification.simplify(verts.astype(np.float32), faces.astype(np.int32), target_reduction=reduction)
    return np.asarray(v, dtype=np.float64), np.asarray(f, dtype=np.int64)


def orient_outward(verts: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """``faces`` of a closed mesh, their winding flipped if the signed volume is negative."""
    tri = verts[faces]
    volume = np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() / 6.0
    return faces[:, ::-1].copy() if volume < 0 else faces


def _smoothstep(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def bone_radii(spec: HandSpec) -> np.ndarray:
    """(16,) capsule radius of the bone each joint moves, metres (0 for the wrist): the tables' radii times
    the spec's scale and thickness."""
    radii = np.zeros(NUM_JOINTS)
    for i, finger in enumerate(kp.MANO_FINGER_ORDER):
        radii[1 + 3 * i : 4 + 3 * i] = THUMB_RADII_MM if finger == "thumb" else FINGER_RADII_MM[finger]
    return radii * spec.thickness * MM * spec.scale


def _skin_weights(verts, faces, prims, spec: HandSpec) -> np.ndarray:
    """Linear-blend-skinning weights with compact blend zones around the joints.

    Each vertex belongs to the bone of the implicit piece it lies on. Across
    each finger joint the weight passes from parent to child bone with a
    smoothstep over +-0.75 bone radii along the bone axis, the same function
    on both sides so the weights are continuous where ownership changes; on
    the palm side the blend fades out radially so the palm is not dragged
    by a finger. The thenar eminence (soft tissue over the thumb metacarpal)
    blends with the palm where their surface distances differ by under 6 mm. Outside the zones a
    vertex follows one bone exactly (weight 1).
    """
    s = spec.scale * MM
    values = np.stack([p.sdf(verts) for p in prims], axis=1)  # (V, P)
    bones = np.array([p.bone for p in prims])
    per_bone = np.stack([values[:, bones == j].min(axis=1) for j in range(NUM_JOINTS)], axis=1)  # (V, 16)
    owner = np.argmin(per_bone, axis=1)
    w = np.zeros((len(verts), NUM_JOINTS))
    w[np.arange(len(verts)), owner] = 1.0

    joints, tips = rest_skeleton(spec)
    ends = child_of_joint(joints, tips)
    radii = bone_radii(spec)
    thumb_cmc = 13
    for j in range(1, NUM_JOINTS):
        p = kp.MANO_PARENTS[j]
        if j == thumb_cmc:
            sel = (owner == 0) | (owner == thumb_cmc)
            t = _smoothstep((per_bone[sel, 0] - per_bone[sel, thumb_cmc] + 6.0 * s) / (12.0 * s))
            w[sel, 0], w[sel, thumb_cmc] = 1.0 - t, t
            continue
        direction = unit_vector(ends[j] - joints[j])
        delta = 0.75 * radii[j]
        rel = verts - joints[j]
        axial = rel @ direction
        radial = np.linalg.norm(rel - axial[:, None] * direction, axis=1)
        t = _smoothstep((axial + delta) / (2.0 * delta))  # 0: parent bone, 1: this bone
        child_side = owner == j
        w[child_side, p] += 1.0 - t[child_side]
        w[child_side, j] -= 1.0 - t[child_side]
        parent_side = owner == p
        if p == 0:
            t = t * _smoothstep((1.9 * radii[j] - radial) / (0.6 * radii[j]))
        w[parent_side, j] += t[parent_side]
        w[parent_side, p] -= t[parent_side]
    w = np.clip(w, 0.0, None)
    w /= w.sum(axis=1, keepdims=True)
    # one round of neighbour averaging softens the few seams where two zones meet
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    acc, count = w.copy(), np.ones(len(verts))
    np.add.at(acc, edges[:, 0], w[edges[:, 1]])
    np.add.at(acc, edges[:, 1], w[edges[:, 0]])
    np.add.at(count, edges[:, 0], 1)
    np.add.at(count, edges[:, 1], 1)
    w = acc / count[:, None]
    # snap negligible weights to zero so that rigid regions move exactly rigidly
    w[w < 1e-6] = 0.0
    return w / w.sum(axis=1, keepdims=True)
