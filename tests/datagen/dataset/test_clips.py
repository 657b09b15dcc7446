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
