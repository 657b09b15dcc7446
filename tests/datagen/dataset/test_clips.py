"""A clip's geometry on the clinic world: it starts at the grasp's drawn camera, its labels are continuous to the
clip's own kinematic bounds, and its head stays clear of the skin with the hand in view."""

import numpy as np
import pytest
from hydra.utils import instantiate

from hupbench.config import compose
from hupbench.core import keypoints as kp
from hupbench.core.camera import project_points
from hupbench.core.errors import RunFailedError
from hupbench.core.geometry import invert_transform, transform_points
from hupbench.datagen.assets.patient import PatientPlacement, body_sdf
from hupbench.datagen.dataset import clips
from hupbench.datagen.dataset.clinic import HEAD_CLEARANCE_M, ClinicWorld
from hupbench.datagen.dataset.clips import clip_geometry
from hupbench.datagen.dataset.grasps_file import CLINIC_GRASPS, GraspSet
from hupbench.datagen.dataset.head import HeadSpec
from hupbench.datagen.dataset.head_motion import HeadMotionSpec
from hupbench.datagen.dataset.scan_motion import ScanMotionSpec

CASES = ((0, 0), (23, 5), (51, 30))


@pytest.fixture(scope="module")
def world():
    return ClinicWorld(instantiate(compose("generate", ["+track=clinic"]).dataset), GraspSet(CLINIC_GRASPS))


@pytest.fixture(scope="module")
def clip_of(world):
    return {case: clip_geometry(world, *case, ScanMotionSpec(), HeadMotionSpec(), np.random.default_rng([5, *case]))
            for case in CASES}


@pytest.mark.parametrize("case", CASES)
def test_a_clip_starts_at_the_grasps_camera_and_labels_follow_its_cameras(world, clip_of, case):
    g, view = case
    clip = clip_of[case]
    np.testing.assert_allclose(clip["T_cam_world"][0], world.cameras(g)["T_cam_world"][view], atol=1e-9)
    want = transform_points(clip["T_cam_world"], world.grasps.keypoints_world[g][None])
    np.testing.assert_allclose(clip["keypoints_cam"], want, atol=1e-12)
    np.testing.assert_allclose(clip["keypoints_2d"], project_points(want, world.spec.intrinsics.K), atol=1e-9)


@pytest.mark.parametrize("case", CASES)
def test_a_clips_labels_are_continuous_to_its_kinematic_bounds(clip_of, case):
    """The probe's centre, taken from the camera-frame labels back to the room through the frame's camera and
    patient pose, moves no farther from frame to frame than the clip's top speed allows."""
    clip = clip_of[case]
    fps = 1.0 / np.diff(clip["time_s"]).mean()
    T_body_cam = invert_transform(clip["T_world_body"]) @ invert_transform(clip["T_cam_world"])
    corners_body = transform_points(T_body_cam, clip["keypoints_cam"][:, kp.NUM_HAND:])  # (F, 8, 3)
    centre_body = corners_body.mean(axis=1)
    np.testing.assert_allclose(centre_body, clip["motion"].centre_body_m, atol=1e-9)
    step_mm = 1000 * np.linalg.norm(np.diff(centre_body, axis=0), axis=1)
    assert step_mm.max() <= clip["motion"].bounds["speed_mm_per_s"] / fps * (1 + 1e-6)
    # the hand moves with the probe: its joints keep their distances to the probe's corners
    hand_to_probe = np.linalg.norm(clip["keypoints_cam"][:, :kp.NUM_HAND, None] - clip["keypoints_cam"][:, None,
                                   kp.NUM_HAND:], axis=-1)
    np.testing.assert_allclose(hand_to_probe, np.broadcast_to(hand_to_probe[0], hand_to_probe.shape), atol=1e-9)


@pytest.mark.parametrize("case", CASES)
def test_the_head_stays_clear_of_the_skin_with_keypoint_9_in_the_image(world, clip_of, case):
    clip, placement = clip_of[case], world.placements[case[0]]
    centres = invert_transform(clip["T_cam_world"])[:, :3, 3]
    for T, centre in zip(clip["T_world_body"], centres):
        moved = PatientPlacement(T, placement.radius_m, placement.vertical_world, placement.normal_world, 0.0, 0.0)
        assert body_sdf(moved, centre[None])[0] > HEAD_CLEARANCE_M
    uv = clip["keypoints_2d"][:, kp.KEYPOINT_NAMES.index("middle_mcp")]
    assert np.all((uv >= 0) & (uv <= [world.spec.intrinsics.width - 1, world.spec.intrinsics.height - 1]))


def test_a_head_that_cannot_stay_clear_is_one_line(world, monkeypatch):
    monkeypatch.setattr(clips, "HEAD_CLEARANCE_M", 10.0)
    with pytest.raises(RunFailedError, match=r"clip of grasp 0, camera 0: 20 heads in a row came within 10 m"):
        clip_geometry(world, 0, 0, ScanMotionSpec(), HeadMotionSpec(), np.random.default_rng(0))


@pytest.fixture(scope="module")
def rendered():
    """A 1-second clip of clinic grasp 23 rendered at 64 x 64 px (the tiny clinic spec, scaled)."""
    from helpers.datasets import clinic_spec

    from hupbench.datagen.dataset.chunks import ChunkRenderer
    from hupbench.datagen.dataset.spec import lamp

    spec = clinic_spec(width=64, height=64, fx=120.0, fy=120.0, cx=32.0, cy=32.0, head=HeadSpec(views_per_grasp=3))
    chunks = ChunkRenderer(spec, str(CLINIC_GRASPS), None, None)
    clip = clip_geometry(chunks.world, 23, 1, ScanMotionSpec(duration_s=(1.0, 1.0)), HeadMotionSpec(),
                         np.random.default_rng(11))
    frames = chunks.render_clip(23, clip, 1, 0, lamp(spec, 0))
    return chunks, clip, frames


def test_a_rendered_clip_shows_the_patient_where_each_frame_puts_it(rendered):
    """Every frame: depth in every pixel, the patient's pixels on the body moved to the frame's pose (verify's own
    check), not on the first frame's body where the probe has moved 10 mm or more."""
    from hupbench.datagen.dataset.verify_frames import depth_holes_problem, patient_depth_problem

    chunks, clip, frames = rendered
    placement = chunks.world.placements[23]
    assert len(frames) == len(clip["time_s"]) == 31
    moved_far = []
    for f, frame in enumerate(frames):
        assert frame["rgb"].shape == (64, 64, 3) and frame["rgb"].dtype == np.uint8
        assert depth_holes_problem(frame["depth"]) is None, f
        row = {"K": chunks.spec.intrinsics.K, "T_cam_world": clip["T_cam_world"][f]}
        moved = PatientPlacement(clip["T_world_body"][f], placement.radius_m, placement.vertical_world,
                                 placement.normal_world, 0.0, 0.0)
        assert patient_depth_problem(row, frame["depth"], frame["seg"], moved) is None, f
        shift_mm = 1000 * np.linalg.norm(clip["motion"].centre_body_m[f] - clip["motion"].centre_body_m[0])
        if shift_mm > 10:
            moved_far.append(patient_depth_problem(row, frame["depth"], frame["seg"], placement))
    assert moved_far and all(problem is not None for problem in moved_far)


def test_a_rendered_clip_frame_equals_the_scene_built_at_its_pose(rendered):
    """The last frame's depth and labels against a renderer given the patient's and room's meshes built at that
    frame's placement."""
    from hupbench.datagen.assets.patient import body_mesh
    from hupbench.datagen.render.scene import Grasp, models_of, scene_parts
    from hupbench.datagen.render.renderer import MeshPart
    from hupbench.datagen.assets.room import room_meshes
    from hupbench.core.contract import CLINIC_SEG_LABELS, SEG_LABELS
    from hupbench.datagen.dataset.clinic import ROOM_ROUGHNESS, SKIN_ROUGHNESS
    from hupbench.datagen.assets.patient import SKIN_RGB

    chunks, clip, frames = rendered
    grasps, placement, f = chunks.grasps, chunks.world.placements[23], len(frames) - 1
    moved = PatientPlacement(clip["T_world_body"][f], placement.radius_m, placement.vertical_world,
                             placement.normal_world, 0.0, 0.0)
    parts = scene_parts(Grasp(grasps.hand_pose[23], grasps.hand_trans[23]), models_of(grasps.hand_spec(23)),
                        probe=grasps.probe)
    parts += [MeshPart("patient", body_mesh(moved), CLINIC_SEG_LABELS["patient"], SKIN_RGB[0],
                       roughness=SKIN_ROUGHNESS)]
    parts += [MeshPart(name, mesh, SEG_LABELS["background"], tuple(rgb), roughness=ROOM_ROUGHNESS)
              for name, mesh, rgb in room_meshes(moved, 0)]
    chunks.renderer.set_parts(parts)
    chunks._grasp_loaded = None
    want = chunks.renderer.render(clip["T_cam_world"][f], ("depth", "seg"))
    near = np.abs(frames[f]["depth"] - want["depth"]) < 1e-4
    assert near.mean() > 0.995 and (frames[f]["seg"] == want["seg"]).mean() > 0.995


@pytest.mark.parametrize("case", CASES)
def test_a_clips_probe_hand_and_forearm_stay_out_of_the_patient_in_every_frame(world, clip_of, case):
    """verify's contact measure (its own build of the grasp's hand and forearm) at every frame's body pose: the lens
    on the skin, no probe vertex deeper than 2 mm, no hand or forearm vertex deeper than 3 mm."""
    from hupbench.datagen.dataset.verify_clinic import ClinicGrasps, _contact_problem, contact, frame_placement

    g, _ = case
    checked = ClinicGrasps(world.grasps, world.grasps.placements, {})
    for T in clip_of[case]["T_world_body"]:
        assert _contact_problem(*contact(checked, g, world.grasps.probe, frame_placement(checked, g, T))) is None
