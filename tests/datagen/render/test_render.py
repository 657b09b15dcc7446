import json
import subprocess
import sys
import textwrap

import numpy as np
import pytest
import trimesh
from helpers import needs_osmesa

from hupbench.core.camera import Intrinsics, look_at, project_points
from hupbench.core.geometry import transform_points
from hupbench.datagen.render.renderer import SEG_LABELS, MeshPart, Renderer, check_modalities

K256 = Intrinsics(480.0, 480.0, 128.0, 128.0, 256, 256)


@pytest.fixture(scope="module")
def renderer():
    with Renderer(K256) as r:
        yield r


def _camera_down_z(distance):
    """OpenCV camera at (0, 0, distance) looking at the origin (towards -z)."""
    return look_at(np.array([0.0, 0.0, distance]), np.zeros(3), up_world=(0.0, 1.0, 0.0))


def test_box_face_reads_back_its_depth(renderer):
    box = trimesh.creation.box(extents=(0.2, 0.2, 0.1))  # top face at z = +0.05
    renderer.set_parts([MeshPart("box", box, SEG_LABELS["probe"])])
    out = renderer.render(_camera_down_z(0.65), ("depth",))
    assert set(out) == {"depth"}
    depth = out["depth"]
    assert depth.dtype == np.float32 and depth.shape == (256, 256)
    # the face 0.6 m from the camera fills the centre of the image
    centre = depth[108:148, 108:148]
    np.testing.assert_allclose(centre, 0.6, atol=1e-3)
    # the 0.2 m face at 0.6 m spans 0.2 / 0.6 * 480 = 160 px; outside it there is only background
    assert depth[5, 5] == 0.0 and depth[250, 128] == 0.0


def test_tilted_plane_depth_matches_ray_intersection(renderer):
    # a plane through the origin tilted 30 degrees about the world x axis
    plane = trimesh.creation.box(extents=(0.6, 0.6, 0.002))
    tilt = trimesh.transformations.rotation_matrix(np.deg2rad(30.0), [1.0, 0.0, 0.0])
    plane.apply_transform(tilt @ trimesh.transformations.translation_matrix([0, 0, -0.001]))
    renderer.set_parts([MeshPart("plane", plane, SEG_LABELS["probe"])])
    T_cam_world = _camera_down_z(0.7)
    depth = renderer.render(T_cam_world, ("depth",))["depth"]
    normal_cam = T_cam_world[:3, :3] @ (tilt[:3, :3] @ [0.0, 0.0, 1.0])
    point_cam = T_cam_world[:3, 3]  # the world origin lies on the plane
    for u, v in [(128, 128), (60, 40), (200, 210), (30, 220)]:
        ray = np.linalg.inv(K256.K) @ [u, v, 1.0]
        z = (normal_cam @ point_cam) / (normal_cam @ ray)  # depth along the optical axis
        assert depth[v, u] == pytest.approx(z, abs=1e-3)


def test_only_requested_modalities_and_label_values(renderer):
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.05)
    left, right = sphere.copy(), sphere.copy()
    left.apply_translation([-0.07, 0, 0])
    right.apply_translation([0.07, 0, 0])
    renderer.set_parts([MeshPart("a", left, SEG_LABELS["hand"]), MeshPart("b", right, SEG_LABELS["probe"])])
    out = renderer.render(_camera_down_z(0.6), ("seg", "rgb"))
    assert set(out) == {"rgb", "seg"}
    assert out["rgb"].dtype == np.uint8 and out["rgb"].shape == (256, 256, 3)
    assert set(np.unique(out["seg"]).tolist()) == {0, 1, 3}
    # the hand sphere is on the left of the image, the probe sphere on the right
    assert out["seg"][128, 128 - 56] == 1 and out["seg"][128, 128 + 56] == 3


def test_full_scene_labels_are_exactly_the_parts_present(renderer):
    from hupbench.datagen.render.preview import handset_grasp
    from hupbench.datagen.render.scene import keypoints_world, scene_parts

    grasp = handset_grasp()
    parts = scene_parts(grasp)
    points = keypoints_world(grasp)
    target = points.mean(axis=0)
    T_cam_world = look_at(target + np.array([0.3, 0.25, 0.3]), target)
    renderer.set_parts(parts)
    seg = renderer.render(T_cam_world, ("seg",))["seg"]
    assert set(np.unique(seg).tolist()) == {0, 1, 2, 3}
    renderer.set_parts([p for p in parts if p.name != "arm"])
    out = renderer.render(T_cam_world, ("seg", "depth"))
    assert set(np.unique(out["seg"]).tolist()) == {0, 1, 3}
    # depth and labels agree on what is background
    np.testing.assert_array_equal(out["depth"] > 0, out["seg"] > 0)


def test_orientation_marker_renders_green_as_probe_on_the_plus_x_end(renderer):
    """The marker is its own part, drawn in PROBE_MARKER_RGB, labelled probe; seen from +x only."""
    from hupbench.datagen.render.preview import handset_grasp
    from hupbench.datagen.render.scene import PROBE_MARKER_RGB, scene_parts

    parts = [p for p in scene_parts(handset_grasp()) if p.name.startswith("probe")]
    assert [p.name for p in parts] == ["probe_body", "probe_lens", "probe_marker"]
    marker = parts[-1]
    assert marker.label == SEG_LABELS["probe"] and marker.color == PROBE_MARKER_RGB
    renderer.set_parts(parts)
    head = np.array([0.0, 0.0, 0.03])
    greens = {}
    for side in (1.0, -1.0):
        # the probe head from 0.5 m on its +x (or -x) side, a little above, lit from the camera
        eye = head + 0.5 * np.array([side * np.cos(np.deg2rad(20)), 0.0, np.sin(np.deg2rad(20))])
        out = renderer.render(look_at(eye, head, up_world=(0.0, 0.0, 1.0)), ("rgb", "seg"))
        rgb = out["rgb"].astype(int)
        green = (rgb[..., 1] > rgb[..., 0] + 60) & (rgb[..., 1] > rgb[..., 2] + 60)
        assert np.all(out["seg"][green] == SEG_LABELS["probe"])
        greens[side] = int(green.sum())
    # 14 x 20 mm at 0.5 m is up to 13 x 19 px of the 256 px image, foreshortened on the sloping shoulder
    assert greens[1.0] >= 60 and greens[-1.0] == 0


def test_camera_at_the_pole_renders_without_nan(renderer):
    from hupbench.datagen.render.preview import handset_grasp
    from hupbench.datagen.render.scene import keypoints_world, scene_parts

    grasp = handset_grasp()
    points = keypoints_world(grasp)
    target = points.mean(axis=0)
    renderer.set_parts(scene_parts(grasp))
    for sign in (1.0, -1.0):
        # straight down (or up) the world z axis, which is also the up vector
        T_cam_world = look_at(target + np.array([0.0, 0.0, sign * 0.8]), target, up_world=(0.0, 0.0, 1.0))
        out = renderer.render(T_cam_world)
        assert np.isfinite(out["depth"]).all()
        assert (out["seg"] > 0).sum() > 500
        uv = project_points(transform_points(T_cam_world, points), K256.K)
        assert np.isfinite(uv).all()


def test_visible_fingertip_depth_agrees_with_keypoint(renderer):
    """A fingertip keypoint sits on the hand surface: where it is seen, depth there is its z."""
    from hupbench.core import keypoints as kp
    from hupbench.datagen.render.preview import handset_grasp
    from hupbench.datagen.render.scene import keypoints_world, scene_parts

    grasp = handset_grasp()
    renderer.set_parts(scene_parts(grasp))
    points = keypoints_world(grasp)
    target = points.mean(axis=0)
    checked = 0
    for eye in ([0.4, -0.4, 0.2], [-0.5, 0.1, 0.2], [0.1, 0.5, 0.1], [0.45, 0.2, -0.3]):
        T = look_at(target + np.array(eye), target)
        out = renderer.render(T, ("depth", "seg"))
        cam = transform_points(T, points)
        uv = project_points(cam, K256.K)
        for tip in kp.FINGERTIPS:
            u, v = np.round(uv[tip]).astype(int)
            if out["seg"][v, u] == SEG_LABELS["hand"] and abs(out["depth"][v, u] - cam[tip, 2]) < 0.004:
                checked += 1
    # fingertips seen from somewhere render at their keypoint depth within a few mm
    assert checked >= 3


def test_modalities_are_checked_and_put_in_canonical_order():
    assert check_modalities(("seg", "rgb")) == ("rgb", "seg")
    assert check_modalities("depth") == ("depth",)
    with pytest.raises(ValueError, match="unknown modality 'normals'"):
        check_modalities(("rgb", "normals"))
    with pytest.raises(ValueError, match="at least one modality"):
        check_modalities(())


@needs_osmesa
def test_osmesa_fallback_renders_the_same_depth():
    """OSMesa, in its own process (PyOpenGL's platform is fixed per process), matches EGL's depth."""
    code = textwrap.dedent(
        """
        import json, numpy as np, trimesh
        from hupbench.core.camera import Intrinsics, look_at
        from hupbench.datagen.render.renderer import MeshPart, Renderer
        box = trimesh.creation.box(extents=(0.1, 0.1, 0.1))  # 80 px wide at 0.6 m in a 128 px image
        with Renderer(Intrinsics(480.0, 480.0, 64.0, 64.0, 128, 128), platform="osmesa") as r:
            r.set_parts([MeshPart("box", box, 3)])
            T = look_at(np.array([0.0, 0.0, 0.65]), np.zeros(3), up_world=(0.0, 1.0, 0.0))
            out = r.render(T, ("depth", "seg"))
            rgba = r.render(T, ("rgb",), alpha=True)["rgb"]  # OSMesa reads RGB only: alpha from coverage
            print(json.dumps({"platform": r.platform, "depth": float(out["depth"][64, 64]),
                              "labels": sorted(np.unique(out["seg"]).tolist()), "rgba_shape": list(rgba.shape),
                              "alpha_matches_seg": bool(((rgba[..., 3] > 0) == (out["seg"] > 0)).all())}))
        """
    )
    env = {k: v for k, v in __import__("os").environ.items() if k != "PYOPENGL_PLATFORM"}
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, env=env)
    assert proc.returncode == 0, proc.stderr[-2000:]
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    assert result["platform"] == "osmesa"
    assert result["depth"] == pytest.approx(0.6, abs=1e-3)
    assert result["labels"] == [0, 3]
    assert result["rgba_shape"] == [128, 128, 4] and result["alpha_matches_seg"]


def test_alpha_output_is_transparent_on_the_background(renderer):
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.05)
    renderer.set_parts([MeshPart("a", sphere, SEG_LABELS["hand"])])
    out = renderer.render(_camera_down_z(0.6), ("rgb", "seg"), alpha=True)
    assert out["rgb"].shape == (256, 256, 4)
    # anti-aliased silhouette pixels blend; one pixel away from the silhouette alpha is exactly 0
    import cv2

    background = cv2.erode((out["seg"] == 0).astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    np.testing.assert_array_equal(out["rgb"][..., 3][background], 0)
    assert (out["rgb"][..., 3][out["seg"] == 1] == 255).mean() > 0.95


def test_a_moved_part_renders_as_its_mesh_moved(renderer):
    """move_part(T) draws what set_parts of the mesh transformed by T draws (depth and labels), and the identity
    puts it back; the other parts stay where they were."""
    from hupbench.core.geometry import axis_angle_to_matrix

    box = trimesh.creation.box(extents=(0.12, 0.08, 0.05))
    floor = trimesh.creation.box(extents=(0.6, 0.6, 0.02))
    floor.apply_translation([0.0, 0.0, -0.1])
    T = np.eye(4)
    T[:3, :3] = axis_angle_to_matrix(np.array([0.2, -0.3, 0.5]))
    T[:3, 3] = [0.03, -0.02, 0.01]
    camera = _camera_down_z(0.7)
    parts = [MeshPart("box", box, SEG_LABELS["probe"]), MeshPart("floor", floor, SEG_LABELS["background"])]
    renderer.set_parts(parts)
    before = renderer.render(camera, ("depth", "seg"))
    renderer.move_part("box", T)
    moved = renderer.render(camera, ("depth", "seg"))
    renderer.set_parts([MeshPart("box", box.copy().apply_transform(T), SEG_LABELS["probe"]), parts[1]])
    want = renderer.render(camera, ("depth", "seg"))
    np.testing.assert_allclose(moved["depth"], want["depth"], atol=1e-5)
    assert (moved["seg"] != want["seg"]).mean() < 1e-3
    assert (moved["seg"] != before["seg"]).mean() > 0.01  # it did move
    renderer.set_parts(parts)
    renderer.move_part("box", T)
    renderer.move_part("box", np.eye(4))
    back = renderer.render(camera, ("depth", "seg"))
    np.testing.assert_array_equal(back["depth"], before["depth"])
