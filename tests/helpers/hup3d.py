"""A folder in the published HUP-3D layout (``manuelbirlo/HUP-3D_renderer``'s ``grasp_renderer.py``) with known
camera-frame geometry, for the tests of ``hupbench import-hup3d``."""

from __future__ import annotations

import pickle
from pathlib import Path

import cv2
import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

SIZE = 64
#: the published renderer's K for a SIZE x SIZE image (Blender: principal point at SIZE / 2)
K_BLENDER = np.array([[120.0, 0.0, SIZE / 2], [0.0, 120.0, SIZE / 2], [0.0, 0.0, 1.0]])
FLIP = np.diag([1.0, -1.0, -1.0, 1.0])
#: (rows, cols, published label, planar depth z in metres) of each flat patch of a frame
PATCHES = ((slice(10, 30), slice(8, 40), 100, 0.48), (slice(30, 44), slice(20, 44), 16, 0.52),
           (slice(44, 50), slice(20, 44), 17, 0.53), (slice(50, 60), slice(24, 40), 15, 0.56))
#: (split, number, view's Euler XYZ degrees as the published renderer stores them, expected view id or -1, grasp, z)
FRAMES = (("train", 1, (70.0, 360.0), 1, 0, 0.5), ("train", 2, (10.0, 270.0), 34, 0, 0.5),
          ("test", 1, (70.0, 360.0), 1, 1, 0.5), ("test", 2, (10.0, 270.0), 34, 1, 0.5),
          ("test", 3, (33.0, 12.0), -1, 1, 0.8))


def _known_frame(rng, number: int) -> dict:
    """A frame's hupbench-side truth: hand joints and the probe pose in the OpenCV camera frame."""
    hand_cv = np.column_stack([rng.uniform(-0.02, 0.02, 21), rng.uniform(0.0, 0.03, 21), rng.uniform(0.52, 0.56, 21)])
    R = Rotation.from_rotvec(rng.normal(size=3) * 0.5).as_matrix()
    T_cam_probe = np.eye(4)
    T_cam_probe[:3, :3], T_cam_probe[:3, 3] = R, [0.01 * number, -0.02, 0.5]
    return {"hand_cv": hand_cv, "T_cam_probe": T_cam_probe}


def _write_frame(folder, number: int, truth: dict, euler_deg, grasp: int, z: float, background: str) -> dict:
    """One frame in the published layout; returns the planar depth it encodes and its labels (published)."""
    for sub in ("meta", "rgb", "depth", "segm"):
        (folder / sub).mkdir(parents=True, exist_ok=True)
    planar = np.zeros((SIZE, SIZE))
    scene = np.zeros((SIZE, SIZE), np.uint8)
    for rows, cols, label, depth_z in PATCHES:
        planar[rows, cols], scene[rows, cols] = depth_z + 0.001 * number, label
    u, v = np.meshgrid(np.arange(SIZE) + 0.5, np.arange(SIZE) + 0.5)  # Blender's pixel centres
    radial = planar * np.sqrt(1 + ((u - K_BLENDER[0, 2]) / K_BLENDER[0, 0]) ** 2
                              + ((v - K_BLENDER[1, 2]) / K_BLENDER[1, 1]) ** 2)
    fg = scene > 0
    far, near = radial[fg].max(), radial[fg].min()
    # depthutils.convert_depth_and_swap_pixed_intensity, stored through cv2.imwrite of a float image
    levels = np.where(fg, 254 * np.abs(radial - far) / (far - near) + 1, 0)
    cv2.imwrite(str(folder / f"depth/img_depth_{number}.png"), np.rint(levels).astype(np.uint8))
    hand_only = np.where(np.isin(scene, (15, 16, 17)), scene, 0)
    probe_only = np.where(scene == 100, scene, 0)
    cv2.imwrite(str(folder / f"segm/img_segm_{number}.png"), np.stack([scene, hand_only, probe_only], axis=2))
    rgb = np.full((SIZE, SIZE, 3), 200, np.uint8)
    rgb[fg] = (90, 140, 210)
    cv2.imwrite(str(folder / f"rgb/img_rgb_{number}.jpg"), rgb)
    coords_3d = truth["hand_cv"] @ FLIP[:3, :3]  # OpenCV -> Blender axes (the flip is its own inverse)
    cam_extr = np.hstack([FLIP[:3, :3], np.zeros((3, 1))])
    projected = (K_BLENDER @ cam_extr @ np.vstack([coords_3d.T, np.ones(21)])).T
    hand_pose = np.full(48, 0.1 * (grasp + 1))
    meta = {"coords_3d": coords_3d.astype(np.float32), "coords_2d": (projected[:, :2] / projected[:, 2:]).astype(
                np.float32), "cam_calib": K_BLENDER, "cam_extr": cam_extr,
            "affine_transform": (FLIP @ truth["T_cam_probe"]).astype(np.float32),
            "pose": np.concatenate([Rotation.from_euler("XYZ", np.radians([*euler_deg, 0.0])).as_rotvec(),
                                    np.zeros(153)]).astype(np.float32),
            "z": z, "hand_pose": list(hand_pose), "hand_trans": [0.0, 0.01 * grasp, 0.0],
            "bg_path": f"assets/backgrounds/{background}.jpg", "depth_min": far, "depth_max": near,
            "side": "right", "obj_visibility_ratio": 1.0}
    with open(folder / f"meta/img_meta_{number}.pkl", "wb") as f:
        pickle.dump(meta, f)
    return {"planar": planar, "scene": scene, "far": far, "near": near}


def _probe_ply(path):
    mesh = trimesh.creation.box(extents=(0.03, 0.02, 0.16))
    mesh.apply_translation([0.004, -0.002, 0.07])
    mesh.export(path)
    return mesh.bounds


def write_published(root: Path) -> tuple[np.ndarray, list[dict]]:
    """The published layout under ``root``: ``root/HUP-3D/{train,test}/`` (the frames of :data:`FRAMES`) and
    ``root/probe.ply``. Returns (the probe's (2, 3) bounds in metres, each frame's truth)."""
    rng = np.random.default_rng(3)
    bounds = _probe_ply(root / "probe.ply")
    truths = []
    for i, (split, number, euler, view, grasp, z) in enumerate(FRAMES):
        truth = _known_frame(rng, number)
        truth |= _write_frame(root / "HUP-3D" / split, number, truth, euler, grasp, z, ("phantom_1", "room")[i % 2])
        truths.append(truth | {"view": view, "grasp": grasp, "z": z})
    return bounds, truths
