"""The fits read a model's segmentation: the patient's skin under the probe is used by neither fit, checked against the
mask, and the probe's fit lands where the probe is although the skin touches its lens."""

import numpy as np
import pytest
import trimesh

from hupbench.core import keypoints as kp
from hupbench.core.contract import SEGMENT_CLASSES
from hupbench.datagen.assets.probe import build_probe
from hupbench.datagen.render.scene import PROBE_BODY_RGB, PROBE_MARKER_RGB
from hupbench.fits import after_network
from hupbench.fits import depth_points as D
from hupbench.fits import hand_fit, probe_fit

S = 128
K = np.array([[240.0, 0.0, 63.75], [0.0, 240.0, 63.75], [0.0, 0.0, 1.0]])
OTHER, HAND, PROBE = (SEGMENT_CLASSES.index(name) for name in ("other", "hand", "probe"))
#: a finger (a 9 mm cylinder along the probe's x) across the probe's -y side, 2.5 cm above the skin, probe frame
FINGER = np.array([0.0, -0.03, 0.025])


def probe_pose():
    """The probe standing on the skin, its cable end up and towards the camera, its marker side in view."""
    z = np.array([0.2, -0.6, -0.5])
    z /= np.linalg.norm(z)
    x = np.array([0.3, 0.2, -1.0]) - np.dot([0.3, 0.2, -1.0], z) * z
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z]), np.array([0.0, 0.03, 0.6])


def scene():
    """(4, S, S) model image of the probe (its marker in the marker's colour) with a finger across it near the lens,
    pressed on a skin plane through its lens
    apex (perpendicular to its long axis), and the true (S, S) classes: probe, hand (the finger), other (the skin)."""
    R, t = probe_pose()
    probe = build_probe()
    cylinder = trimesh.creation.cylinder(radius=0.009, height=0.09, sections=24)
    along_x = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])
    finger = cylinder.vertices @ along_x.T + FINGER
    meshes = [trimesh.Trimesh(probe.mesh.vertices @ R.T + t, probe.mesh.faces, process=False),
              trimesh.Trimesh(finger @ R.T + t, cylinder.faces, process=False)]
    face_class = np.concatenate([np.full(len(probe.mesh.faces), PROBE), np.full(len(cylinder.faces), HAND)])
    face_rgb = np.concatenate([np.where(probe.marker_face_mask[:, None], PROBE_MARKER_RGB, PROBE_BODY_RGB),
                               np.tile([0.76, 0.57, 0.45], (len(cylinder.faces), 1))])
    v, u = np.mgrid[0:S, 0:S]
    rays = np.stack([(u.ravel() - K[0, 2]) / K[0, 0], (v.ravel() - K[1, 2]) / K[1, 1], np.ones(S * S)], 1)
    normal = R[:, 2]
    skin_z = (normal @ t) / (rays @ normal)                      # the plane's depth along each pixel's ray
    depth = np.where(skin_z > 0, skin_z, 0.0)
    classes = np.full(S * S, OTHER)
    unit = rays / np.linalg.norm(rays, axis=1, keepdims=True)
    hits, ray, tri = trimesh.util.concatenate(meshes).ray.intersects_location(np.zeros_like(unit), unit,
                                                                              multiple_hits=False)
    nearer = (hits[:, 2] < depth[ray]) | (depth[ray] == 0)
    depth[ray[nearer]], classes[ray[nearer]] = hits[nearer, 2], face_class[tri[nearer]]
    image = np.full((4, S * S), 0.5, np.float32)                 # the skin grey, the probe and finger coloured
    image[:3, ray[nearer]] = face_rgb[tri[nearer]].T
    image[3] = depth
    return image.reshape(4, S, S), classes.reshape(S, S)


def network_output():
    """(1, 29, 2), (1, 29, 3): the probe's box turned 12 degrees about its long axis and moved 4 mm, the hand's
    joints along the finger."""
    R, t = probe_pose()
    angle = np.radians(12.0)
    turn = np.array([[np.cos(angle), -np.sin(angle), 0.0], [np.sin(angle), np.cos(angle), 0.0], [0.0, 0.0, 1.0]])
    points3d = np.zeros((1, kp.NUM_KEYPOINTS, 3))
    points3d[0, kp.CORNER_SLICE] = build_probe().corners_probe @ (R @ turn).T + t + [0.004, 0.0, 0.0]
    along = np.linspace(-0.04, 0.04, kp.NUM_HAND)[:, None] * [1.0, 0.0, 0.0] + FINGER
    points3d[0, kp.HAND_SLICE] = along @ R.T + t
    return np.zeros((1, kp.NUM_KEYPOINTS, 2)), points3d


@pytest.fixture
def taken(monkeypatch):
    """Each fit's wanted pixels (S, S) bool, recorded where it samples its measured points."""
    wanted = {}

    def recording(part):
        def sample(depth, K_input, want, max_points):
            wanted[part] = want[0].reshape(S, S).copy()
            return D.sample_points(depth, K_input, want, max_points)
        return sample

    monkeypatch.setattr(probe_fit, "sample_points", recording("probe"))
    monkeypatch.setattr(hand_fit, "sample_points", recording("hand"))
    return wanted


def test_skin_points_under_the_probe_are_used_by_neither_fit(taken):
    image, classes = scene()
    skin = (classes == OTHER) & (image[3] > 0)
    points2d, points3d = network_output()
    config = {"probe_fit": "depth", "hand_fit": "depth"}
    after_network(config, points2d, points3d, image[None], K)
    # without a segmentation the skin under the probe lies within both fits' reach, and is taken
    assert (taken["probe"] & skin).sum() > 50 and (taken["hand"] & skin).sum() > 50
    after_network(config, points2d, points3d, image[None], K, segmentation=classes[None])
    assert not (taken["probe"] & skin).any() and not (taken["hand"] & skin).any()
    assert (taken["probe"] <= (classes == PROBE)).all() and (taken["hand"] <= (classes == HAND)).all()
    assert taken["probe"].sum() > 100 and taken["hand"].sum() > 20


def test_with_the_segmentation_the_probe_is_fitted_on_the_skin():
    image, classes = scene()
    R, t = probe_pose()
    truth = build_probe().corners_probe @ R.T + t
    points2d, points3d = network_output()
    start = np.linalg.norm(points3d[0, kp.CORNER_SLICE] - truth, axis=-1).mean() * 1000
    _, segmented = after_network({"probe_fit": "depth"}, points2d, points3d, image[None], K,
                                 segmentation=classes[None])
    error = np.linalg.norm(segmented[0, kp.CORNER_SLICE] - truth, axis=-1).mean() * 1000
    assert start > 5.0 and error < 0.5, (start, error)
