"""The published HUP-3D dataset converted into a hupbench dataset (:mod:`hupbench.core.contract`).

The published layout, as ``manuelbirlo/HUP-3D_renderer`` (``grasp_renderer.py``) writes it into one
folder per split (``<split>/``) or, merged, into one folder::

    meta/img_meta_N.pkl        a pickled dict, N = 1, 2, ...: coords_3d (21, 3) metres in Blender's world
                               axes (= the camera's OpenGL axes: the renderer keeps the camera at the
                               identity), coords_2d (21, 2), cam_calib (3, 3), cam_extr (3, 4) =
                               diag(1, -1, -1) (Blender -> OpenCV axes), affine_transform (4, 4) probe
                               mesh -> Blender world, z (camera distance, m), pose[:3] (the body's global
                               rotation, axis-angle: the sphere view), hand_pose (48,) and hand_trans (3,)
                               (the grasp's MANO parameters), bg_path, depth_min and depth_max (swapped:
                               depth_min holds the largest depth)
    rgb/img_rgb_N.jpg          256 x 256 JPEG
    depth/img_depth_N.png      8-bit: 0 background, 1 the farthest, 255 the nearest surface,
                               round(254 (far - r) / (far - near) + 1) of Cycles' radial depth r
    depth/img_depth_N0001.exr  the radial depth itself, float, 1e10 = background (when kept)
    segm/img_segm_N.png        3 channels as OpenCV reads them: the full scene, the hand alone, the probe
                               alone; 0 background, 15 forearm, 16 palm, 17 fingers, 100 probe

What is converted, per frame (the module's functions, in order): the 21 joints (already in OpenPose
order, :data:`PUBLISHED_TO_HUPBENCH` checks it) and the 8 corners of the probe mesh's axis-aligned box,
moved by ``affine_transform``, into the OpenCV camera frame; 2D keypoints projected with K; depth
unprojected to planar z (from the EXR where it exists, else from the 8-bit PNG with the meta's range);
the full-scene labels mapped to hupbench's; the view (from ``pose[:3]``), distance, background and
grasp (distinct hand poses) recovered. The glove and the lamp are not in the meta: glove_id is -1,
the lamp zeros, and the manifest's ``imported.unknown`` says so.

The dataset records its probe as ``hupbench generate`` records a mesh probe: the manifest's ``probe``
(:attr:`hupbench.datagen.assets.probe.Probe.record` of the PLY given) and its ``grasps.npz``, which holds the
distinct grasps and the mesh's geometry (:func:`hupbench.datagen.dataset.grasps_file.probe_of_dataset` reads
it back, for eval's probe-pose metrics and the BOP export); the manifest's ``grasps_sha256`` is that
file's sha256. The dataset is built beside OUT and renamed into place once complete.

Convention:
    Pixel centres: Blender's K puts the principal point at (128, 128) for pixels covering [i, i + 1);
    hupbench's pixel centres are at integers (:mod:`hupbench.core.contract`), so K's cx and cy and
    the published coords_2d shift by -0.5 px. Depth precision from the 8-bit PNG: a step of
    (far - near) / 254 per level, rounded to the nearest level, so up to (far - near) / 508 off (plus
    half a uint16 step); such depth is marked approximate in the manifest.
"""

from __future__ import annotations

import csv
import io
import math
import pickle
import re
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import cv2
import numpy as np

from hupbench.core import keypoints as kp
from hupbench.core import tolerances as tol
from hupbench.core.camera import project_points, swap_gl_cv_axes
from hupbench.core.contract import (
    ANNOTATION_FIELDS,
    ANNOTATIONS,
    DEPTH_SCALE_M,
    MANIFEST,
    SCHEMA_VERSION,
    SEG_LABELS,
    SPLITS,
    frame_path,
)
from hupbench.datagen.dataset.sphere import SphereSpec, all_viewpoints, latitude_count
from hupbench.core.errors import BadValueError, MissingFileError
from hupbench.core.geometry import axis_angle_to_matrix, euler_to_matrix, invert_transform, transform_points
from hupbench.core.io import atomic_folder, check_writable, encode_image, file_sha256, save_npz, write_bytes, write_json

FORMAT = "HUP-3D"
#: the published mask's material pass indices -> hupbench's labels
PUBLISHED_SEG = {0: SEG_LABELS["background"], 15: SEG_LABELS["arm"], 16: SEG_LABELS["hand"],
                 17: SEG_LABELS["hand"], 100: SEG_LABELS["probe"]}
#: Blender writes this depth where a ray hits nothing
EXR_BACKGROUND_M = 1e9
#: the published 8-bit depth: levels 1..255 span [near, far]
DEPTH_LEVELS = 254
DEPTH_SOURCES = ("auto", "png")
#: the imported dataset's grasps file: the distinct grasps and the probe's geometry
GRASPS = "grasps.npz"
#: what a published frame's number looks like in its file names
_META_NAME = re.compile(r"^img_meta_(\d+)\.pkl$")
#: the meta fields the conversion reads (coords_2d is checked when present)
REQUIRED_META = ("coords_3d", "cam_calib", "cam_extr", "affine_transform", "depth_min", "depth_max", "pose", "z",
                 "hand_pose", "hand_trans", "bg_path")
#: the renderer's joints before it reorders them: the hand root, SMPL-H's right-hand joints in MANO's
#: finger order (index, middle, little, ring, thumb; three each, proximal first), the five fingertip
#: vertices (thumb to little)
_RENDERER_JOINTS = (("wrist",)
                    + tuple(kp.HAND_NAMES[kp.FINGER_START[f] + k] for f in kp.MANO_FINGER_ORDER for k in range(3))
                    + tuple(kp.HAND_NAMES[tip] for tip in kp.FINGERTIPS))
#: coordutils.get_hand_body_info's reordering of those joints (``idxs``)
_RENDERER_REORDER = (0, 13, 14, 15, 16, 1, 2, 3, 17, 4, 5, 6, 18, 10, 11, 12, 19, 7, 8, 9, 20)
#: the joint names of the published coords_3d, in its order
PUBLISHED_HAND_NAMES = tuple(_RENDERER_JOINTS[i] for i in _RENDERER_REORDER)
#: hupbench hand keypoint i is published joint PUBLISHED_TO_HUPBENCH[i]
PUBLISHED_TO_HUPBENCH = tuple(PUBLISHED_HAND_NAMES.index(name) for name in kp.HAND_NAMES)
#: the renderer's camera pose in Blender's world (camutils.check_camera asserts the identity), OpenGL axes
T_BLENDER_CAMGL = np.eye(4)
#: fields the published meta does not hold, and what the importer writes for them
UNKNOWN = {"glove_id": "-1: the meta does not record the hand texture (setHandTextures is not saved)",
           "light_position_cam": "zeros: the meta does not record the lamp (setLighting saves nothing)",
           "light_color": "zeros: as light_position_cam", "light_energy_w": "0: as light_position_cam"}


@dataclass(frozen=True)
class SourceFrame:
    """One published frame: its split, its number N and its folder (holding meta/, rgb/, depth/, segm/)."""

    split: str
    number: int
    folder: Path

    def file(self, kind: str) -> Path:
        names = {"meta": f"meta/img_meta_{self.number}.pkl", "rgb": f"rgb/img_rgb_{self.number}.jpg",
                 "depth": f"depth/img_depth_{self.number}.png", "exr": f"depth/img_depth_{self.number}0001.exr",
                 "segm": f"segm/img_segm_{self.number}.png"}
        return self.folder / names[kind]


# --- finding and reading the published files -------------------------------------------------


def find_frames(root: Path, split: str | None) -> tuple[list[SourceFrame], str]:
    """The published frames under ``root``, sorted by (split, number), and where their split came from.

    Split folders (``root/train/meta``, ...) give each frame its published split; a folder with
    ``meta/`` itself puts every frame in ``split`` (default "test").

    Raises:
        MissingFileError: no root, or no meta files in ``root/meta`` nor in its split folders. BadValueError:
        ``split`` given for a root that has split folders.
    """
    if not root.is_dir():
        raise MissingFileError(f"HUP-3D folder {root} does not exist" if not root.exists()
                               else f"HUP-3D folder {root} is a file; expected the folder holding meta/, rgb/, ...")
    folders = {s: root / s for s in SPLITS if (root / s / "meta").is_dir()}
    if folders and split is not None:
        raise BadValueError(f"{root} has its own split folders ({', '.join(folders)}): --split is for a folder "
                            "holding meta/ itself")
    split_from = "the published split folders"
    if not folders:
        folders = {split or "test": root}
        split_from = f"--split {split or 'test'} (a folder without split folders)"
    frames = []
    for name, folder in folders.items():
        metas = (folder / "meta").iterdir() if (folder / "meta").is_dir() else ()
        numbers = sorted(int(m.group(1)) for p in metas if (m := _META_NAME.match(p.name)))
        frames += [SourceFrame(name, n, folder) for n in numbers]
    if not frames:
        where = ", ".join(str(f / "meta") for f in folders.values())
        raise MissingFileError(f"no img_meta_N.pkl files in {where} (nor in train/, val/ or test/ of {root}): not the "
                               "published HUP-3D layout, nothing to import")
    return sorted(frames, key=lambda f: (SPLITS.index(f.split), f.number)), split_from


def _array(meta: dict, key: str, shape: tuple[int, ...], path: Path, leading: bool = False) -> np.ndarray:
    """``meta[key]`` as float64 of ``shape``, all finite; with ``leading``, the first ``shape[0]`` numbers of
    a longer sequence."""
    try:
        value = np.asarray(meta[key], dtype=np.float64)
    except (TypeError, ValueError):
        value = np.zeros(0)
    if leading:
        value = value.reshape(-1)[:shape[0]]
    if value.shape != shape or not np.isfinite(value).all():
        what = f"(at least {shape[0]}; its first {shape[0]} are used)" if leading else f"of shape {shape}"
        raise BadValueError(f"{path}: {key} must be finite numbers {what}, got {value.shape}")
    return value


def read_meta(path: Path) -> dict:
    """A published meta pickle, its fields checked and as float64 arrays.

    Returns:
        {"coords_3d": (21, 3) metres, Blender world axes; "coords_2d": (21, 2) published pixels or None;
        "cam_calib": (3, 3); "cam_extr": (3, 4); "affine_transform": (4, 4) probe mesh -> Blender world;
        "far_m", "near_m": the radial depth range (the published depth_min and depth_max, swapped back);
        "pose3": (3,) axis-angle; "z": metres; "hand_pose": (48,); "hand_trans": (3,); "bg_name": str}.

    Raises:
        BadValueError: not a pickle of a dict, a field missing or malformed.
    """
    try:
        with open(path, "rb") as f:
            meta = pickle.load(f)  # the user's own dataset files
        why = f"a pickled {type(meta).__name__}"
    except (pickle.UnpicklingError, EOFError, AttributeError, ImportError, IndexError, ValueError) as exc:
        meta, why = None, f"{type(exc).__name__}: {exc}"
    if not isinstance(meta, dict):
        raise BadValueError(f"{path}: not a readable meta pickle of a dict ({why})")
    missing = [k for k in REQUIRED_META if k not in meta]
    if missing:
        raise BadValueError(f"{path} lacks {', '.join(missing)}: not a published HUP-3D meta file")
    out = {"coords_3d": _array(meta, "coords_3d", (kp.NUM_HAND, 3), path),
           "coords_2d": None if meta.get("coords_2d") is None else _array(meta, "coords_2d", (kp.NUM_HAND, 2), path),
           "cam_calib": _array(meta, "cam_calib", (3, 3), path),
           "cam_extr": _array(meta, "cam_extr", (3, 4), path),
           "affine_transform": _array(meta, "affine_transform", (4, 4), path),
           "pose3": _array(meta, "pose", (3,), path, leading=True), "z": float(_array(meta, "z", (), path)),
           "hand_pose": _array(meta, "hand_pose", (48,), path),
           "hand_trans": _array(meta, "hand_trans", (3,), path).reshape(3),
           "bg_name": Path(str(meta["bg_path"])).name}
    # the renderer swaps them: depth_min holds the largest depth (depthutils returns max, min)
    out["far_m"] = float(_array(meta, "depth_min", (), path))
    out["near_m"] = float(_array(meta, "depth_max", (), path))
    if not 0 < out["near_m"] <= out["far_m"]:
        raise BadValueError(f"{path}: depth_min {out['far_m']} and depth_max {out['near_m']} are not the published "
                            "swapped range (depth_min >= depth_max > 0)")
    if np.abs(out["cam_extr"] - invert_transform(swap_gl_cv_axes(T_BLENDER_CAMGL))[:3]).max() > tol.IMPORT_META_MATCH:
        raise BadValueError(f"{path}: cam_extr is {out['cam_extr'].tolist()}, not the published renderer's camera "
                            "(at Blender's origin: diag(1, -1, -1))")
    return out


class PublishedProbe(NamedTuple):
    """A probe PLY as stored: ``ProbeMeshSpec``, ``trimesh.Trimesh`` (metres), box corners (8, 3), manifest record."""
    spec: object
    mesh: object
    corners_probe: np.ndarray
    record: dict


def read_probe_mesh(path: Path) -> PublishedProbe:
    """The probe the published frames were rendered with, from its PLY, in the mesh's own frame.

    The mesh is taken as stored (metres, no repair): ``affine_transform`` places exactly these vertices, and
    the box corners (keypoints 21-28, :data:`hupbench.core.keypoints.CORNER_BITS` order, the published
    ``get_obj_corners3d`` order) are their axis-aligned box. The import derives no signed distance (it needs none).

    Args:
        path: the probe PLY the dataset was rendered with (not in the public repositories).

    Raises:
        MissingFileError: no file. BadValueError: not a triangle mesh of a hand-held size in metres.
    """
    import trimesh

    from hupbench.datagen.assets.probe_mesh import MAX_LENGTH_M, MIN_LENGTH_M, ProbeMeshSpec, box_corners, \
        mesh_probe_record

    if not path.is_file():
        raise MissingFileError(f"probe mesh {path} does not exist (the PLY the dataset was rendered with, e.g. "
                               "voluson_painted_downscaled.ply)")
    try:
        mesh = trimesh.load(path, force="mesh", process=False)
        faces = getattr(mesh, "faces", None)
        length = float(np.ptp(mesh.vertices, axis=0).max()) if isinstance(mesh, trimesh.Trimesh) and len(faces) else 0.0
        why = f"{len(faces)} faces, {length:g} m long" if length else "no faces"
    except Exception as exc:  # trimesh raises many kinds on a malformed file; all mean the same to the user
        length, why = 0.0, f"unreadable: {type(exc).__name__}: {exc}"
    if not MIN_LENGTH_M <= length <= MAX_LENGTH_M:
        raise BadValueError(f"probe mesh {path}: not a triangle mesh of the probe in metres ({why}); expected the "
                            f"probe's PLY, {MIN_LENGTH_M:g} to {MAX_LENGTH_M:g} m long")
    spec = ProbeMeshSpec(str(path.resolve()), "m", False, file_sha256(path))
    return PublishedProbe(spec, mesh, box_corners(mesh.bounds), mesh_probe_record(spec, mesh.vertices, mesh.faces))


# --- the conversion of one frame -------------------------------------------------------------


def hupbench_K(cam_calib: np.ndarray) -> np.ndarray:
    """(3, 3) K with hupbench's integer pixel centres from Blender's (principal point -0.5 px)."""
    K = np.array(cam_calib, dtype=np.float64)
    K[:2, 2] -= 0.5
    return K


def keypoints_cam(meta: dict, corners_probe: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The 29 keypoints in the OpenCV camera frame and ``T_cam_world`` (world = the probe mesh's frame).

    Args:
        meta: :func:`read_meta`'s dict. corners_probe: (8, 3) metres, the mesh's frame.

    Returns:
        keypoints_3d_cam (29, 3) float64 metres, OpenCV camera frame; T_cam_probe (4, 4) float64.
    """
    T_cam_blender = invert_transform(swap_gl_cv_axes(T_BLENDER_CAMGL))
    hand_cam = transform_points(T_cam_blender, meta["coords_3d"][list(PUBLISHED_TO_HUPBENCH)])
    T_cam_probe = T_cam_blender @ meta["affine_transform"]
    return np.concatenate([hand_cam, transform_points(T_cam_probe, corners_probe)]), T_cam_probe


def planar_depth(radial_m: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Depth along the optical axis from depth along each pixel's ray.

    Args:
        radial_m: (H, W) metres from the camera centre, 0 = background. K: (3, 3) hupbench pixel centres.

    Returns:
        (H, W) float64 metres, z of the OpenCV camera frame, 0 = background.
    """
    h, w = radial_m.shape
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    ray = np.sqrt(1.0 + ((u - K[0, 2]) / K[0, 0]) ** 2 + ((v - K[1, 2]) / K[1, 1]) ** 2)
    return radial_m / ray


def radial_from_png(levels: np.ndarray, far_m: float, near_m: float) -> np.ndarray:
    """Undo the published 8-bit depth: level 1 is ``far_m``, 255 ``near_m``, 0 background.

    Args:
        levels: (H, W) uint8. far_m, near_m: the frame's range (the meta's depth_min, depth_max).

    Returns:
        (H, W) float64 radial metres, 0 = background; off by at most ``(far_m - near_m) / 508``.
    """
    radial = far_m - (levels.astype(np.float64) - 1.0) * (far_m - near_m) / DEPTH_LEVELS
    return np.where(levels > 0, radial, 0.0)


def read_exr_depth(path: Path) -> np.ndarray:
    """(H, W) float64 radial metres of a Blender depth EXR, 0 = background.

    Raises:
        BadValueError: no EXR reader installed (the OpenEXR package), or the file is not a depth EXR.
    """
    try:
        import OpenEXR
    except ImportError:
        raise BadValueError(f"{path}: reading the EXR depth needs the OpenEXR package (pip install OpenEXR); "
                            "--depth png uses the 8-bit depth instead") from None
    try:
        with OpenEXR.File(str(path)) as exr:
            channels = exr.channels()
        why = f"no depth channel among {sorted(channels)}"
    except Exception as exc:  # OpenEXR raises plain exceptions for damaged files
        channels, why = {}, f"unreadable: {exc}"
    name = next((c for c in ("V", "Z", "R", "Y") if c in channels), None) if len(channels) != 1 else next(iter(channels))
    if name is None:
        raise BadValueError(f"{path}: not a depth EXR ({why})")
    pixels = np.asarray(channels[name].pixels, dtype=np.float64)
    if pixels.ndim == 3:
        pixels = pixels[..., 0]
    return np.where(np.isfinite(pixels) & (pixels < EXR_BACKGROUND_M), pixels, 0.0)


def read_labels(path: Path) -> np.ndarray:
    """(H, W) uint8 hupbench labels of a published 3-channel mask (its full-scene channel, OpenCV's 0)."""
    image = _read_image(path, cv2.IMREAD_UNCHANGED)
    if image.ndim != 3 or image.shape[2] < 1 or image.dtype != np.uint8:
        raise BadValueError(f"{path}: expected an 8-bit 3-channel mask (scene, hand, probe), got {image.dtype} "
                            f"{image.shape}")
    scene = image[..., 0]
    present = set(np.flatnonzero(np.bincount(scene.ravel(), minlength=256)).tolist())
    unknown = sorted(present - set(PUBLISHED_SEG))
    if unknown:
        raise BadValueError(f"{path}: labels {unknown[:8]} are not the published ones {sorted(PUBLISHED_SEG)} "
                            "(background, forearm, palm, fingers, probe)")
    lut = np.zeros(256, dtype=np.uint8)
    for published, label in PUBLISHED_SEG.items():
        lut[published] = label
    return lut[scene]


def _read_image(path: Path, flags: int) -> np.ndarray:
    if not path.is_file():
        raise MissingFileError(f"{path} is missing (every meta file has its rgb, depth and segm images)")
    image = cv2.imdecode(np.frombuffer(path.read_bytes(), np.uint8), flags)
    if image is None:
        raise BadValueError(f"{path}: not a decodable image")
    return image


def view_rotations() -> np.ndarray:
    """The published renderer's body rotation for every sphere view (hupbench's view ids).

    ``camera_sphere.py`` turns a view (theta, phi) into roll = atan2(y, x), pitch = atan2(-z, |(x, y)|)
    (degrees mod 360), then Euler XYZ angles (360 - pitch, 360 - roll, 0) for the rings up to
    N_lat / 2 + 1 and (-pitch, 360 - roll, 0) below; ``mesh_manip.randomized_verts`` stores that
    rotation in ``pose[:3]``.

    Returns:
        (V, 3, 3) float64 rotation matrices, V = all views of :func:`hupbench.datagen.dataset.sphere.all_viewpoints`.
    """
    spec = SphereSpec()  # the published sphere: 0.8 m, 0.15 m circles, N_lat by ceil
    angles = all_viewpoints(spec)
    n_lat = latitude_count(spec)
    theta, phi = angles[:, 0], angles[:, 1]
    x, y, z = np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)
    roll = np.degrees(np.arctan2(y, x)) % 360.0
    pitch = np.degrees(np.arctan2(-z, np.hypot(x, y))) % 360.0
    ring = np.rint(theta / (math.pi / n_lat))
    first = np.where(ring <= n_lat / 2 + 1, 360.0 - pitch, -pitch)
    euler = np.radians(np.stack([first, 360.0 - roll, np.zeros_like(roll)], axis=1))
    return euler_to_matrix(euler, "xyz")


def view_of(pose3: np.ndarray, rotations: np.ndarray) -> int:
    """The view id whose published rotation ``pose3`` (axis-angle) is, or -1 when none is within
    ``tol.IMPORT_VIEW_RAD``."""
    R = axis_angle_to_matrix(pose3)
    cosine = (np.trace(np.swapaxes(rotations, -1, -2) @ R, axis1=-2, axis2=-1) - 1.0) / 2.0
    angle = np.arccos(np.clip(cosine, -1.0, 1.0))
    best = int(np.argmin(angle))
    return best if angle[best] <= tol.IMPORT_VIEW_RAD else -1


# --- the verb ---------------------------------------------------------------------------------


class ImportContext(NamedTuple):
    """What every frame of one import shares: the depth source ("auto" or "png"), K (3, 3), the probe's box
    corners (8, 3) in its mesh frame, the sphere's view rotations (V, 3, 3) and (theta, phi) angles (V, 2), the
    background names, the distinct grasps seen so far (hand pose and translation as float32 bytes -> (grasp index,
    hand_pose (48,), hand_trans (3,)) as first seen; a new grasp is added) and the folder written."""
    depth: str
    K: np.ndarray
    corners_probe: np.ndarray
    view_rotations: np.ndarray
    view_angles: np.ndarray
    backgrounds: list[str]
    grasps: dict[bytes, tuple]
    out: Path


def _convert_frame(f, meta: dict, frame_id: int, size, ctx: ImportContext):
    """One published frame written into ``ctx.out`` in hupbench's layout; returns (its annotation row, its image
    size (W, H), the slack of its stored depth in metres, "exr" or "png": where its depth came from)."""
    # chunks imports the renderer: only when converting
    from hupbench.datagen.dataset.chunks import visibility

    rgb = _read_image(f.file("rgb"), cv2.IMREAD_COLOR)
    rgb_bytes = f.file("rgb").read_bytes()
    size = size or (rgb.shape[1], rgb.shape[0])
    labels = read_labels(f.file("segm"))
    levels = _read_image(f.file("depth"), cv2.IMREAD_UNCHANGED)
    # what each image must be beyond the frame's size: the rgb a JPEG, the depth 8-bit single-channel
    for name, image, kind, right in (("rgb", rgb, "JPEG", rgb_bytes.startswith(b"\xff\xd8")),
                                     ("segm", labels, "", True),
                                     ("depth", levels, "8-bit single-channel", levels.ndim == 2 and levels.dtype == np.uint8)):
        if image.shape[:2] != size[::-1] or not right:
            raise BadValueError(f"{f.file(name)}: {image.dtype} {image.shape}, expected a {size[0]} x {size[1]} "
                                f"{kind or 'image'}")
    if ctx.depth == "auto" and f.file("exr").is_file():
        radial, approx, depth_kind = read_exr_depth(f.file("exr")), 0.0, "exr"
    else:
        radial = radial_from_png(levels, meta["far_m"], meta["near_m"])
        approx, depth_kind = (meta["far_m"] - meta["near_m"]) / (2 * DEPTH_LEVELS), "png"
    z = planar_depth(radial, ctx.K)
    stored = np.where(z > 0, np.clip(np.rint(z / DEPTH_SCALE_M), 1, 65535), 0).astype(np.uint16)
    # the slack of a stored depth: the PNG's rounding and the uint16's
    slack = approx + DEPTH_SCALE_M / 2
    kp3d, T_cam_probe = keypoints_cam(meta, ctx.corners_probe)
    kp3d = kp3d.astype(np.float32)
    kp2d = project_points(kp3d.astype(np.float64), ctx.K).astype(np.float32)
    if meta["coords_2d"] is not None:
        off = np.abs(kp2d[kp.HAND_SLICE] - (meta["coords_2d"][list(PUBLISHED_TO_HUPBENCH)] - 0.5)).max()
        if off > tol.IMPORT_COORDS_2D_PX:
            raise BadValueError(f"{f.file('meta')}: coords_2d is {off:.3f} px from coords_3d projected with "
                                "cam_calib and cam_extr: the meta is not self-consistent")
    visible = visibility(kp3d.astype(np.float64), kp2d.astype(np.float64),
                         stored.astype(np.float64) * DEPTH_SCALE_M, labels, slack_m=slack)
    view = view_of(meta["pose3"], ctx.view_rotations)
    key = np.concatenate([meta["hand_pose"], meta["hand_trans"]]).astype(np.float32).tobytes()
    grasp, hand_pose, hand_trans = ctx.grasps.setdefault(key, (len(ctx.grasps), meta["hand_pose"], meta["hand_trans"]))
    row = {"frame_id": frame_id, "keypoints_3d_cam": kp3d, "keypoints_2d": kp2d, "visible": visible, "K": ctx.K,
           "T_cam_world": T_cam_probe, "grasp_id": grasp, "grasp_index": grasp, "view_id": view,
           "theta": ctx.view_angles[view, 0] if view >= 0 else -1.0,
           "phi": ctx.view_angles[view, 1] if view >= 0 else -1.0, "z_ego": meta["z"],
           "background_id": ctx.backgrounds.index(meta["bg_name"]), "glove_id": -1, "hand_pose": hand_pose,
           "hand_trans": hand_trans, "light_position_cam": np.zeros(3), "light_color": np.zeros(3),
           "light_energy_w": 0.0}
    write_bytes(frame_path(ctx.out, f.split, "rgb", frame_id), rgb_bytes)
    write_bytes(frame_path(ctx.out, f.split, "depth", frame_id), encode_image(".png", stored))
    write_bytes(frame_path(ctx.out, f.split, "seg", frame_id), encode_image(".png", labels))
    return row, size, slack, depth_kind


def run_import_hup3d(source: str | Path, probe_mesh: str | Path, out: str | Path, split: str | None = None,
                     depth: str = "auto", log=print) -> dict:
    """Convert a published HUP-3D folder into a hupbench dataset at ``out``.

    Args:
        source: the published folder (split folders train/val/test each holding meta/, rgb/, depth/,
            segm/; or one such folder). probe_mesh: the probe PLY the frames were rendered with.
        out: a new or empty folder. split: the split of a folder without split folders (default "test").
        depth: "auto" (the EXR where it exists, else the 8-bit PNG) or "png" (always the PNG).
        log: where the summary line goes.

    Returns:
        {"out", "counts", "frames", "depth_from": {"exr": n, "png": n}, "depth_error_max_m", "views_unknown"}.

    Raises:
        MissingFileError, BadValueError: bad input (each message names the file or option).
    """
    source, out, probe_mesh = Path(source), Path(out), Path(probe_mesh)
    for option, value, allowed in (("--split", split, (None, *SPLITS)), ("--depth", depth, DEPTH_SOURCES)):
        if value not in allowed:
            raise BadValueError(f"{option} must be one of {[v for v in allowed if v]}, got {value!r}")
    check_writable(out, "OUT")
    if out.is_dir() and any(out.iterdir()):
        raise BadValueError(f"output {out} is not empty: import-hup3d writes a new dataset into an empty or new "
                            "folder")
    frames, split_from = find_frames(source, split)
    probe = read_probe_mesh(probe_mesh)
    metas = [read_meta(f.file("meta")) for f in frames]
    K = hupbench_K(metas[0]["cam_calib"])
    for f, meta in zip(frames, metas):
        if np.abs(hupbench_K(meta["cam_calib"]) - K).max() > tol.IMPORT_META_MATCH:
            raise BadValueError(f"{f.file('meta')}: cam_calib differs from the first frame's; one K per dataset")
    backgrounds = sorted({m["bg_name"] for m in metas})
    rows = {s: {name: [] for name in ANNOTATION_FIELDS} for s in SPLITS}
    depth_from = {"exr": 0, "png": 0}
    error_max, size, listing = 0.0, None, []
    # built beside OUT and renamed into place: a frame that fails leaves OUT as it was
    with atomic_folder(out) as stage:
        ctx = ImportContext(depth, K, probe.corners_probe, view_rotations(), all_viewpoints(SphereSpec()), backgrounds,
                            {}, stage)
        for frame_id, (f, meta) in enumerate(zip(frames, metas)):
            row, frame_size, slack, depth_kind = _convert_frame(f, meta, frame_id, size, ctx)
            size = size or frame_size
            depth_from[depth_kind] += 1
            error_max = max(error_max, slack)
            for name, value in row.items():
                rows[f.split][name].append(value)
            listing.append((frame_id, f.split, f.file("meta").relative_to(source).as_posix(),
                            "exr" if depth_kind == "exr" else "png8"))
        counts = _write_tables(stage, rows, listing, ctx.grasps, probe)
        views_unknown = int(sum(np.count_nonzero(np.asarray(rows[s]["view_id"]) < 0) for s in counts))
        summary = {"split_from": split_from, "depth_from": depth_from, "error_max_m": error_max,
                   "views_unknown": views_unknown, "image_size": size, "K": K, "backgrounds": backgrounds,
                   "grasps_sha256": file_sha256(stage / GRASPS)}
        write_json(stage / MANIFEST, _manifest(source, probe, metas, rows, counts, summary))
    log(f"hupbench import-hup3d: {len(frames)} frames ({', '.join(f'{s} {n}' for s, n in counts.items())}) -> {out}; "
        f"depth from EXR {depth_from['exr']}, from 8-bit PNG {depth_from['png']}"
        + (f" (approximate: up to {1000 * error_max:.2f} mm off)" if depth_from["png"] else "")
        + (f"; {views_unknown} frame(s) of no published view (view_id -1)" if views_unknown else ""))
    return {"out": out, "counts": counts, "frames": len(frames), "depth_from": depth_from,
            "depth_error_max_m": error_max, "views_unknown": views_unknown}


def _write_tables(out: Path, rows: dict, listing: list[tuple], grasps: dict, probe) -> dict[str, int]:
    """Each split's annotations.npz, imported_frames.csv (frame id -> published meta file) and grasps.npz (the
    distinct grasps in grasp-index order, and the probe's geometry as ``hupbench grasps`` stores a mesh
    probe's). Returns the frame count of each split that has frames."""
    from hupbench.datagen.assets.probe_mesh import probe_arrays

    counts = {}
    for s in SPLITS:
        n = len(rows[s]["frame_id"])
        if n:
            counts[s] = n
            save_npz(out / s / ANNOTATIONS, {name: np.asarray(values, dtype=ANNOTATION_FIELDS[name][0])
                                             for name, values in rows[s].items()})
    text = io.StringIO()
    writer = csv.writer(text, lineterminator="\n")
    writer.writerow(["frame_id", "split", "published_meta", "depth_from"])
    writer.writerows(listing)
    write_bytes(out / "imported_frames.csv", text.getvalue().encode())
    save_npz(out / GRASPS, {"hand_pose": np.array([pose for _, pose, _ in grasps.values()], np.float64),
                            "hand_trans": np.array([trans for _, _, trans in grasps.values()], np.float64),
                            "grasp_id": np.arange(len(grasps), dtype=np.int64), **probe_arrays(probe)})
    return counts


def _manifest(source: Path, probe, metas: list[dict], rows: dict, counts: dict, summary: dict) -> dict:
    """The imported dataset's manifest: the contract's fields, the probe's record (as ``hupbench generate``
    records a mesh probe) and an "imported" block saying what came from where and what is unknown."""
    corners = probe.corners_probe
    return {
        "schema_version": SCHEMA_VERSION,
        "generator": {"name": "hupbench.import_hup3d", "format": FORMAT},
        "counts": counts, "keypoint_names": list(kp.KEYPOINT_NAMES),
        "skeleton_edges": [list(e) for e in kp.SKELETON_EDGES], "image_size": list(summary["image_size"]),
        "K": summary["K"].tolist(),
        "modalities": ["rgb", "depth", "seg"], "rgb_format": "jpg", "depth_scale_m": DEPTH_SCALE_M,
        "seg_labels": dict(SEG_LABELS),
        "layout": {"shape": [sum(counts.values()), 1, 1, 1, 1], "order": ["grasp", "z_ego", "background", "glove", "view"],
                   "index": "imported: frame_id numbers the published frames in (split, published number) order; "
                            "imported_frames.csv maps each to its published meta file"},
        "grasp_ids": {s: sorted(set(rows[s]["grasp_id"])) for s in counts},
        "grasp_indices": {s: sorted(set(rows[s]["grasp_index"])) for s in counts},
        "grasps_sha256": summary["grasps_sha256"],
        "probe": probe.record,
        "backgrounds": {"names": summary["backgrounds"]},
        "z_ego_m": sorted({m["z"] for m in metas}),
        "imported": {
            "format": FORMAT, "source": str(source.resolve()),
            "split_from": summary["split_from"],
            "probe_mesh": {"path": probe.spec.path, "sha256": probe.spec.sha256,
                           "frame": "the mesh's own frame: T_cam_world maps it into the camera, the corners are "
                                    "its vertices' axis-aligned box",
                           "box_min_m": corners[0].tolist(), "box_max_m": corners[-1].tolist()},
            "depth": {"approximate": summary["depth_from"]["png"] > 0, "frames_from_exr": summary["depth_from"]["exr"],
                      "frames_from_png8": summary["depth_from"]["png"], "error_max_m": summary["error_max_m"],
                      "note": "planar z from Cycles' radial depth; from the 8-bit PNG each level is "
                              "(far - near) / 254, so a depth is off by up to (far - near) / 508"},
            "seg_map": {str(k): v for k, v in PUBLISHED_SEG.items()},
            "hand": "coords_3d in OpenPose order (the renderer's reordering); hand_pose and hand_trans are the "
                    "published MANO parameters, not hupbench's hand model",
            "views_unknown": summary["views_unknown"],
            "unknown": UNKNOWN,
        },
    }
