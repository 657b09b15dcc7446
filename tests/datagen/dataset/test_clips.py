"""A clip's geometry on the clinic world: it starts at the grasp's drawn camera, its labels are continuous to the
clip's own kinematic bounds (the probe's, the head's and the fingers'), its fingers take their recorded poses, and
its head stays clear of the skin with the hand in view."""

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
from hupbench.datagen.dataset.clips import clip_geometry, clip_record
from hupbench.datagen.dataset.finger_motion import FingerMotionSpec, finger_poses
from hupbench.datagen.dataset.grasps_file import CLINIC_GRASPS, GraspSet
from hupbench.datagen.dataset.head import HeadSpec
from hupbench.datagen.dataset.head_motion import HeadMotionSpec
from hupbench.datagen.dataset.scan_motion import ScanMotionSpec

CASES = ((0, 0), (23, 5), (51, 30))


@pytest.fixture(scope="module")
def world():
    return ClinicWorld(instantiate(compose("generate", ["+track=clinic"]).dataset), GraspSet(CLINIC_GRASPS))


#: adjustments about every second: most clips of 5 to 10 s get several
FINGERS = FingerMotionSpec(rate_hz=1.0)


@pytest.fixture(scope="module")
def clip_of(world):
    return {case: clip_geometry(world, *case, ScanMotionSpec(), HeadMotionSpec(), np.random.default_rng([5, *case]),
                                FINGERS, np.random.default_rng([6, *case])) for case in CASES}


@pytest.mark.parametrize("case", CASES)
def test_a_clip_starts_at_the_grasps_camera_and_labels_follow_its_cameras(world, clip_of, case):
    """The first frame is the grasp's camera and pose; every frame's keypoints are its hand pose's (the grasp's
    skeleton and wrist) and the probe's corners, seen by its camera."""
    from hupbench.datagen.assets.hand import build_hand

    g, view = case
    clip = clip_of[case]
    np.testing.assert_allclose(clip["T_cam_world"][0], world.cameras(g)["T_cam_world"][view], atol=1e-9)
    assert clip["adjustments"] and (clip["hand_pose"][0] == world.grasps.hand_pose[g]).all()
    np.testing.assert_array_equal(clip["hand_pose"], finger_poses(world.grasps.hand_pose[g], clip["adjustments"],
                                                                  clip["time_s"]))
    world_points = world.grasps.keypoints_world[g][None].repeat(len(clip["time_s"]), axis=0)
    world_points[:, :kp.NUM_HAND] = build_hand(world.grasps.hand_spec(g)).keypoints(
        clip["hand_pose"], world.grasps.hand_trans[g], clamp=False)
    np.testing.assert_allclose(clip["keypoints_world"], world_points, atol=1e-12)
    want = transform_points(clip["T_cam_world"], world_points)
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
    # the wrist and the knuckles move with the probe: they keep their distances to the probe's corners; the
    # fingers move relative to it, no faster than the record's bound
    hand_to_probe = np.linalg.norm(clip["keypoints_cam"][:, :kp.NUM_HAND, None] - clip["keypoints_cam"][:, None,
                                   kp.NUM_HAND:], axis=-1)
    rigid = [kp.KEYPOINT_NAMES.index(name) for name in ("wrist", "index_mcp", "middle_mcp", "ring_mcp", "little_mcp")]
    np.testing.assert_allclose(hand_to_probe[:, rigid], np.broadcast_to(hand_to_probe[0, rigid],
                                                                        hand_to_probe[:, rigid].shape), atol=1e-9)
    assert np.ptp(hand_to_probe, axis=0).max() > 5e-3  # a fingertip moved 5 mm or more against the probe
    hand_world = transform_points(invert_transform(clip["T_cam_world"]), clip["keypoints_cam"][:, :kp.NUM_HAND])
    step_mm = 1000 * np.linalg.norm(np.diff(hand_world, axis=0), axis=-1).max()
    bound = clip_record(clip | {"background": 0, "glove": 0}, fps)["fingers"]["keypoint_speed_mm_per_s"]
    assert 0 < step_mm <= bound / fps * (1 + 1e-6)


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
                         np.random.default_rng(11), FingerMotionSpec(rate_hz=4.0, move_s=(0.1, 0.2), hold_s=(0.0, 0.2)),
                         np.random.default_rng(12))
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


@pytest.mark.parametrize("which", ["last", "fingers moved"])
def test_a_rendered_clip_frame_equals_the_scene_built_at_its_pose(rendered, which):
    """A frame's depth and labels (the last, and the first whose fingers moved) against a renderer given the hand
    at the frame's pose and the patient's and room's meshes built at the frame's placement."""
    from hupbench.datagen.assets.patient import body_mesh
    from hupbench.datagen.render.scene import Grasp, models_of, scene_parts
    from hupbench.datagen.render.renderer import MeshPart
    from hupbench.datagen.assets.room import room_meshes
    from hupbench.core.contract import CLINIC_SEG_LABELS, SEG_LABELS
    from hupbench.datagen.dataset.clinic import ROOM_ROUGHNESS, SKIN_ROUGHNESS
    from hupbench.datagen.assets.patient import SKIN_RGB

    chunks, clip, frames = rendered
    grasps, placement = chunks.grasps, chunks.world.placements[23]
    moved = np.flatnonzero((clip["hand_pose"] != grasps.hand_pose[23]).any(axis=1))
    f = len(frames) - 1 if which == "last" else int(moved[len(moved) // 2])
    moved = PatientPlacement(clip["T_world_body"][f], placement.radius_m, placement.vertical_world,
                             placement.normal_world, 0.0, 0.0)
    parts = scene_parts(Grasp(clip["hand_pose"][f], grasps.hand_trans[23]), models_of(grasps.hand_spec(23)),
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
    if which == "fingers moved":  # the grasp's own hand would not match there
        parts[0] = scene_parts(Grasp(grasps.hand_pose[23], grasps.hand_trans[23]), models_of(grasps.hand_spec(23)),
                               probe=grasps.probe)[0]
        chunks.renderer.set_parts(parts)
        still = chunks.renderer.render(clip["T_cam_world"][f], ("depth", "seg"))
        assert (still["seg"] != want["seg"]).sum() > 0


@pytest.mark.parametrize("case", CASES)
def test_a_clips_probe_hand_and_forearm_stay_out_of_the_patient_in_every_frame(world, clip_of, case):
    """verify's contact measure (its own build of the grasp's hand and forearm, the hand at each frame's pose) at
    every frame's body pose: the lens on the skin, no probe vertex deeper than 2 mm, no hand or forearm vertex
    deeper than 3 mm."""
    from hupbench.datagen.assets.hand import build_hand
    from hupbench.datagen.dataset.verify_clinic import ClinicGrasps, _contact_problem, contact, frame_placement

    g, _ = case
    checked = ClinicGrasps(world.grasps, world.grasps.placements, {})
    clip = clip_of[case]
    hands = build_hand(world.grasps.hand_spec(g)).vertices(clip["hand_pose"], world.grasps.hand_trans[g])
    for T, hand in zip(clip["T_world_body"], hands):
        assert _contact_problem(*contact(checked, g, world.grasps.probe, frame_placement(checked, g, T), hand)) is None
