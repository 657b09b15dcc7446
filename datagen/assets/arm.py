"""A forearm attached at the wrist: the only piece of a body any frame shows.

Convention:
    Metres and radians. The forearm frame has its origin at the wrist joint
    centre with the axes of the hand frame at a neutral wrist (+x towards
    the fingers, +y dorsal, +z ulnar); the forearm extends along -x. Wrist
    angles give the hand relative to the forearm (:func:`wrist_rotation`):
    positive flexion turns the fingers palmar (towards -y), positive
    deviation turns them ulnar (towards +z, the little finger).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from hupbench.core.geometry import axis_angle_to_matrix
from hupbench.datagen.assets.hand_anatomy import WRIST_LIMITS_RAD
from hupbench.datagen.assets.hand_mesh import orient_outward

MM = 1e-3


@dataclass(frozen=True)
class ArmSpec:
    """Forearm shape: an elliptic tube that widens from the wrist to the elbow.

    Attributes:
        scale: size factor shared with the hand.
        length_m: wrist to the cut near the elbow, metres.
        wrist_width_m, wrist_thickness_m: ellipse diameters at the wrist.
        elbow_width_m, elbow_thickness_m: ellipse diameters at the far end.
        overlap_m: how far the tube reaches into the hand, so no gap shows.
    """

    scale: float = 1.0
    length_m: float = 0.25
    wrist_width_m: float = 0.056
    wrist_thickness_m: float = 0.038
    elbow_width_m: float = 0.078
    elbow_thickness_m: float = 0.064
    overlap_m: float = 0.012
    segments_around: int = 48
    segments_along: int = 24

    def __post_init__(self) -> None:
        # built in code (no config node makes one): invariants, not input checks
        sizes = [getattr(self, name) for name in ("scale", "length_m", "wrist_width_m", "wrist_thickness_m",
                                                  "elbow_width_m", "elbow_thickness_m")]
        assert all(np.isfinite(v) and v > 0 for v in sizes), self
        assert self.segments_around >= 8 and self.segments_along >= 2, self


def wrist_rotation(flexion: float, deviation: float) -> np.ndarray:
    """Rotation of the hand relative to the forearm.

    Args:
        flexion: radians; positive bends the palm towards the forearm's palmar side (-y).
        deviation: radians; positive turns the fingers towards the little finger (+z, ulnar).

    Returns:
        (3, 3) float64 ``R_forearm_hand``.
    """
    for v in (flexion, deviation):
        assert WRIST_LIMITS_RAD[0] - 1e-9 <= v <= WRIST_LIMITS_RAD[1] + 1e-9, v
    # flexion turns +x towards -y: a negative rotation about +z; ulnar deviation turns +x
    # towards +z: a negative rotation about +y
    return axis_angle_to_matrix(np.array([0.0, 0.0, -flexion])) @ axis_angle_to_matrix(np.array([0.0, -deviation, 0.0]))


@functools.lru_cache(maxsize=8)
def forearm_rest(spec: ArmSpec) -> tuple[np.ndarray, np.ndarray]:
    """Closed tube in the forearm frame: (V, 3) vertices, (F, 3) outward faces."""
    n, m = spec.segments_around, spec.segments_along
    t = np.linspace(0.0, 1.0, m + 1)
    # ease the taper so the wrist end narrows quickly and the muscle belly is round
    ease = np.sin(t * np.pi / 2.0)
    x = spec.overlap_m - t * (spec.length_m + spec.overlap_m)
    half_w = 0.5 * (spec.wrist_width_m + (spec.elbow_width_m - spec.wrist_width_m) * ease)
    half_t = 0.5 * (spec.wrist_thickness_m + (spec.elbow_thickness_m - spec.wrist_thickness_m) * ease)
    phi = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    ring_y = np.cos(phi)[None, :] * half_t[:, None]
    ring_z = np.sin(phi)[None, :] * half_w[:, None]
    verts = np.stack([np.repeat(x[:, None], n, axis=1), ring_y, ring_z], axis=-1).reshape(-1, 3)
    faces = []
    for i in range(m):
        for k in range(n):
            a, b = i * n + k, i * n + (k + 1) % n
            c, d = a + n, b + n
            faces += [(a, c, b), (b, c, d)]
    # caps: a centre vertex at each end
    start_c, end_c = len(verts), len(verts) + 1
    verts = np.vstack([verts, [[x[0], 0, 0], [x[-1], 0, 0]]])
    for k in range(n):
        a, b = k, (k + 1) % n
        faces.append((start_c, a, b))
        faces.append((end_c, m * n + b, m * n + a))
    faces = orient_outward(verts, np.array(faces, dtype=np.int64))
    return verts * spec.scale if spec.scale != 1.0 else verts, faces


def forearm_mesh(R_world_hand: np.ndarray, wrist_world: np.ndarray, flexion: float = 0.0, deviation: float = 0.0,
                 spec: ArmSpec = ArmSpec()):
    """The forearm posed at a hand's wrist.

    Args:
        R_world_hand: (3, 3) float, the hand's global rotation (hand frame -> world).
        wrist_world: (3,) float, metres, wrist position in the world.
        flexion, deviation: wrist angles, radians, within +-45 degrees.
        spec: forearm shape.

    Returns:
        ``trimesh.Trimesh`` in the world frame, metres, closed.
    """
    import trimesh

    assert np.shape(R_world_hand) == (3, 3) and np.shape(wrist_world) == (3,)
    verts, faces = forearm_rest(spec)
    R_world_forearm = R_world_hand @ wrist_rotation(flexion, deviation).T
    return trimesh.Trimesh(verts @ R_world_forearm.T + wrist_world, faces, process=False)
