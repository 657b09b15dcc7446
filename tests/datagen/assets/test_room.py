"""The room: its colours per variant, its sizes, and every camera ray from where a sonographer's head can be ends
on geometry within the 6.55 m a uint16 depth at 0.1 mm holds."""

import numpy as np
import pytest
import trimesh

from hupbench.core import keypoints as kp
from hupbench.datagen.assets import patient as pt
from hupbench.datagen.assets import room
from hupbench.datagen.dataset.grasps_file import DEFAULT_GRASPS, GraspSet
from hupbench.datagen.render.scene import Grasp, scene_parts

#: the image the rays are cast for: 256 px square, 480 px focal length, principal point at the centre
SIZE_PX, FOCAL_PX = 256, 480.0
MAX_DEPTH_M = 6.5


def _placement(T_world_body=np.eye(4)) -> pt.PatientPlacement:
    return pt.PatientPlacement(np.asarray(T_world_body, dtype=np.float64), 0.2, np.asarray(T_world_body)[:3, 2],
                               np.array([0.0, 0.0, 1.0]), 0.0, 0.0)


def test_variants_pick_their_colours_from_the_palettes_deterministically():
    colours = [tuple(rgb for _, _, rgb in room.room_meshes(_placement(), v)) for v in range(12)]
    assert colours == [tuple(rgb for _, _, rgb in room.room_meshes(_placement(), v)) for v in range(12)]
    assert len(set(colours)) > 6
    for bed, floor, walls, _ in colours:
        assert bed in room.SHEET_RGB and floor in room.FLOOR_RGB and walls in room.WALL_RGB


def test_the_room_is_sized_around_the_patient():
    T = trimesh.transformations.rotation_matrix(1.1, [0.3, 1.0, -0.2], [0.05, -0.1, 0.2])
    parts = {name: mesh for name, mesh, _ in room.room_meshes(_placement(T), 3)}
    assert list(parts) == ["bed", "floor", "walls", "ceiling"]
    body = {name: trimesh.transform_points(mesh.vertices, np.linalg.inv(T)) for name, mesh in parts.items()}
    assert body["bed"][:, 2].max() == pytest.approx(0.0, abs=1e-12)  # the couch top under the torso's back
    assert np.ptp(body["floor"][:, 2]) < 1e-12 and -0.7 <= body["floor"][0, 2] <= -0.6
    assert body["ceiling"][:, 2].min() > 1.5
    walls = body["walls"]
    for axis in (0, 1):
        assert 1.5 <= -walls[:, axis].min() <= 3.0 and 1.5 <= walls[:, axis].max() <= 3.0
    assert parts["bed"].is_watertight and parts["bed"].volume > 0
    # the room's faces look inwards: each normal points from its face towards the room's middle
    middle = parts["walls"].vertices.mean(axis=0)
    for name in ("floor", "walls", "ceiling"):
        mesh = parts[name]
        assert (np.einsum("ij,ij->i", mesh.face_normals, middle - mesh.triangles_center) > 0).all(), name


def _camera_rays(rng, target, vertical, count):
    """Rays through the four corners and the centre of ``count`` cameras around ``target``.

    A camera is 0.35-0.8 m from the target, at least 25 degrees above the bed plane, aimed within 15 % of
    the image width of the target, rolled by up to 15 degrees.

    Returns:
        origins (count * 5, 3), unit directions (count * 5, 3), world frame.
    """
    u = np.cross(vertical, [1.0, 0.0, 0.0] if abs(vertical[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    w = np.cross(vertical, u)
    origins, directions = [], []
    for _ in range(count):
        elevation, azimuth = np.radians(rng.uniform(25.0, 90.0)), rng.uniform(0.0, 2.0 * np.pi)
        towards = np.cos(elevation) * (np.cos(azimuth) * u + np.sin(azimuth) * w) + np.sin(elevation) * vertical
        camera = target + rng.uniform(0.35, 0.8) * towards
        forward = -towards
        right = np.cross(forward, vertical + 1e-9 * u)
        right /= np.linalg.norm(right)
        down = np.cross(forward, right)
        # the target anywhere within +-15 % of the width of the centre: turn the axis by that much
        shift = rng.uniform(-0.15, 0.15, 2) * SIZE_PX / FOCAL_PX
        forward = forward - shift[0] * right - shift[1] * down
        forward /= np.linalg.norm(forward)
        roll = np.radians(rng.uniform(-15.0, 15.0))
        right, down = (np.cos(roll) * right + np.sin(roll) * down, -np.sin(roll) * right + np.cos(roll) * down)
        for px, py in ((0, 0), (SIZE_PX, 0), (0, SIZE_PX), (SIZE_PX, SIZE_PX), (SIZE_PX / 2, SIZE_PX / 2)):
            ray = forward + (px - SIZE_PX / 2) / FOCAL_PX * right + (py - SIZE_PX / 2) / FOCAL_PX * down
            origins.append(camera)
            directions.append(ray / np.linalg.norm(ray))
    return np.array(origins), np.array(directions)


@pytest.mark.parametrize("g", [1, 7])
def test_every_camera_ray_ends_on_the_room_or_patient_within_the_depth_range(g):
    grasps = GraspSet(DEFAULT_GRASPS)
    parts = {p.name: p.mesh for p in scene_parts(Grasp(grasps.hand_pose[g], grasps.hand_trans[g]),
                                                   probe=grasps.probe)}
    placement = pt.place_patient(pt.PatientSpec(), grasps.probe, parts["hand"].vertices, parts["arm"].vertices,
                                 np.random.default_rng(g))
    scene = trimesh.util.concatenate([pt.body_mesh(placement)] + [m for _, m, _ in room.room_meshes(placement, g)])
    target = grasps.keypoints_world[g, kp.KEYPOINT_NAMES.index("middle_mcp")]  # keypoint 9
    origins, directions = _camera_rays(np.random.default_rng(100 + g), target, placement.vertical_world, 60)
    outside = pt.body_sdf(placement, origins) > 0  # a camera inside the patient is no sonographer's
    assert outside.mean() > 0.8
    origins, directions = origins[outside], directions[outside]
    hits, ray_index, _ = trimesh.ray.ray_triangle.RayMeshIntersector(scene).intersects_location(
        origins, directions, multiple_hits=False)
    assert np.array_equal(np.sort(ray_index), np.arange(len(origins)))
    distance = np.linalg.norm(hits - origins[ray_index], axis=1)
    assert distance.max() < MAX_DEPTH_M
