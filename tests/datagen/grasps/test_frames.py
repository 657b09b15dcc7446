import numpy as np
import pytest
import trimesh

from hupbench.core.geometry import invert_transform, transform_points
from hupbench.datagen.grasps.frames import T_gen_probe, check_euler_deg, probe_z_offset, volume_centroid
from hupbench.datagen.grasps.approach import to_generator_frame
from hupbench.datagen.grasps.refine import GraspBatch
from hupbench.datagen.assets.hand import build_hand
from hupbench.datagen.assets.hand_anatomy import anatomical_to_pose
from hupbench.core.geometry import matrix_to_axis_angle
from hupbench.datagen.assets.probe import build_probe


@pytest.fixture(scope="module")
def probe():
    return build_probe()


def test_volume_centroid_matches_trimesh():
    box = trimesh.creation.box(extents=(0.1, 0.2, 0.3))
    box.apply_translation([0.01, -0.02, 0.5])
    np.testing.assert_allclose(volume_centroid(box.vertices, box.faces), [0.01, -0.02, 0.5], atol=1e-12)


def test_probe_z_offset_is_the_mesh_centroid_height(probe):
    dz = probe_z_offset(probe)
    np.testing.assert_allclose(dz, probe.mesh.center_mass[2], atol=1e-9)
    # the centroid sits inside the body, between the lens and the cable end
    assert 0.03 < dz < 0.12
    # on the long axis, up to the orientation marker on the +x end, which moves the centroid 0.06 mm
    # towards +x (the generator frame keeps it on the axis, (0, 0, dz))
    np.testing.assert_allclose(probe.mesh.center_mass[1], 0.0, atol=1e-9)
    assert 0.0 < probe.mesh.center_mass[0] < 0.1e-3


def test_generator_frame_centres_the_rotated_probe(probe):
    T = T_gen_probe([30.0, -50.0, 110.0], probe)
    centroid_probe = np.array([0.0, 0.0, probe_z_offset(probe)])
    np.testing.assert_allclose(transform_points(T, centroid_probe[None])[0], 0.0, atol=1e-12)
    np.testing.assert_allclose(T_gen_probe([0, 0, 0], probe), T_gen_probe([360, 360, -360], probe), atol=1e-12)
    for pitch in (90.0, -90.0):  # gimbal lock of intrinsic x-y-z: still a proper rotation
        R = T_gen_probe([25.0, pitch, 40.0], probe)[:3, :3]
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)


def test_paper_z_offset_correction_at_zero_orientation(probe):
    """At Theta_Vol = 0 going from the generator to the renderer frame adds (0, 0, Delta z) to the hand."""
    rng = np.random.default_rng(0)
    gen = GraspBatch(np.broadcast_to(np.eye(3), (2, 3, 3)).copy(), rng.normal(size=(2, 3)) * 0.05,
                     np.zeros((2, 15, 3)))
    probe_frame = to_generator_frame(gen, invert_transform(T_gen_probe([0, 0, 0], probe)))
    np.testing.assert_allclose(probe_frame.trans, gen.trans + [0.0, 0.0, probe_z_offset(probe)], atol=1e-12)
    np.testing.assert_allclose(probe_frame.R_global, gen.R_global, atol=1e-12)


def test_frame_change_moves_the_hand_rigidly(probe):
    hand = build_hand()
    rng = np.random.default_rng(1)
    angles = rng.uniform(0.0, 0.5, size=(1, 15, 3)) * [1, 0.1, 0.1]
    from hupbench.core.geometry import axis_angle_to_matrix

    grasp = GraspBatch(axis_angle_to_matrix(rng.normal(size=(1, 3))), rng.normal(size=(1, 3)) * 0.05, angles)
    T = T_gen_probe([10.0, 80.0, -30.0], probe)
    gen = to_generator_frame(grasp, T)
    pose = lambda g: anatomical_to_pose(g.angles[0], matrix_to_axis_angle(g.R_global[0]))  # noqa: E731
    k_probe = hand.keypoints(pose(grasp), grasp.trans[0], clamp=False)
    k_gen = hand.keypoints(pose(gen), gen.trans[0], clamp=False)
    np.testing.assert_allclose(k_gen, transform_points(T, k_probe), atol=1e-12)
    back = to_generator_frame(gen, invert_transform(T))
    np.testing.assert_allclose(back.trans, grasp.trans, atol=1e-12)
    np.testing.assert_allclose(back.R_global, grasp.R_global, atol=1e-12)


@pytest.mark.parametrize("bad", [[0, 0], [[0, 0, 0], [1, 2]], [[0, np.nan, 0]], "abc", [[0, 0, 400]]])
def test_malformed_euler_angles_are_rejected(bad):
    with pytest.raises(ValueError, match="Theta_Vol"):
        check_euler_deg(bad)
