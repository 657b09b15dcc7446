import math

import numpy as np
import pytest

from hupbench.core import keypoints as kp
from hupbench.core.camera import Intrinsics, project_points
from hupbench.core.geometry import axis_angle_to_matrix, invert_transform, transform_points
from hupbench.datagen.dataset.sphere import (
    SphereSpec,
    all_viewpoints,
    arm_frame,
    camera_pose,
    excluded_view_ids,
    latitude_count,
    sphere_frame,
    viewpoints,
)

K = Intrinsics(480.0, 480.0, 128.0, 128.0, 256, 256).K


def _random_arm(seed):
    """A random orthonormal (forearm axis, dorsal) pair and a target, world frame."""
    rng = np.random.default_rng(seed)
    Q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    return Q[:, 0], Q[:, 1], rng.uniform(-0.05, 0.05, size=3)


def _published_views(r_sph=0.8, r_circ=0.15):
    """The published renderer's view list, computed here from its description: the north pole, rings
    i = 1 .. N-1 at theta = i pi / N with floor(2 pi r_sph sin(theta) / (2 r_circ)) views at equal phi
    from 0, the south pole; N = ceil(pi / (2 asin(r_circ / r_sph))). Returns (theta, phi) in degrees."""
    n = math.ceil(math.pi / (2 * math.asin(r_circ / r_sph)))
    out = [(0.0, 0.0)]
    for i in range(1, n):
        theta = 180.0 * i / n
        count = math.floor(2 * math.pi * r_sph * math.sin(math.radians(theta)) / (2 * r_circ))
        out += [(theta, 360.0 * j / count) for j in range(count)]
    return np.array(out + [(180.0, 0.0)])


def _rot_x(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _rot_y(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def test_published_counts_92_and_90():
    spec = SphereSpec()
    assert latitude_count(spec) == 9
    angles = all_viewpoints(spec)
    assert len(angles) == 92
    rings = [int(np.sum(np.isclose(angles[:, 0], i * math.pi / 9))) for i in range(1, 9)]
    assert rings == [5, 10, 14, 16, 16, 14, 10, 5]
    ids, kept = viewpoints(spec)
    # the published renderer keeps both poles and drops two views next to the elbow
    assert len(ids) == 90 and 0 in ids and 91 in ids and 34 not in ids and 50 not in ids


def test_view_list_and_exclusions_match_the_published_renderer():
    expected = _published_views()
    np.testing.assert_allclose(np.degrees(all_viewpoints(SphereSpec())), expected, atol=1e-9)
    # the published renderer turns the body by x = 90 - theta, y = -phi (degrees, intrinsic X then Y)
    # and skips the views with y = 270 and x = 10 or 350: the two 10 deg off the forearm on the elbow side
    x, y = (90.0 - expected[:, 0]) % 360.0, (-expected[:, 1]) % 360.0
    skipped = np.flatnonzero(np.isclose(y, 270.0) & (np.isclose(x, 10.0) | np.isclose(x, 350.0)))
    assert skipped.tolist() == [34, 50]
    assert excluded_view_ids(SphereSpec()) == (34, 50)
    ids, kept = viewpoints(SphereSpec())
    assert ids.tolist() == [i for i in range(92) if i not in (34, 50)]
    np.testing.assert_allclose(np.degrees(kept), np.delete(expected, [34, 50], axis=0), atol=1e-9)


def test_paper_floor_variant():
    spec = SphereSpec(variant="floor")
    assert latitude_count(spec) == 8
    assert len(all_viewpoints(spec)) == 82
    # theta = 90 deg is a ring here, but with 16 views phi = 90 deg lies on the forearm itself (0 deg)
    assert len(viewpoints(spec)[0]) == 81
    assert len(viewpoints(SphereSpec(variant="floor", exclude=("poles",)))[0]) == 80


def test_exclusions_are_configurable():
    assert len(viewpoints(SphereSpec(exclude=()))[0]) == 92
    ids, _ = viewpoints(SphereSpec(exclude=(3, 50)))
    assert len(ids) == 90 and 3 not in ids and 50 not in ids
    with pytest.raises(ValueError, match="exclude id 92 is not a view"):
        viewpoints(SphereSpec(exclude=(92,)))
    # the elbow rule by cone: 25 deg also takes the neighbours at phi = 67.5 and 112.5 deg (24.5 deg off)
    assert excluded_view_ids(SphereSpec(elbow_cone_deg=25.0)) == (33, 34, 35, 49, 50, 51)
    assert excluded_view_ids(SphereSpec(exclude=("elbow", "poles"))) == (0, 34, 50, 91)
    # on the forearm-axis sphere the elbow side is the north pole
    assert excluded_view_ids(SphereSpec(axis="forearm")) == (0,)
    assert excluded_view_ids(SphereSpec(axis="forearm", exclude=("poles",))) == (0, 91)


@pytest.mark.parametrize("kwargs, message", [
    (dict(r_circ_m=0.8), "must be smaller than r_sph_m"),
    (dict(r_circ_m=1.0), "must be smaller than r_sph_m"),
    (dict(r_sph_m=-1.0), "r_sph_m must be a finite number > 0, got -1.0"),
    (dict(variant="round"), "variant must be one of"),
    (dict(axis="vertical"), r"axis must be one of \('body', 'forearm'\), got 'vertical'"),
    (dict(exclude=("hollow",)), "exclude rules are .* got 'hollow'"),
    (dict(exclude=(1.5,)), r"exclude rules are .* \(or view ids\), got 1.5"),
    (dict(exclude=(92,)), r"exclude id 92 is not a view: ids are 0..91"),
    (dict(exclude=("poles", *range(1, 91))), "the sphere exclusions leave no view"),
    (dict(elbow_cone_deg=-1.0), r"elbow_cone_deg must be a finite number in \[0, 180\], got -1.0"),
    (dict(elbow_cone_deg=180.0), "the sphere exclusions leave no view"),
    (dict(elbow_cone_deg=True), r"elbow_cone_deg must be a finite number in \[0, 180\], got True"),
])
def test_bad_sphere(kwargs, message):
    """Refused when the spec is built (the config is checked), view ids and the views left included."""
    with pytest.raises(ValueError, match=message):
        SphereSpec(**kwargs)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_body_sphere_cameras_equal_the_published_body_rotation(seed):
    """Every view, poles included: the published renderer keeps the camera at the origin (Blender axes:
    looking down -z, y up) and turns the SMPL-H body by Rx(90 deg - theta) Ry(-phi), with the right
    middle-finger MCP moved to (0, 0, -z_ego). In the body's axes (x towards the body's left, i.e. from the
    outstretched right hand towards its elbow; y up, the back of the palm-down hand; z to the front) the
    camera then sits at R^T (0, 0, z_ego) from the MCP with image up R^T (0, 1, 0). Ours must agree once
    the body axes are put on the grasp's arm: x = forearm axis, y = dorsal."""
    forearm, dorsal, target = _random_arm(seed)
    body_axes_world = np.stack([forearm, dorsal, np.cross(forearm, dorsal)], axis=1)
    frame = sphere_frame(forearm, dorsal, "body")
    for z_ego in (0.5, 0.8):
        for theta, phi in all_viewpoints(SphereSpec()):
            R = _rot_x(math.pi / 2 - theta) @ _rot_y(-phi)
            direction_world = body_axes_world @ R.T @ np.array([0.0, 0.0, 1.0])
            up_world = body_axes_world @ R.T @ np.array([0.0, 1.0, 0.0])
            T = camera_pose(theta, phi, z_ego, target, frame, "body")
            eye = invert_transform(T)[:3, 3]
            np.testing.assert_allclose((eye - target) / z_ego, direction_world, atol=1e-12)
            np.testing.assert_allclose(-T[1, :3], up_world, atol=1e-12)  # OpenCV y is image down
            # the whole pose: Blender's camera axes to OpenCV's flip y and z
            T_published = np.eye(4)
            T_published[:3, :3] = np.diag([1.0, -1.0, -1.0]) @ R @ body_axes_world.T
            T_published[:3, 3] = np.diag([1.0, -1.0, -1.0]) @ (-R @ body_axes_world.T @ target - [0, 0, z_ego])
            np.testing.assert_allclose(T, T_published, atol=1e-12)
            np.testing.assert_allclose(transform_points(T, target[None])[0], [0.0, 0.0, z_ego], atol=1e-15)


def test_body_sphere_image_up_is_the_back_of_the_hand():
    forearm, dorsal, target = _random_arm(3)
    frame = sphere_frame(forearm, dorsal, "body")
    radial = np.cross(forearm, dorsal)
    for theta, phi in all_viewpoints(SphereSpec()):
        T = camera_pose(theta, phi, 0.5, target, frame, "body")
        assert np.all(np.isfinite(T))
        centre = project_points(transform_points(T, target[None]), K)[0]
        np.testing.assert_allclose(centre, [128.0, 128.0], atol=1e-9)
        up = project_points(transform_points(T, (target + 0.05 * dorsal)[None]), K)[0]
        if 0.0 < theta < math.pi:
            # the dorsal direction (north) points straight up in the image, however far the view is tilted
            assert abs(up[0] - 128.0) < 1e-6 and up[1] < 128.0 - 1.0, (theta, phi, up)
    # at the poles: looking down on the back of the hand the little-finger side is up; from below the thumb
    north = camera_pose(0.0, 0.0, 0.5, target, frame, "body")
    south = camera_pose(math.pi, 0.0, 0.5, target, frame, "body")
    assert project_points(transform_points(north, (target - 0.05 * radial)[None]), K)[0][1] < 128.0 - 1.0
    assert project_points(transform_points(south, (target + 0.05 * radial)[None]), K)[0][1] < 128.0 - 1.0
    # on the equator at phi = 90 deg the camera sits on the forearm, elbow side
    eye = invert_transform(camera_pose(math.pi / 2, math.pi / 2, 0.5, target, frame, "body"))[:3, 3]
    np.testing.assert_allclose((eye - target) / 0.5, forearm, atol=1e-12)


def test_arm_frame_third_axis_is_the_thumb_side_of_our_right_hand():
    from hupbench.datagen.assets.hand import build_hand

    hand = build_hand()
    pose = np.zeros(48)
    pose[:3] = [0.3, -1.1, 0.7]
    R = axis_angle_to_matrix(pose[:3])
    frame = arm_frame(-R[:, 0], R[:, 1])
    np.testing.assert_allclose(frame.T @ frame, np.eye(3), atol=1e-12)
    assert np.linalg.det(frame) == pytest.approx(1.0)
    joints = hand.keypoints(pose[None], np.zeros((1, 3)))[0]
    thumb = joints[kp.KEYPOINT_NAMES.index("thumb_mcp")] - joints[kp.KEYPOINT_NAMES.index("middle_mcp")]
    little = joints[kp.KEYPOINT_NAMES.index("little_mcp")] - joints[kp.KEYPOINT_NAMES.index("middle_mcp")]
    assert thumb @ frame[:, 2] > 0.02 and little @ frame[:, 2] < -0.02


def test_forearm_sphere_keeps_the_earlier_cameras():
    frame = sphere_frame(np.array([-1.0, 0.2, 0.1]), np.array([0.0, 1.0, 0.0]), "forearm")
    np.testing.assert_allclose(frame.T @ frame, np.eye(3), atol=1e-12)
    target = np.array([0.01, 0.02, 0.09])
    for theta, phi in all_viewpoints(SphereSpec()):
        T = camera_pose(theta, phi, 0.5, target, frame, "forearm")
        assert np.all(np.isfinite(T))
        cam = transform_points(T, target[None])[0]
        np.testing.assert_allclose(cam, [0.0, 0.0, 0.5], atol=1e-12)
    # at the poles the dorsal direction (longitude 0) is up in the image
    for theta in (0.0, math.pi):
        T = camera_pose(theta, 0.0, 0.5, target, frame, "forearm")
        up_point = project_points(transform_points(T, (target + 0.05 * frame[:, 0])[None]), K)[0]
        assert up_point[1] < 128.0 - 1.0 and abs(up_point[0] - 128.0) < 1e-6
    # elsewhere the fingers (-north) point up in the image
    T = camera_pose(math.pi / 2, 1.0, 0.5, target, frame, "forearm")
    finger_point = project_points(transform_points(T, (target - 0.05 * frame[:, 2])[None]), K)[0]
    assert finger_point[1] < 128.0 - 1.0
    # north is the elbow, longitude 0 the back of the hand
    eye = invert_transform(camera_pose(0.0, 0.0, 0.5, target, frame, "forearm"))[:3, 3]
    np.testing.assert_allclose((eye - target) / 0.5, frame[:, 2], atol=1e-12)
    assert frame[:, 2] @ np.array([-1.0, 0.2, 0.1]) > 0
