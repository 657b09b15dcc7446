import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from hupbench.core.camera import Intrinsics, look_at, project_points, swap_gl_cv_axes
from hupbench.core.geometry import make_transform, transform_points


def test_hup3d_lens_gives_paper_intrinsics():
    K = Intrinsics.from_lens(60.0, 32.0, 256, 256).K
    np.testing.assert_allclose(K, [[480, 0, 128], [0, 480, 128], [0, 0, 1]])


@pytest.mark.parametrize("size", [(0, 256), (256, -1), (256.0, 256)])
def test_bad_image_size_raises(size):
    with pytest.raises(ValueError, match="image (width|height) must be a whole number >= 1"):
        Intrinsics(480.0, 480.0, 128.0, 128.0, *size)


@pytest.mark.parametrize("values, message", [
    ((0.0, 480.0, 128.0, 128.0), "focal length fx must be positive and finite, got 0.0"),
    ((480.0, float("nan"), 128.0, 128.0), "focal length fy must be positive and finite, got nan"),
    ((480.0, 480.0, float("inf"), 128.0), "principal point cx must be finite, got inf"),
])
def test_bad_focal_or_principal_point_raises(values, message):
    with pytest.raises(ValueError, match=message):
        Intrinsics(*values, 256, 256)


def test_from_lens():
    assert Intrinsics.from_lens(60.0, 32.0, 256, 256).K.tolist() == [[480.0, 0.0, 128.0], [0.0, 480.0, 128.0],
                                                                     [0.0, 0.0, 1.0]]
    with pytest.raises(ValueError, match="focal_mm must be a finite number > 0, got 0.0"):
        Intrinsics.from_lens(0.0, 32.0, 256, 256)


def test_projection_matches_opencv():
    rng = np.random.default_rng(0)
    K = np.array([[480.0, 0.0, 128.0], [0.0, 470.0, 120.5], [0.0, 0.0, 1.0]])
    points_world = rng.uniform(-0.2, 0.2, size=(500, 3))
    R = Rotation.random(random_state=1).as_matrix()
    T_cam_world = make_transform(R, R @ -np.array([0.0, 0.0, 0.0]) + np.array([0.01, -0.02, 0.7]))
    ours = project_points(transform_points(T_cam_world, points_world), K)
    rvec, _ = cv2.Rodrigues(R)
    theirs, _ = cv2.projectPoints(points_world, rvec, T_cam_world[:3, 3], K, None)
    np.testing.assert_allclose(ours, theirs.reshape(-1, 2), atol=1e-3)


def test_points_at_or_behind_camera():
    K = Intrinsics(480.0, 480.0, 128.0, 128.0, 256, 256).K
    points = np.array([[0.0, 0.0, 1.0], [0.1, 0.0, 0.0], [0.0, 0.1, -0.5]])
    with pytest.raises(ValueError, match=r"2 point\(s\) at or behind the camera plane"):
        project_points(points, K)
    uv = project_points(points, K, behind="nan")
    np.testing.assert_allclose(uv[0], [128.0, 128.0])
    assert np.isnan(uv[1:]).all()


def test_look_at_centres_target_and_keeps_up():
    K = Intrinsics(480.0, 480.0, 128.0, 128.0, 256, 256).K
    target = np.array([0.05, -0.02, 0.1])
    T = look_at(np.array([0.6, 0.3, 0.4]), target, up_world=(0, 0, 1))
    np.testing.assert_allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-12)
    assert np.linalg.det(T[:3, :3]) == pytest.approx(1.0)
    uv = project_points(transform_points(T, target[None]), K)[0]
    np.testing.assert_allclose(uv, [128.0, 128.0], atol=1e-9)
    # a point above the target appears higher in the image (smaller v)
    above = project_points(transform_points(T, (target + [0, 0, 0.05])[None]), K)[0]
    assert above[1] < 128.0 - 1.0


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_look_at_at_the_poles_is_defined(sign):
    target = np.zeros(3)
    T = look_at(np.array([0.0, 0.0, sign * 0.8]), target, up_world=(0, 0, 1))
    assert np.all(np.isfinite(T))
    np.testing.assert_allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(transform_points(T, target[None])[0], [0.0, 0.0, 0.8], atol=1e-12)
    # the fallback up is the world x axis (least aligned with the view), so +x appears up in the image
    K = Intrinsics(480.0, 480.0, 128.0, 128.0, 256, 256).K
    uv = project_points(transform_points(T, np.array([[0.05, 0.0, 0.0]])), K)[0]
    assert uv[1] < 128.0 - 1.0 and abs(uv[0] - 128.0) < 1e-6


def test_gl_cv_swap_is_an_involution_with_known_axes():
    rng = np.random.default_rng(2)
    T_world_cam = make_transform(Rotation.random(random_state=3).as_matrix(), rng.normal(size=3))
    np.testing.assert_allclose(swap_gl_cv_axes(swap_gl_cv_axes(T_world_cam)), T_world_cam, atol=1e-15)
    # a point 1 m in front of the OpenCV camera is at z = -1 in the OpenGL camera frame
    T_world_gl = swap_gl_cv_axes(T_world_cam)
    p_world = transform_points(T_world_cam, np.array([[0.1, 0.2, 1.0]]))
    p_gl = transform_points(np.linalg.inv(T_world_gl), p_world)[0]
    np.testing.assert_allclose(p_gl, [0.1, -0.2, -1.0], atol=1e-12)


def test_resize_with_padding_keeps_projections_consistent():
    from hupbench.core.camera import resize_intrinsics, resize_points

    K = np.array([[480.0, 0.0, 128.0], [0.0, 470.0, 100.0], [0.0, 0.0, 1.0]])
    points = np.array([[0.01, -0.02, 0.5], [0.1, 0.05, 0.8], [-0.07, 0.0, 0.6]])

    def project(K_, p):
        uvw = p @ K_.T
        return uvw[:, :2] / uvw[:, 2:]

    for scale, offset in ((0.5, (0.0, 0.0)), (0.37, (20.0, 0.0)), (2.0, (3.0, 11.0))):
        moved = resize_points(project(K, points), scale, offset)
        np.testing.assert_allclose(moved, project(resize_intrinsics(K, scale, offset), points), atol=1e-9)
    # pixel centres at integers: the image's outer edge -0.5 stays the edge after resizing
    np.testing.assert_allclose(resize_points(np.array([-0.5, -0.5]), 0.25), [-0.5, -0.5])
