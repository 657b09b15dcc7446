import math

import numpy as np
import pytest

from datagen.camera import Intrinsics, project_points
from datagen.geometry import transform_points
from datagen.sphere import SphereSpec, all_viewpoints, camera_pose, latitude_count, sphere_frame, viewpoints


def test_published_counts_92_and_90():
    spec = SphereSpec()
    assert latitude_count(spec) == 9
    angles = all_viewpoints(spec)
    assert len(angles) == 92
    rings = [int(np.sum(np.isclose(angles[:, 0], i * math.pi / 9))) for i in range(1, 9)]
    assert rings == [5, 10, 14, 16, 16, 14, 10, 5]
    ids, kept = viewpoints(spec)
    assert len(ids) == 90 and 0 not in ids and 91 not in ids
    assert np.all((kept[:, 0] > 0) & (kept[:, 0] < math.pi))


def test_paper_floor_variant():
    spec = SphereSpec(variant="floor")
    assert latitude_count(spec) == 8
    assert len(all_viewpoints(spec)) == 82
    assert len(viewpoints(spec)[0]) == 80


def test_exclusions_are_configurable():
    assert len(viewpoints(SphereSpec(exclude=()))[0]) == 92
    ids, _ = viewpoints(SphereSpec(exclude=(3, 50)))
    assert len(ids) == 90 and 3 not in ids and 50 not in ids
    with pytest.raises(ValueError, match="exclude id 92 is not a view"):
        viewpoints(SphereSpec(exclude=(92,)))


@pytest.mark.parametrize("kwargs, message", [
    (dict(r_circ_m=0.8), "must be smaller than r_sph_m"),
    (dict(r_circ_m=1.0), "must be smaller than r_sph_m"),
    (dict(r_sph_m=-1.0), "r_sph_m must be positive"),
    (dict(variant="round"), "variant must be one of"),
])
def test_bad_sphere(kwargs, message):
    with pytest.raises(ValueError, match=message):
        SphereSpec(**kwargs)


def test_cameras_look_at_the_target_at_every_view_including_poles():
    K = Intrinsics(480.0, 480.0, 128.0, 128.0, 256, 256).K
    frame = sphere_frame(np.array([-1.0, 0.2, 0.1]), np.array([0.0, 1.0, 0.0]))
    np.testing.assert_allclose(frame.T @ frame, np.eye(3), atol=1e-12)
    target = np.array([0.01, 0.02, 0.09])
    for theta, phi in all_viewpoints(SphereSpec()):
        T = camera_pose(theta, phi, 0.5, target, frame)
        assert np.all(np.isfinite(T))
        cam = transform_points(T, target[None])[0]
        np.testing.assert_allclose(cam, [0.0, 0.0, 0.5], atol=1e-12)
    # at the poles the dorsal direction (longitude 0) is up in the image
    for theta in (0.0, math.pi):
        T = camera_pose(theta, 0.0, 0.5, target, frame)
        up_point = project_points(transform_points(T, (target + 0.05 * frame[:, 0])[None]), K)[0]
        assert up_point[1] < 128.0 - 1.0 and abs(up_point[0] - 128.0) < 1e-6
    # elsewhere the fingers (-north) point up in the image
    T = camera_pose(math.pi / 2, 1.0, 0.5, target, frame)
    finger_point = project_points(transform_points(T, (target - 0.05 * frame[:, 2])[None]), K)[0]
    assert finger_point[1] < 128.0 - 1.0
