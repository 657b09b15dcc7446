"""A scan's clip: the lens on the skin in every frame, the probe rigid with the hand's grasp, the drawn kinematics
met, and no frame-to-frame change beyond the clip's own bounds."""

import numpy as np
import pytest

from hupbench.core.errors import BadValueError, RunFailedError
from hupbench.core.geometry import invert_transform, transform_points
from hupbench.datagen.assets.patient import PatientPlacement, body_sdf
from hupbench.datagen.dataset.grasps_file import CLINIC_GRASPS, GraspSet
from hupbench.datagen.dataset.scan_motion import SKILL_KINEMATICS, ScanMotionSpec, draw_kinematics, scan_motion
from hupbench.core.motion_metrics import KINEMATICS_KEYS, point_kinematics

GRASPS = (0, 17, 42)


@pytest.fixture(scope="module")
def grasps():
    return GraspSet(CLINIC_GRASPS)


@pytest.fixture(scope="module")
def clips(grasps):
    spec = ScanMotionSpec()
    return {g: scan_motion(grasps.placements[g], grasps.probe, spec, np.random.default_rng([7, g])) for g in GRASPS}


def _lens(probe):
    vertices = np.asarray(probe.mesh.vertices, dtype=np.float64)
    return vertices[np.unique(probe.mesh.faces[probe.lens_face_mask])]


@pytest.mark.parametrize("g", GRASPS)
def test_the_lens_touches_the_skin_in_every_frame(grasps, clips, g):
    """Checked with the patient module's own signed distance of the placed body (not the clip's record)."""
    clip, placement = clips[g], grasps.placements[g]
    lens = _lens(grasps.probe)
    for f in range(0, len(clip.time_s), 7):
        moved = PatientPlacement(clip.T_world_body[f], placement.radius_m, placement.vertical_world,
                                 placement.normal_world, 0.0, 0.0)
        assert body_sdf(moved, lens).min() == pytest.approx(-ScanMotionSpec().press_m, abs=1e-7), f
    np.testing.assert_allclose(clip.lens_skin_m, -ScanMotionSpec().press_m, atol=1e-7)


@pytest.mark.parametrize("g", GRASPS)
def test_the_first_frame_is_the_grasps_placement_and_the_probe_stays_rigid(grasps, clips, g):
    clip = clips[g]
    np.testing.assert_allclose(clip.T_world_body[0], grasps.placements[g].T_world_body, atol=1e-6)
    centre_probe = grasps.probe.corners_probe.mean(axis=0)
    centres = transform_points(invert_transform(clip.T_world_body), centre_probe[None])[:, 0]
    np.testing.assert_allclose(centres, clip.centre_body_m, atol=1e-12)
    R = clip.T_world_body[:, :3, :3]
    np.testing.assert_allclose(R @ np.swapaxes(R, 1, 2), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)


@pytest.mark.parametrize("g", GRASPS)
def test_the_clip_has_its_drawn_kinematics_and_stays_within_its_bounds(clips, g):
    clip, spec = clips[g], ScanMotionSpec()
    for key in KINEMATICS_KEYS:
        assert clip.kinematics[key] == pytest.approx(clip.target[key], rel=2e-3), key
        assert clip.bounds[key] > clip.kinematics[key]
    # a frame moves no farther than the clip's top speed allows in a frame's time
    step_mm = np.linalg.norm(np.diff(clip.centre_body_m, axis=0), axis=1) * 1000.0
    assert step_mm.max() <= clip.bounds["speed_mm_per_s"] / spec.fps * (1 + 1e-9)
    assert 5.0 <= clip.time_s[-1] <= 10.0 and np.allclose(np.diff(clip.time_s), 1.0 / spec.fps)
    # at the frames' rate the speed is what the oversampled motion has, within the sampling's smoothing
    at_frames = point_kinematics(clip.centre_body_m, spec.fps)
    assert at_frames["speed_mm_per_s"] == pytest.approx(clip.kinematics["speed_mm_per_s"], rel=0.25)


def test_the_same_seed_gives_the_same_clip_and_another_another(grasps, clips):
    again = scan_motion(grasps.placements[GRASPS[0]], grasps.probe, ScanMotionSpec(), np.random.default_rng([7, 0]))
    np.testing.assert_array_equal(again.T_world_body, clips[GRASPS[0]].T_world_body)
    other = scan_motion(grasps.placements[GRASPS[0]], grasps.probe, ScanMotionSpec(), np.random.default_rng([8, 0]))
    assert other.target != again.target


def test_drawn_kinematics_centre_on_the_skill_s_figures():
    """Log-normal factors of mean 1: over 4,000 draws the target over the skill's interpolated mean averages 1,
    and a consultant-like draw (skill < 0.1) is slower than a fellow-like one (skill > 0.9)."""
    rng = np.random.default_rng(3)
    draws = [draw_kinematics(rng) for _ in range(4000)]
    consultant, fellow = SKILL_KINEMATICS["consultant"], SKILL_KINEMATICS["fellow"]
    for key in KINEMATICS_KEYS:
        ratio = [target[key] / (consultant[key][0] + skill * (fellow[key][0] - consultant[key][0]))
                 for skill, target in draws]
        assert np.mean(ratio) == pytest.approx(1.0, abs=0.02), key
    slow = np.median([t["speed_mm_per_s"] for s, t in draws if s < 0.1])
    fast = np.median([t["speed_mm_per_s"] for s, t in draws if s > 0.9])
    assert slow == pytest.approx(12.9, rel=0.1) and fast == pytest.approx(24.6, rel=0.1)


def test_a_tilt_limit_the_figures_cannot_meet_is_one_line(grasps):
    with pytest.raises(RunFailedError, match="within dataset.scan.max_tilt_deg 0.01 deg in none"):
        scan_motion(grasps.placements[0], grasps.probe, ScanMotionSpec(max_tilt_deg=0.01),
                    np.random.default_rng(0))


@pytest.mark.parametrize("field, value, message", [
    ("duration_s", (10.0, 5.0), "dataset.scan.duration_s must be two numbers"),
    ("fps", 0, "dataset.scan.fps must be a finite number"),
    ("tilt_share", (0.5, 1.5), "dataset.scan.tilt_share must be two numbers"),
    ("max_tilt_deg", 90, "dataset.scan.max_tilt_deg must be a finite number"),
    ("press_m", 0.01, "dataset.scan.press_m must be a finite number"),
])
def test_bad_spec_values_are_refused_naming_the_key(field, value, message):
    with pytest.raises(BadValueError, match=message):
        ScanMotionSpec(**{field: value})



def test_moves_that_sink_the_hand_into_the_patient_are_drawn_again(grasps):
    """A keep-out vertex 5 mm inside the skin under the lens sinks in every draw: the clip fails in one line naming
    the contact; the grasp's own hand and forearm (built as the renderer builds them) keep out of the body."""
    g = GRASPS[0]
    placement = grasps.placements[g]
    inside = np.array([[0.0, 0.0, 0.0]]) - 0.005 * placement.normal_world
    with pytest.raises(RunFailedError, match="with the probe, hand and forearm out of the body .*kinematics met"):
        scan_motion(placement, grasps.probe, ScanMotionSpec(duration_s=(1.0, 1.0)), np.random.default_rng(0),
                    keep_out=inside)
