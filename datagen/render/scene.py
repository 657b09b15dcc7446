"""A hand-probe scene: the posed meshes and the 29 keypoints of one grasp.

Convention:
    World = probe frame (the probe at the origin, as in HUP-3D) unless a
    ``T_world_probe`` is given. Hand pose and translation are in the world
    frame (see :mod:`hupbench.datagen.assets.hand`). Metres.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from hupbench.core import keypoints as kp
from hupbench.datagen.assets.arm import ArmSpec, forearm_mesh
from hupbench.core.geometry import axis_angle_to_matrix, transform_points
from hupbench.datagen.assets.hand import build_hand
from hupbench.datagen.assets.hand_anatomy import HandSpec, clamp_pose
from hupbench.datagen.assets.probe import Probe, ProbeSpec, build_probe
from hupbench.datagen.render.renderer import SEG_LABELS, MeshPart

#: HUP-3D's colours (the published renderer, manuelbirlo/HUP-3D_renderer): the two glove colours and the arm
GLOVE_RGB = ((0.5647, 0.5922, 0.7686), (0.3804, 0.6196, 0.8667))
ARM_RGB = (1.0, 0.6784, 0.3765)
PROBE_BODY_RGB = (0.86, 0.86, 0.84)
PROBE_LENS_RGB = (0.18, 0.19, 0.21)
#: the probe's orientation marker (hupbench.datagen.assets.probe.ProbeSpec): the saturated green of a marker light, far
#: from the grey housing, the dark lens, both glove colours, the arm and the skin tones of the backgrounds;
#: it also glows (PROBE_MARKER_EMISSIVE) like the light it stands for, so it stays green in the shadow of
#: the hand or away from the lamp
PROBE_MARKER_RGB = (0.05, 0.85, 0.25)
PROBE_MARKER_EMISSIVE = (0.0004, 0.2025, 0.0144)


@dataclass
class Grasp:
    """A hand holding the probe.

    Attributes:
        hand_pose: (48,) float axis-angle, radians (``hupbench.datagen.assets.hand`` Convention).
        hand_trans: (3,) float, metres, wrist position in the world frame.
        wrist_flexion, wrist_deviation: forearm -> hand angles, radians.
        T_world_probe: (4, 4) float probe pose; identity puts the probe at the origin.
    """

    hand_pose: np.ndarray
    hand_trans: np.ndarray
    wrist_flexion: float = 0.0
    wrist_deviation: float = 0.0
    T_world_probe: np.ndarray = field(default_factory=lambda: np.eye(4))

    def __post_init__(self) -> None:
        # the grasps file's reader checked the pose and translation; the probe pose is the identity or made here
        self.hand_pose = np.asarray(self.hand_pose, dtype=np.float64)
        self.hand_trans = np.asarray(self.hand_trans, dtype=np.float64)
        self.T_world_probe = np.asarray(self.T_world_probe, dtype=np.float64)
        assert self.hand_pose.shape == (48,) and self.hand_trans.shape == (3,), (self.hand_pose.shape,
                                                                                 self.hand_trans.shape)
        assert self.T_world_probe.shape == (4, 4) and np.allclose(self.T_world_probe[3], [0, 0, 0, 1])


@dataclass(frozen=True)
class SceneModels:
    """The specs of the embedded models a scene is built from."""

    hand: HandSpec = HandSpec()
    probe: ProbeSpec = ProbeSpec()
    arm: ArmSpec = ArmSpec()


def models_of(hand: HandSpec) -> SceneModels:
    """The scene models of a subject's hand: the forearm scaled with the hand (as the grasp refinement's
    forearm, :func:`hupbench.datagen.grasps.refine.hand_regions`, which it kept clear of the probe), the probe
    the default; ``models_of(HandSpec())`` is ``SceneModels()``."""
    return SceneModels(hand=hand, arm=ArmSpec(scale=hand.scale))


def keypoints_world(grasp: Grasp, models: SceneModels = SceneModels(), probe: Probe | None = None) -> np.ndarray:
    """The 29 keypoints of a grasp.

    Args:
        grasp: the hand and probe placement.
        models: model specs.
        probe: the probe (e.g. a mesh probe, :func:`hupbench.datagen.assets.probe.probe_of`); None builds ``models.probe``.

    Returns:
        (29, 3) float64, metres, world frame, in ``hupbench.core.keypoints`` order.
    """
    hand = build_hand(models.hand)
    probe = probe or build_probe(models.probe)
    out = np.zeros((kp.NUM_KEYPOINTS, 3))
    out[kp.HAND_SLICE] = hand.keypoints(grasp.hand_pose, grasp.hand_trans)
    out[kp.CORNER_SLICE] = transform_points(grasp.T_world_probe, probe.corners_probe)
    return out


def scene_parts(grasp: Grasp, models: SceneModels = SceneModels(), glove_rgb=GLOVE_RGB[0],
                arm_rgb=ARM_RGB, probe: Probe | None = None) -> list[MeshPart]:
    """Posed, coloured meshes of a grasp, ready for :class:`hupbench.datagen.render.renderer.Renderer`.

    Args:
        grasp: the hand and probe placement.
        models: model specs.
        probe: the probe (e.g. a mesh probe); None builds ``models.probe``.
        glove_rgb: (3,) hand colour in [0, 1].
        arm_rgb: (3,) forearm colour in [0, 1].

    Returns:
        Parts "hand" (label 1), "arm" (2), "probe_body", "probe_lens" and, when the probe has an
        orientation marker, "probe_marker" (all three label 3).
    """
    import trimesh

    hand = build_hand(models.hand)
    probe = probe or build_probe(models.probe)
    pose = clamp_pose(grasp.hand_pose)
    hand_mesh = hand.mesh(pose, grasp.hand_trans, clamp=False)
    arm_mesh = forearm_mesh(
        axis_angle_to_matrix(pose[:3]), grasp.hand_trans, grasp.wrist_flexion, grasp.wrist_deviation, models.arm
    )
    probe_mesh = probe.mesh.copy()
    probe_mesh.apply_transform(grasp.T_world_probe)
    lens, marker = probe.lens_face_mask, probe.marker_face_mask
    body_mesh = trimesh.Trimesh(probe_mesh.vertices, probe_mesh.faces[~lens & ~marker], process=False)
    lens_mesh = trimesh.Trimesh(probe_mesh.vertices, probe_mesh.faces[lens], process=False)
    marker_mesh = None
    if marker.any():
        marker_mesh = trimesh.Trimesh(probe_mesh.vertices, probe_mesh.faces[marker], process=False)
    if not isinstance(probe.spec, ProbeSpec):
        # a mesh probe's edges may be sharp (a CAD box): normals are shared only across gentle folds
        body_mesh, lens_mesh = body_mesh.smooth_shaded, lens_mesh.smooth_shaded
        if probe.marker_patch is not None:
            marker_mesh = probe.marker_patch.copy()
            marker_mesh.apply_transform(grasp.T_world_probe)
    parts = [
        MeshPart("hand", hand_mesh, SEG_LABELS["hand"], tuple(glove_rgb), roughness=0.8),
        MeshPart("arm", arm_mesh, SEG_LABELS["arm"], tuple(arm_rgb), roughness=0.6),
        MeshPart("probe_body", body_mesh, SEG_LABELS["probe"], PROBE_BODY_RGB, roughness=0.35),
        MeshPart("probe_lens", lens_mesh, SEG_LABELS["probe"], PROBE_LENS_RGB, roughness=0.5),
    ]
    if marker_mesh is not None:
        parts.append(MeshPart("probe_marker", marker_mesh, SEG_LABELS["probe"], PROBE_MARKER_RGB, roughness=0.3,
                              emissive=PROBE_MARKER_EMISSIVE))
    return parts


def hand_and_arm_vertices(grasps, g: int, probe) -> np.ndarray:
    """(V, 3) float64, metres, world (probe) frame: the hand's and the forearm's vertices of grasp ``g`` of a
    :class:`hupbench.datagen.dataset.grasps_file.GraspSet` holding ``probe``, built as :func:`scene_parts` builds them
    for the renderer (the grasp's own hand, ``GraspSet.hand_spec``)."""
    parts = {p.name: p.mesh for p in scene_parts(Grasp(grasps.hand_pose[g], grasps.hand_trans[g]),
                                                  models_of(grasps.hand_spec(g)), probe=probe)}
    return np.concatenate([np.asarray(parts["hand"].vertices, np.float64),
                           np.asarray(parts["arm"].vertices, np.float64)])
