import numpy as np
import pytest
import trimesh

from hupbench.core import keypoints as kp
from hupbench.core.geometry import axis_angle_to_matrix
from hupbench.datagen.assets.hand import build_hand, forward_kinematics
from hupbench.datagen.assets.hand_anatomy import (
    POSE_DIM,
    HandSpec,
    anatomical_frames,
    anatomical_to_pose,
    clamp_pose,
    joint_limits_rad,
    pose_to_anatomical,
)

# an adult hand of about the 50th percentile (Pheasant and Haslegrave, Bodyspace, 3rd ed., 2006), mm: wrist->MCP,
# proximal, middle, distal (DIP->tip), written out here so that a change of the model's table shows
REFERENCE_FINGERS_MM = {
    "index": (85, 46, 27, 18),
    "middle": (84, 50, 32, 20),
    "ring": (77, 46, 31, 20),
    "little": (70, 39, 22, 18),
}
REFERENCE_THUMB_MM = {"cmc": (22, 22), "metacarpal": (36, 47), "proximal": (31, 37), "distal": (27, 30)}
MANO_INDEX_MCP, MANO_INDEX_PIP = 1, 2


@pytest.fixture(scope="module")
def hand():
    return build_hand()


def _length_mm(points, a, b):
    return 1000.0 * np.linalg.norm(points[a] - points[b])


def test_rest_bone_lengths_match_reference(hand):
    k = hand.keypoints_rest
    for finger, lengths in REFERENCE_FINGERS_MM.items():
        start = kp.FINGER_START[finger]
        chain = [0, start, start + 1, start + 2, start + 3]
        for (a, b), expected in zip(zip(chain, chain[1:]), lengths):
            assert _length_mm(k, a, b) == pytest.approx(expected, abs=1.0), (finger, a, b)
    t = kp.FINGER_START["thumb"]
    for (a, b), (lo, hi) in zip([(0, t), (t, t + 1), (t + 1, t + 2), (t + 2, t + 3)], REFERENCE_THUMB_MM.values()):
        assert lo - 1.0 <= _length_mm(k, a, b) <= hi + 1.0


def test_size_parameter_scales_lengths():
    small = build_hand(HandSpec(scale=0.9, voxel_m=0.002))
    k_ref, k_small = build_hand().keypoints_rest, small.keypoints_rest
    np.testing.assert_allclose(k_small, 0.9 * k_ref, atol=1e-12)


@pytest.mark.parametrize("change", [dict(scale=3.0), dict(scale=float("nan")), dict(voxel_m=0.01),
                                    dict(max_faces=10)])
def test_a_hand_spec_out_of_its_range_is_a_bug(change):
    """No config node builds a HandSpec: a value out of range is the caller's bug (an assert), not bad input."""
    with pytest.raises(AssertionError):
        HandSpec(**change)


def test_flexing_index_mcp_90_degrees_points_finger_into_palm(hand):
    angles = np.zeros((15, 3))
    angles[MANO_INDEX_MCP - 1, 0] = np.pi / 2
    posed = hand.keypoints(anatomical_to_pose(angles), np.zeros(3))
    rest = hand.keypoints_rest
    mcp = kp.FINGER_START["index"]
    # the index finger lies in the palm plane (y = 0) at rest, so a 90 degree flexion about
    # its MCP points the whole finger straight palmar (-y), lengths kept
    length = sum(REFERENCE_FINGERS_MM["index"][1:]) / 1000.0
    np.testing.assert_allclose(posed[mcp + 3], rest[mcp] + np.array([0.0, -length, 0.0]), atol=2e-4)
    for k in (1, 2, 3):
        expected = rest[mcp] + np.array([0.0, -np.linalg.norm(rest[mcp + k] - rest[mcp]), 0.0])
        np.testing.assert_allclose(posed[mcp + k], expected, atol=1e-9)
    # nothing else moves
    others = [i for i in range(21) if not mcp < i <= mcp + 3]
    np.testing.assert_allclose(posed[others], rest[others], atol=1e-12)


def test_flexing_pip_90_degrees_rotates_children_about_the_pip(hand):
    angles = np.zeros((15, 3))
    angles[MANO_INDEX_PIP - 1, 0] = np.pi / 2
    posed = hand.keypoints(anatomical_to_pose(angles), np.zeros(3))
    rest = hand.keypoints_rest
    pip = kp.FINGER_START["index"] + 1
    axis = anatomical_frames()[MANO_INDEX_PIP - 1][:, 0]
    R = axis_angle_to_matrix(axis * np.pi / 2)
    for child in (pip + 1, pip + 2):
        np.testing.assert_allclose(posed[child], rest[pip] + R @ (rest[child] - rest[pip]), atol=1e-12)
        # the child now sits at a right angle to the proximal phalanx
        u, v = rest[pip] - rest[pip - 1], posed[child] - posed[pip]
        assert abs(u @ v) / (np.linalg.norm(u) * np.linalg.norm(v)) < 1e-9


def test_global_rotation_and_translation_move_everything_rigidly(hand):
    rng = np.random.default_rng(0)
    pose = np.zeros(POSE_DIM)
    pose[:3] = rng.normal(size=3)
    trans = rng.normal(size=3)
    R = axis_angle_to_matrix(pose[:3])
    np.testing.assert_allclose(hand.keypoints(pose, trans), hand.keypoints_rest @ R.T + trans, atol=1e-12)
    np.testing.assert_allclose(hand.vertices(pose, trans), hand.vertices_rest @ R.T + trans, atol=1e-12)


def test_anatomical_round_trip_within_limits():
    rng = np.random.default_rng(1)
    limits = joint_limits_rad()
    angles = rng.uniform(limits[..., 0], limits[..., 1], size=(8, 15, 3))
    pose = anatomical_to_pose(angles, rng.normal(size=(8, 3)))
    np.testing.assert_allclose(pose_to_anatomical(pose), angles, atol=1e-9)
    np.testing.assert_allclose(clamp_pose(pose), pose, atol=1e-12)


def test_joint_limits_are_clamped(hand):
    angles = np.zeros((15, 3))
    angles[MANO_INDEX_PIP - 1, 0] = np.deg2rad(150.0)  # beyond PIP 105
    angles[2, 0] = np.deg2rad(-40.0)  # index DIP hyperextended, limit 0
    clamped = pose_to_anatomical(clamp_pose(anatomical_to_pose(angles)))
    assert np.rad2deg(clamped[MANO_INDEX_PIP - 1, 0]) == pytest.approx(105.0, abs=1e-6)
    assert np.rad2deg(clamped[2, 0]) == pytest.approx(0.0, abs=1e-6)
    # keypoints() clamps by default: the pose out of limits gives the clamped keypoints
    np.testing.assert_allclose(
        hand.keypoints(anatomical_to_pose(angles), np.zeros(3)),
        hand.keypoints(anatomical_to_pose(clamped), np.zeros(3)),
        atol=1e-9,
    )


def test_mesh_is_closed_within_budget_and_hand_sized(hand):
    mesh = trimesh.Trimesh(hand.vertices_rest, hand.faces, process=False)
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert len(mesh.faces) <= 8000
    assert mesh.volume > 0
    assert 150e-6 < mesh.volume < 600e-6  # m^3: an adult hand is a few hundred cm^3
    assert len(mesh.split(only_watertight=False)) == 1
    extent_mm = 1000 * (mesh.bounds[1] - mesh.bounds[0])
    assert 170 < extent_mm[0] < 215  # wrist end to the middle fingertip plus the wrist bar
    assert 25 < extent_mm[1] < 60  # palm thickness with knuckles and thenar


def test_fingertips_lie_on_the_surface_and_joints_inside(hand):
    mesh = trimesh.Trimesh(hand.vertices_rest, hand.faces, process=False)
    k = hand.keypoints_rest
    _, dist, _ = trimesh.proximity.closest_point(mesh, k[list(kp.FINGERTIPS)])
    assert dist.max() < 1.5e-3
    inner = [i for i in range(21) if i not in kp.FINGERTIPS]
    assert mesh.contains(k[inner]).all()


def test_skin_weights_are_a_partition_of_unity(hand):
    w = hand.weights
    assert w.shape == (len(hand.vertices_rest), 16)
    assert np.all(w >= 0)
    np.testing.assert_allclose(w.sum(axis=1), 1.0, atol=1e-12)
    # every bone drives some part of the surface on its own
    assert np.all((w > 0.9).sum(axis=0) > 10)


def test_skinned_vertices_follow_their_bones(hand):
    angles = np.zeros((15, 3))
    angles[MANO_INDEX_MCP - 1, 0] = np.deg2rad(70.0)
    angles[MANO_INDEX_PIP - 1, 0] = np.deg2rad(60.0)
    angles[12, :2] = np.deg2rad([30.0, 20.0])  # thumb CMC
    pose = anatomical_to_pose(angles, np.array([0.2, -0.4, 0.1]))
    trans = np.array([0.01, 0.02, 0.3])
    verts = hand.vertices(pose, trans)
    G = forward_kinematics(pose, trans)  # G[j] maps (p - J_j); A[j] maps rest points directly
    A = G.copy()
    A[..., :3, 3] -= np.einsum("...jik,jk->...ji", G[..., :3, :3], hand.joints_rest)
    for bone in (0, MANO_INDEX_MCP, MANO_INDEX_PIP, 13):
        rigid = hand.weights[:, bone] > 1.0 - 1e-9
        assert rigid.sum() > 10
        expected = hand.vertices_rest[rigid] @ A[bone, :3, :3].T + A[bone, :3, 3]
        np.testing.assert_allclose(verts[rigid], expected, atol=1e-12)
    # the index fingertip keypoint stays on the (moved) index fingertip surface
    tip = hand.keypoints(pose, trans)[kp.FINGER_START["index"] + 3]
    assert np.linalg.norm(verts - tip, axis=1).min() < 2.0e-3
