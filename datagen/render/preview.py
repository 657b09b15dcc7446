"""A one-page preview of a grasp: RGB, depth, labels and the projected skeleton.

Convention:
    World = probe frame, metres. The camera looks at the centre of the
    hand-probe keypoints from ``distance_m`` away, at azimuth/elevation given
    in degrees about the world z axis (the probe's long axis).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hupbench.core import keypoints as kp
from hupbench.datagen.assets.hand_anatomy import anatomical_to_pose
from hupbench.datagen.assets.probe_shape import ProbeSpec
from hupbench.core.camera import Intrinsics, look_at, project_points
from hupbench.core.errors import BadValueError
from hupbench.core.geometry import (
    axis_angle_to_matrix,
    matrix_to_axis_angle,
    transform_points,
)
from hupbench.core.draw import (
    colorize_depth,
    colorize_labels,
    draw_keypoints,
    grid,
    titled,
    write_png,
)
from hupbench.datagen.render.renderer import (
    MODALITIES,
    PointLight,
    Renderer,
    RenderSettings,
    check_modalities,
)
from hupbench.datagen.render.scene import Grasp, SceneModels, keypoints_world, scene_parts


@dataclass(frozen=True)
class PreviewView:
    """Where the preview camera stands."""

    distance_m: float = 0.5
    azimuth_deg: float = 35.0
    elevation_deg: float = 25.0

    def __post_init__(self) -> None:
        if not np.isfinite(self.distance_m) or self.distance_m <= 0:
            raise BadValueError(f"distance_m must be positive, got {self.distance_m!r}")
        if not -90.0 <= self.elevation_deg <= 90.0:
            raise BadValueError(f"elevation_deg must be in [-90, 90], got {self.elevation_deg!r}")


def handset_grasp() -> Grasp:
    """A power grip around the probe's handle, set by hand (not optimised).

    The palm lies on the probe's -y face with the fingers wrapping round the
    -x edge onto the +y face and the thumb along the +x side towards the
    lens, the forearm leaving on the +x side. Used by the preview until the
    grasp generator supplies optimised grasps.
    """
    deg = np.deg2rad
    angles = np.zeros((15, 3))
    # (flexion, abduction, twist) per MANO joint: index 1-3, middle 4-6, little 7-9, ring 10-12,
    # thumb 13-15; DIP flexion is 2/3 of PIP. The finger flexions and the placement were tuned
    # once by a small grid search for pad contact without penetration against the probe.
    for first, (mcp, pip) in zip((0, 3, 6, 9), ((10, 95), (40, 105), (40, 85), (55, 90))):
        angles[first : first + 3, 0] = deg([mcp, pip, 2.0 * pip / 3.0])
    angles[12] = deg([36, 28, -30])  # thumb CMC: flexed, abducted and rotated onto the probe
    angles[13, 0] = deg(45)
    angles[14, 0] = deg(60)
    # hand frame -> world: fingers along -x, palm facing +y, thumb side towards the lens (-z),
    # tilted 20 degrees about the palm normal so the knuckle line runs along the handle
    R_world_hand = axis_angle_to_matrix(np.array([0.0, deg(-20.0), 0.0])) @ np.diag([-1.0, -1.0, 1.0])
    pose = anatomical_to_pose(angles, matrix_to_axis_angle(R_world_hand))
    return Grasp(hand_pose=pose, hand_trans=np.array([0.056, -0.031, 0.098]), wrist_flexion=deg(-10.0))


def render_preview(grasp: Grasp, intrinsics: Intrinsics, view: PreviewView = PreviewView(),
                   models: SceneModels = SceneModels(), modalities=MODALITIES,
                   platform: str | None = None, probe=None) -> dict:
    """Render a grasp and compose the preview sheet.

    Args:
        grasp: the hand and probe placement.
        intrinsics: camera.
        view: camera placement around the grasp.
        models: model specs.
        modalities: which of "rgb", "depth", "seg" to render (and show).
        platform: GL platform, see :mod:`hupbench.datagen.render.gl`.
        probe: a mesh probe (:func:`hupbench.datagen.assets.probe.probe_of`), drawn with its frame's axes
            (x red, y green, z blue, 5 cm); None for ``models.probe``.

    Returns:
        dict with "sheet" (H, W, 3) uint8, the rendered modalities,
        "keypoints_cam" (29, 3) float64 metres OpenCV camera frame,
        "keypoints_2d" (29, 2) float64 pixels, "T_cam_world" (4, 4).
    """
    modalities = check_modalities(modalities)
    points_world = keypoints_world(grasp, models, probe=probe)
    target = 0.5 * (points_world.min(axis=0) + points_world.max(axis=0))
    az, el = np.deg2rad(view.azimuth_deg), np.deg2rad(view.elevation_deg)
    direction = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    T_cam_world = look_at(target + view.distance_m * direction, target, up_world=(0.0, 0.0, 1.0))
    keypoints_cam = transform_points(T_cam_world, points_world)
    keypoints_2d = project_points(keypoints_cam, intrinsics.K)

    eye = target + view.distance_m * direction
    lamp = eye + np.array([0.0, 0.0, 0.3])
    settings = RenderSettings(background_rgb=(1.0, 1.0, 1.0), ambient=0.3,
                              lights=[PointLight(lamp, (1.0, 1.0, 0.95), intensity=1.3 * view.distance_m**2 * 4)])
    with Renderer(intrinsics, platform=platform) as renderer:
        renderer.set_parts(scene_parts(grasp, models, probe=probe))
        frames = renderer.render(T_cam_world, modalities, settings)

    tiles = []
    if "rgb" in frames:
        tiles.append(titled(frames["rgb"], "RGB"))
    if "depth" in frames:
        d = frames["depth"][frames["depth"] > 0]
        label = f"depth {d.min():.3f}-{d.max():.3f} m" if d.size else "depth (empty)"
        tiles.append(titled(colorize_depth(frames["depth"]), label))
    if "seg" in frames:
        tiles.append(titled(colorize_labels(frames["seg"]), "labels: hand (blue) arm (orange) probe (grey)"))
    base = frames["rgb"] if "rgb" in frames else np.full((intrinsics.height, intrinsics.width, 3), 255, np.uint8)
    tiles.append(titled(draw_keypoints(base, keypoints_2d), f"{kp.NUM_KEYPOINTS} keypoints"))
    if probe is not None and not isinstance(probe.spec, ProbeSpec):  # a mesh probe (its record hashes the mesh)
        tiles.append(titled(_probe_axes(base, T_cam_world, intrinsics), "probe frame: x red, y green, z blue"))
    sheet = grid(tiles, columns=2)
    return {**frames, "sheet": sheet, "keypoints_cam": keypoints_cam, "keypoints_2d": keypoints_2d,
            "T_cam_world": T_cam_world}


def _probe_axes(image: np.ndarray, T_cam_world: np.ndarray, intrinsics: Intrinsics) -> np.ndarray:
    """The probe frame's axes (5 cm) drawn over an image: how a mesh was taken or aligned."""
    import cv2

    ends = transform_points(T_cam_world, np.array([[0, 0, 0], [0.05, 0, 0], [0, 0.05, 0], [0, 0, 0.05]], float))
    uv = np.round(project_points(ends, intrinsics.K)).astype(int)
    out = np.ascontiguousarray(image.copy())
    for k, colour in ((1, (230, 30, 30)), (2, (30, 170, 30)), (3, (30, 60, 230))):
        cv2.arrowedLine(out, tuple(map(int, uv[0])), tuple(map(int, uv[k])), colour, 2, tipLength=0.15)
    return out


def write_preview(path: str | Path, result: dict) -> Path:
    """Write a preview sheet from :func:`render_preview` as PNG."""
    path = Path(path)
    assert path.suffix.lower() == ".png", path
    write_png(path, result["sheet"])
    return path


def preview(path: str | Path, grasp: Grasp | None = None, intrinsics: Intrinsics | None = None,
            view: PreviewView = PreviewView(), modalities=MODALITIES, platform: str | None = None,
            probe=None) -> dict:
    """Render a grasp (default: :func:`handset_grasp`) and write its preview sheet to ``path``.

    Args:
        path: output PNG path.
        grasp: the grasp to show.
        intrinsics: camera; default HUP-3D's 256 x 256, fx = fy = 480.
        view: camera placement around the grasp.
        modalities: which of "rgb", "depth", "seg" to render.
        platform: GL platform, see :mod:`hupbench.datagen.render.gl`.
        probe: a mesh probe to show instead of the procedural one (with its frame's axes).

    Returns:
        :func:`render_preview`'s dict plus "path".
    """
    intrinsics = intrinsics or Intrinsics.from_lens(60.0, 32.0, 256, 256)
    result = render_preview(grasp or handset_grasp(), intrinsics, view, modalities=modalities, platform=platform,
                            probe=probe)
    return {**result, "path": write_preview(path, result)}
