import numpy as np
import pytest

from hupbench.datagen.assets.arm import ArmSpec, forearm_mesh, wrist_rotation
from hupbench.core.geometry import axis_angle_to_matrix


def _axis(mesh, wrist):
    """Unit direction from the wrist to the far end cap centre."""
    far = mesh.vertices[-1]  # the far cap's centre vertex
    return (far - wrist) / np.linalg.norm(far - wrist)


def test_forearm_is_closed_and_attached_at_the_wrist():
    wrist = np.array([0.1, -0.2, 0.3])
    mesh = forearm_mesh(np.eye(3), wrist)
    assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0
    # neutral wrist: the forearm leaves along the hand's -x axis
    np.testing.assert_allclose(_axis(mesh, wrist), [-1.0, 0.0, 0.0], atol=1e-12)
    # its near end reaches into the hand by the overlap, centred on the wrist
    near = mesh.vertices[-2]
    np.testing.assert_allclose(near, wrist + [ArmSpec().overlap_m, 0.0, 0.0], atol=1e-12)
    length = np.linalg.norm(mesh.vertices[-1] - wrist)
    assert length == pytest.approx(ArmSpec().length_m, abs=1e-12)


def test_forearm_follows_hand_rotation_and_wrist_angles():
    R_world_hand = axis_angle_to_matrix(np.array([0.3, -1.1, 0.4]))
    wrist = np.zeros(3)
    neutral = forearm_mesh(R_world_hand, wrist)
    np.testing.assert_allclose(_axis(neutral, wrist), R_world_hand @ [-1.0, 0.0, 0.0], atol=1e-12)
    # 30 degrees of flexion closes the angle between palm and forearm: in the hand frame
    # the forearm tilts palmar (-y), 30 degrees off -x
    flexed = forearm_mesh(np.eye(3), wrist, flexion=np.deg2rad(30.0))
    np.testing.assert_allclose(_axis(flexed, wrist), [-np.cos(np.pi / 6), -np.sin(np.pi / 6), 0.0], atol=1e-12)
    np.testing.assert_allclose(wrist_rotation(0.0, 0.0), np.eye(3), atol=1e-15)


@pytest.mark.parametrize("change", [dict(length_m=0.0), dict(wrist_width_m=float("nan")), dict(segments_around=4)])
def test_an_arm_spec_out_of_its_range_is_a_bug(change):
    """No config node builds an ArmSpec: a value out of range is the caller's bug (an assert), not bad input."""
    with pytest.raises(AssertionError):
        ArmSpec(**change)
