"""The fingers adjusting over a clip: a minimum-jerk move out to a loosened grasp and back, the thumb and the
frames outside every adjustment at the grasp's pose exactly, no joint past its extension limit, and adjustments
that would sink the hand into the probe or the patient not made."""

import numpy as np
import pytest

from hupbench.core.errors import BadValueError
from hupbench.datagen.assets.hand import build_hand
from hupbench.datagen.assets.hand_anatomy import joint_limits_rad, pose_to_anatomical
from hupbench.datagen.dataset.finger_motion import FingerMotionSpec, finger_motion, finger_poses, min_jerk
from hupbench.datagen.dataset.grasps_file import CLINIC_GRASPS, GraspSet

FPS = 30.0
TIME = np.arange(151) / FPS
ADJUSTMENT = {"fingers": ["index", "ring"], "start_s": 1.0, "move_s": 0.5, "hold_s": 0.4,
              "open_deg": [[10.0, 15.0, 5.0], [8.0, 8.0, 8.0]]}


@pytest.fixture(scope="module")
def grasps():
    return GraspSet(CLINIC_GRASPS)


def test_min_jerk_rises_from_0_to_1_with_zero_speed_and_acceleration_at_both_ends():
    s = np.linspace(-0.5, 1.5, 2001)
    y = min_jerk(s)
    assert y[s <= 0].max() == 0.0 and y[s >= 1].min() == 1.0 and np.all(np.diff(y) >= 0)
    h = 1e-4
    for end in (0.0, 1.0):
        speed = (min_jerk(np.array([end + h])) - min_jerk(np.array([end - h])))[0] / (2 * h)
        acceleration = (min_jerk(np.array([end + h])) - 2 * min_jerk(np.array([end])) + min_jerk(
            np.array([end - h])))[0] / h ** 2
        assert abs(speed) < 1e-6 and abs(acceleration) < 1e-2
    assert min_jerk(np.array([0.5]))[0] == pytest.approx(0.5)


def test_finger_poses_loosen_only_the_named_fingers_and_hold_the_grasp_outside(grasps):
    pose = grasps.hand_pose[7]
    poses = finger_poses(pose, [ADJUSTMENT], TIME)
    outside = (TIME <= 1.0) | (TIME >= 1.0 + 2 * 0.5 + 0.4)
    assert (poses[outside] == pose).all()  # exactly the grasp's
    angles, angles0 = pose_to_anatomical(poses), pose_to_anatomical(pose)
    held = (TIME >= 1.5) & (TIME <= 1.9)
    want = angles0[None].repeat(held.sum(), axis=0)
    want[:, 0:3, 0] -= np.deg2rad(ADJUSTMENT["open_deg"][0])  # index: MANO joints 1-3
    want[:, 9:12, 0] -= np.deg2rad(ADJUSTMENT["open_deg"][1])  # ring: MANO joints 10-12
    np.testing.assert_allclose(angles[held], want, atol=1e-9)
    np.testing.assert_array_equal(poses[:, :3], np.broadcast_to(pose[:3], (len(TIME), 3)))
    # the flexion moves no faster than the minimum-jerk profile's peak, 15/8 of the amplitude over the move
    step = np.abs(np.diff(angles[:, 1, 0]))
    assert 0 < step.max() <= 15 / 8 * np.deg2rad(15.0) / 0.5 / FPS * (1 + 1e-6)


def test_finger_motion_draws_adjustments_that_fit_the_clip_within_the_joint_limits(grasps):
    g = 11
    hand, trans = build_hand(grasps.hand_spec(g)), grasps.hand_trans[g]
    far = np.eye(4)
    far[2, 3] = 10.0  # the body 10 m away: nothing to sink into
    spec = FingerMotionSpec(rate_hz=2.0, open_deg=(30.0, 40.0))
    draw = lambda seed: finger_motion(spec, grasps.hand_pose[g], lambda p: hand.vertices(p, trans),  # noqa: E731
                                      grasps.probe, 0.3, np.repeat(far[None], len(TIME), axis=0), TIME,
                                      np.random.default_rng(seed))
    adjustments = draw(0)
    assert len(adjustments) >= 2 and adjustments == draw(0)
    ends = [a["start_s"] + 2 * a["move_s"] + a["hold_s"] for a in adjustments]
    assert all(a["start_s"] >= e for a, e in zip(adjustments[1:], ends[:-1])) and ends[-1] <= TIME[-1]
    assert all(1 <= len(a["fingers"]) <= 2 and "thumb" not in a["fingers"] for a in adjustments)
    angles = pose_to_anatomical(finger_poses(grasps.hand_pose[g], adjustments, TIME))
    assert (angles[..., 0] >= joint_limits_rad()[:, 0, 0] - 1e-9).all()  # no joint past its extension limit


class _Probe:
    """A stand-in probe whose surface the grasp's hand touches at each of its vertices: a vertex that has moved is
    ``depth`` inside it (negative: outside)."""

    def __init__(self, vertices, depth):
        self.vertices, self.depth = vertices, depth

    def signed_distance(self, points):
        moved = np.linalg.norm(np.asarray(points) - self.vertices, axis=-1) > 1e-9
        return np.where(moved, -self.depth, 0.0)


def test_an_adjustment_that_sinks_the_hand_into_the_probe_or_the_patient_is_not_made(grasps):
    g = 11
    hand, trans, pose = build_hand(grasps.hand_spec(g)), grasps.hand_trans[g], grasps.hand_pose[g]
    vertices = lambda p: hand.vertices(p, trans)  # noqa: E731
    own = vertices(pose[None])[0]
    spec = FingerMotionSpec(rate_hz=2.0)
    far, near = np.eye(4), np.eye(4)
    far[2, 3] = 10.0
    near[2, 3] = -trans[2] - 0.5  # the wrist 0.5 m below the bed's top (body z = 0): every hand vertex below it
    body = lambda T: np.repeat(T[None], len(TIME), axis=0)  # noqa: E731
    rng = lambda: np.random.default_rng(0)  # noqa: E731
    assert finger_motion(spec, pose, vertices, _Probe(own, -0.01), 0.3, body(far), TIME, rng())
    assert finger_motion(spec, pose, vertices, _Probe(own, 0.0004), 0.3, body(far), TIME, rng())  # within the slack
    assert finger_motion(spec, pose, vertices, _Probe(own, 0.001), 0.3, body(far), TIME, rng()) == []
    assert finger_motion(spec, pose, vertices, _Probe(own, -0.01), 0.3, body(near), TIME, rng()) == []
    assert finger_motion(FingerMotionSpec(rate_hz=0.0), pose, vertices, grasps.probe, 0.3, body(far), TIME,
                         rng()) == []


@pytest.mark.parametrize("field, value, message", [
    ("rate_hz", -1.0, "dataset.fingers.rate_hz"), ("open_deg", (20.0, 5.0), "dataset.fingers.open_deg"),
    ("move_s", (0.0, 0.1), "dataset.fingers.move_s"), ("max_fingers", 5, "dataset.fingers.max_fingers")])
def test_a_bad_finger_spec_is_refused_naming_its_field(field, value, message):
    with pytest.raises(BadValueError, match=message):
        FingerMotionSpec(**{field: value})
