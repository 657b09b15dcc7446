"""The clinic track's world of each grasp: its subject's hand, the patient under its probe, the room, and
the cameras of a sonographer's head.

On the clinic track each grasp of the grasps file carries its subject (``subject_hand``, the measured
``hand_length_mm`` and ``hand_breadth_mm``, ``subject_sex``: :mod:`hupbench.datagen.assets.subjects`) and the
patient placed under its probe (``patient_*`` arrays: :mod:`hupbench.datagen.assets.patient`), both made by
``hupbench grasps +subjects=clinic``. A frame is (grasp, background, glove, view): the view is one of the grasp's
``head.views_per_grasp`` cameras (:func:`hupbench.datagen.dataset.head.head_cameras`), drawn once per grasp from
a generator seeded with (dataset seed, grasp index), so frame ``i`` stays a pure function of (config, grasps,
i); the background index picks the room's colours and, with the grasp, the patient's skin tone.

Convention:
    World = probe frame, metres. Cameras are ``T_cam_world`` in OpenCV axes.
"""

from __future__ import annotations

import numpy as np

from hupbench.core import keypoints as kp
from hupbench.core.contract import CLINIC_SEG_LABELS, SEG_LABELS
from hupbench.core.errors import BadValueError
from hupbench.datagen.assets.arm import ArmSpec
from hupbench.datagen.assets.hand_mesh import segment_distance
from hupbench.datagen.assets.patient import SKIN_RGB, body_mesh, body_sdf
from hupbench.datagen.assets.room import room_meshes
from hupbench.datagen.dataset.grasps_file import GraspSet
from hupbench.datagen.dataset.head import head_cameras
from hupbench.datagen.dataset.spec import DatasetSpec
from hupbench.datagen.render.renderer import MeshPart

#: how far a camera (the sonographer's eyes) stays from the patient's skin and from the forearm's axis, metres:
#: a head is about 0.15-0.2 m across (Pheasant and Haslegrave, Bodyspace, 3rd ed., 2006, head breadth and
#: length), so its eyes cannot come nearer than about half of that to a surface it does not touch
HEAD_CLEARANCE_M = 0.10
#: the seed streams of a grasp's cameras and of a frame's skin tone (with the dataset seed and the indices)
CAMERA_STREAM, SKIN_STREAM = 101, 102
#: the patient's surface colour's roughness (skin) and the room's
SKIN_ROUGHNESS, ROOM_ROUGHNESS = 0.6, 0.9
_LOOK_AT = kp.KEYPOINT_NAMES.index("middle_mcp")


def check_clinic_grasps(grasps: dict[str, np.ndarray], path) -> None:
    """A grasps file (:func:`hupbench.datagen.dataset.grasps_file.read_grasps`' arrays of ``path``) can be rendered on
    the clinic track: it holds each grasp's subject and patient."""
    if "subject_sex" not in grasps or "patient_radius_m" not in grasps:
        raise BadValueError(f"grasps file {path} holds no subjects and patients: the clinic track renders grasps made "
                            "by `hupbench grasps +subjects=clinic` (grasps_path=null renders the shipped ones)")


class ClinicWorld:
    """What the clinic track adds to a grasp: the patient, the room and the head's cameras (cached per grasp).

    Args:
        spec: the dataset spec (track "clinic": ``spec.head`` set).
        grasps: the grasps rendered, with their subjects and patients (:func:`check_clinic_grasps` checked them).
    """

    def __init__(self, spec: DatasetSpec, grasps: GraspSet) -> None:
        assert spec.head is not None and grasps.placements is not None and grasps.subjects is not None
        self.spec, self.grasps, self.placements = spec, grasps, grasps.placements
        self._cameras: dict[int, dict] = {}
        self._colours: dict[tuple[int, int], dict] = {}
        self._arm_length_m = ArmSpec().length_m
        self._keep_out: dict[int, np.ndarray] = {}  # the last grasp's (a worker renders a grasp's clips together)

    def cameras(self, g: int) -> dict:
        """Grasp ``g``'s cameras (:func:`hupbench.datagen.dataset.head.head_cameras`' dict), drawn once."""
        if g not in self._cameras:
            grasps, placement = self.grasps, self.placements[g]
            wrist = grasps.hand_trans[g]
            elbow = wrist + self._arm_length_m * grasps.forearm_axis[g]

            def clear(points: np.ndarray) -> np.ndarray:
                return (body_sdf(placement, points) > HEAD_CLEARANCE_M) \
                    & (segment_distance(points, wrist, elbow)[0] > HEAD_CLEARANCE_M)

            rng = np.random.default_rng([self.spec.seed, CAMERA_STREAM, g])
            self._cameras[g] = head_cameras(self.spec.head, self.spec.intrinsics, grasps.keypoints_world[g, _LOOK_AT],
                                            placement.vertical_world, clear, rng)
        return self._cameras[g]

    def keep_out(self, g: int) -> np.ndarray:
        """(V, 3) float64, metres, world frame: grasp ``g``'s hand and forearm vertices as the renderer builds them
        (what a clip may not sink into the patient), built once per grasp."""
        from hupbench.datagen.render.scene import hand_and_arm_vertices

        if g not in self._keep_out:
            self._keep_out = {g: hand_and_arm_vertices(self.grasps, g, self.grasps.probe)}
        return self._keep_out[g]

    def parts(self, g: int) -> list[MeshPart]:
        """The patient (label "patient") and the room (label 0: background with depth) of grasp ``g``, in the
        colours of background 0 (:meth:`colours` gives each background's)."""
        placement = self.placements[g]
        parts = [MeshPart("patient", body_mesh(placement), CLINIC_SEG_LABELS["patient"], SKIN_RGB[0],
                          roughness=SKIN_ROUGHNESS)]
        parts += [MeshPart(name, mesh, SEG_LABELS["background"], tuple(rgb), roughness=ROOM_ROUGHNESS)
                  for name, mesh, rgb in room_meshes(placement, 0)]
        return parts

    def skin_tone(self, g: int, background: int) -> int:
        """The skin tone index (into ``SKIN_RGB``) of grasp ``g``'s patient behind background ``background``."""
        rng = np.random.default_rng([self.spec.seed, SKIN_STREAM, g, background])
        return int(rng.integers(len(SKIN_RGB)))

    def colours(self, g: int, background: int) -> dict[str, tuple[float, float, float]]:
        """Part name -> RGB of grasp ``g``'s patient and room behind background ``background``: the background
        index picks the room's palette and, with the grasp, the skin tone (kept per grasp and background)."""
        if (g, background) not in self._colours:
            out = {"patient": tuple(SKIN_RGB[self.skin_tone(g, background)])}
            out.update({name: tuple(rgb) for name, _, rgb in room_meshes(self.placements[g], background)})
            self._colours[g, background] = out
        return self._colours[g, background]

    def rows(self, g: int, background: int, view: int) -> dict:
        """The clinic annotation values of one frame (:data:`hupbench.core.contract.CLINIC_ANNOTATION_FIELDS`)."""
        cams, subjects = self.cameras(g), self.grasps.subjects
        return {"hand_length_mm": subjects["hand_length_mm"][g], "hand_breadth_mm": subjects["hand_breadth_mm"][g],
                "subject_sex": subjects["subject_sex"][g], "skin_tone_id": self.skin_tone(g, background),
                "roll_deg": cams["roll_deg"][view], "aim_px": cams["aim_px"][view]}
