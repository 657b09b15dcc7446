"""Contact sheet: every selected grasp rendered from three viewpoints, with its scores.

Convention:
    Probe frame (lens apex at the origin, +z along the handle), metres.
"""

from __future__ import annotations

import numpy as np

from hupbench.core.camera import Intrinsics, look_at
from hupbench.core.geometry import axis_angle_to_matrix
from hupbench.core.draw import grid, stack, text_block, titled
from hupbench.datagen.render.renderer import PointLight, Renderer, RenderSettings
from hupbench.datagen.assets.hand_anatomy import HandSpec
from hupbench.datagen.render.scene import Grasp, models_of, scene_parts

VIEW_DISTANCE_M = 0.42


def grasp_views(hand_pose: np.ndarray) -> list[np.ndarray]:
    """Three ``T_cam_world`` looking at a grasp from the side away from the forearm.

    Two views 55 degrees either side of the direction opposite the forearm,
    slightly from above, and one from below the lens (it must stay uncovered).

    Args:
        hand_pose: (48,) float axis-angle; its global rotation gives the forearm direction.

    Returns:
        list of three (4, 4) float64 camera poses (OpenCV), probe frame.
    """
    centre = np.array([0.0, 0.0, 0.085])
    forearm = -axis_angle_to_matrix(np.asarray(hand_pose[:3], dtype=np.float64))[:, 0]  # hand -x
    away = np.arctan2(-forearm[1], -forearm[0]) if np.hypot(forearm[0], forearm[1]) > 1e-6 else 0.0
    views = []
    for azimuth, elevation in ((away + np.deg2rad(55), 20.0), (away - np.deg2rad(55), 20.0), (away, -40.0)):
        el = np.deg2rad(elevation)
        d = np.array([np.cos(el) * np.cos(azimuth), np.cos(el) * np.sin(azimuth), np.sin(el)])
        views.append(look_at(centre + VIEW_DISTANCE_M * d, centre, up_world=(0.0, 0.0, 1.0)))
    return views


VIEW_NAMES = ("from 55 degrees one side", "from 55 degrees the other", "from below the lens")


def contact_sheet(arrays: dict, size: int = 200, platform: str | None = None,
                  split_of: dict[int, str] | None = None, probe=None) -> np.ndarray:
    """Render the contact sheet of ``grasps.npz``-style arrays.

    Args:
        arrays: with "grasp_id", "hand_pose" (N, 48), "hand_trans" (N, 3), "keypoints_probe"
            (N, 21, 3) and "score_*" entries.
        size: tile side, pixels.
        platform: GL platform.
        split_of: {grasp id: split name} to print beside each grasp id (a dataset's manifest
            ``grasp_ids``), or None.
        probe: the probe the grasps hold (a mesh probe); None for the procedural one.

    Returns:
        (H, W, 3) uint8: a header saying what the views and scores are, then one row per grasp,
        three views each, every tile titled.
    """
    from hupbench.datagen.grasps.refine import PADS
    from hupbench.datagen.grasps.scores import CONTACT_MM

    intrinsics = Intrinsics.from_lens(60.0, 32.0, size, size)
    tiles = []
    with Renderer(intrinsics, platform=platform) as renderer:
        for i, gid in enumerate(arrays["grasp_id"]):
            # each grasp on its subject's hand when the arrays carry one
            hand = HandSpec(*map(float, arrays["subject_hand"][i])) if "subject_hand" in arrays else HandSpec()
            renderer.set_parts(scene_parts(Grasp(arrays["hand_pose"][i], arrays["hand_trans"][i]),
                                           models_of(hand), probe=probe))
            split = f" ({split_of[int(gid)]})" if split_of and int(gid) in split_of else ""
            labels = (f"grasp {int(gid)}{split}",
                      f"pen {arrays['score_max_penetration_mm'][i]:.1f} mm, pads {int(arrays['score_pads_in_contact'][i])}",
                      f"fc {arrays['score_force_closure_residual'][i]:.2f}")
            for k, T in enumerate(grasp_views(arrays["hand_pose"][i])):
                eye = np.linalg.inv(T)[:3, 3]
                settings = RenderSettings(lights=[PointLight(eye + [0.0, 0.0, 0.15], intensity=0.5)], ambient=0.3)
                rgb = renderer.render(T, ("rgb",), settings)["rgb"]
                tiles.append(titled(rgb, f"{labels[k]}\n{VIEW_NAMES[k]}"))
    sheet = grid(tiles, columns=3)
    header = text_block([
        (f"{len(arrays['grasp_id'])} grasps, one per row, each from three cameras: two 20 degrees above the grip, "
         "55 degrees either side of the direction opposite the forearm, and one 40 degrees below it, looking at "
         "the lens (which must stay uncovered). The green patch on the probe is its orientation marker."),
        ("pen: deepest hand point inside the probe. "
         f"pads: how many of the {len(PADS)} pads (thumb, four fingertips, palm) lie within {CONTACT_MM:g} mm "
         "of the probe. fc: force-closure residual, 0 when the contacts can hold the probe still.")],
        sheet.shape[1], scale=0.42, line_px=17)
    return stack([header, sheet])
