"""The examination room around the patient: a couch under her, a floor, four walls and a ceiling.

The room is closed so that every camera ray ends on geometry: a camera near the probe, looking down at the
hand from 25 degrees above the couch with a 256 px, 480 px-focal image, sends its corner rays up to 21
degrees off its axis, about level; with only a floor they would travel tens of metres. The room's longest
diagonal (6.3 m) bounds every ray from inside it below the 6.55 m a uint16 depth at 0.1 mm can hold.

Sizes: an examination couch about 2 m long and 0.9 m wide with its top about 0.65 m above the floor
(a fixed-height couch's typical 0.6-0.7 m; height-adjustable couches span about 0.5-0.9 m); the walls
1.6-2.4 m from the abdomen, the room about 4.2 x 3.8 x 2.75 m, the size of an ultrasound examination room.

Convention:
    Metres. The meshes are built in the patient's body frame (:mod:`hupbench.datagen.assets.patient`: +z up,
    origin on the couch top under the abdomen) and returned in the world frame of a placement.
    Colours are sRGB in [0, 1].
"""

from __future__ import annotations

import numpy as np
import trimesh

from hupbench.datagen.assets.patient import PatientPlacement

__all__ = ["BED_BOX_M", "ROOM_BOX_M", "room_meshes"]

#: the couch, (low corner, high corner) in the body frame, metres: its top is the body frame's z = 0
BED_BOX_M = np.array([[-1.0, -0.45, -0.65], [1.0, 0.45, 0.0]])
#: the room's inside, (low corner, high corner) in the body frame, metres: the floor 0.65 m under the couch top
ROOM_BOX_M = np.array([[-2.0, -1.6, -0.65], [2.2, 2.2, 2.1]])
#: couch covers: white, pale blue, pale green, the off-white of a paper roll
SHEET_RGB = ((0.92, 0.92, 0.90), (0.70, 0.80, 0.90), (0.70, 0.84, 0.76), (0.96, 0.94, 0.88))
#: painted walls: off-white, blue-grey, pale green, beige
WALL_RGB = ((0.90, 0.88, 0.82), (0.76, 0.82, 0.86), (0.84, 0.89, 0.80), (0.92, 0.85, 0.76))
#: floors: grey vinyl, oak, blue-grey vinyl, sand
FLOOR_RGB = ((0.55, 0.55, 0.52), (0.62, 0.49, 0.36), (0.42, 0.50, 0.55), (0.70, 0.66, 0.58))
CEILING_RGB = (0.95, 0.95, 0.94)


def _box(corners: np.ndarray) -> trimesh.Trimesh:
    """An outward-wound box between (2, 3) low and high corners, metres."""
    low, high = corners
    return trimesh.creation.box(extents=high - low, transform=trimesh.transformations.translation_matrix(
        0.5 * (low + high)))


def _inside_faces(room: trimesh.Trimesh, keep: np.ndarray) -> trimesh.Trimesh:
    """The room's faces where ``keep`` (F,) holds, as their own mesh."""
    mesh = trimesh.Trimesh(room.vertices, room.faces[keep], process=False)
    mesh.remove_unreferenced_vertices()
    return mesh


def room_meshes(placement: PatientPlacement, variant: int) -> list[tuple[str, trimesh.Trimesh, tuple]]:
    """The couch, floor, walls and ceiling around a placed patient.

    Args:
        placement: where the patient lies (:func:`hupbench.datagen.assets.patient.place_patient`).
        variant: picks the couch cover, wall and floor colours from their palettes, the same for the same
            variant.

    Returns:
        ``[("bed", mesh, rgb), ("floor", ...), ("walls", ...), ("ceiling", ...)]``: world-frame meshes,
        metres; the bed outward-wound, the room's faces wound to face into the room; rgb (3,) sRGB.
    """
    sheet, wall, floor = np.random.default_rng(variant).integers(0, 4, size=3)
    box = _box(ROOM_BOX_M)
    room = trimesh.Trimesh(box.vertices, box.faces[:, ::-1], process=False)  # wound to be seen from inside
    up = room.face_normals[:, 2]
    parts = [("bed", _box(BED_BOX_M), SHEET_RGB[sheet]),
             ("floor", _inside_faces(room, up > 0.5), FLOOR_RGB[floor]),
             ("walls", _inside_faces(room, np.abs(up) < 0.5), WALL_RGB[wall]),
             ("ceiling", _inside_faces(room, up < -0.5), CEILING_RGB)]
    for _, mesh, _ in parts:
        mesh.apply_transform(placement.T_world_body)
    return parts
