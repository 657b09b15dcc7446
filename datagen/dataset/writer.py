"""Dataset generation: Algorithm 1 of HUP-3D, written to the dataset contract of DESIGN.md.

Frames are the product grasps x z_ego x backgrounds x gloves x viewpoints.
The frame index is the mixed-radix number of that tuple, viewpoints fastest:

    i = (((grasp * n_z + z) * n_bg + bg) * n_glove + glove) * n_view + view

and frame ``i`` is a pure function of (config, i): its camera comes from the
sphere, its lamp from a generator seeded with (seed, i). Frames are rendered
in chunks of one (grasp, z_ego, background) block (n_glove x n_view frames
sharing the meshes); a chunk's image files are written atomically, then its
annotation rows, also atomically: a chunk whose rows exist is done, any
other is rendered again on resume (overwriting, never duplicating).
``shard=k/n`` renders only the chunks ``c`` with ``c % n == k``. Chunks are
rendered by :class:`ChunkRenderer`, in local worker processes or on Ray actors
(:mod:`datagen.dataset.ray_launcher`), and written by :func:`write_chunk`. When every
chunk is done the rows are merged into ``<split>/annotations.npz`` and
``manifest.json`` is written last.

Convention:
    Annotations are in the OpenCV camera frame, metres; 2D in pixels of the
    stored image. World = probe frame.
"""

from __future__ import annotations

import contextlib
import ctypes
import hashlib
import io
import json
import math
import multiprocessing
import os
import pickle
import shutil
import signal
import sys
import threading
import time
import zipfile
import zlib
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Iterator

import cv2
import numpy as np

from datagen.render import gl
from datagen import keypoints as kp
from datagen import tolerances as tol
from datagen.camera import Intrinsics, project_points
from datagen.dataset.contract import ANNOTATION_DTYPES, DEPTH_SCALE_M, SCHEMA_VERSION, SPLITS, frame_path
from datagen.geometry import axis_angle_to_matrix, invert_transform, transform_points
from datagen.io import TMP_PATTERN, DiskFullError, LockedError, OutputLock, save_npz, write_bytes, write_json, write_with
from datagen.processes import check_workers as check_processes
from datagen.dataset.ray_launcher import RayOptions, check_launcher
from datagen.render.renderer import MODALITIES, SEG_LABELS, PointLight, RenderSettings, check_modalities
from datagen.render.scene import ARM_RGB, GLOVE_RGB, Grasp, scene_parts
from datagen.dataset.sphere import (
    SphereSpec,
    camera_pose,
    excluded_view_ids,
    sphere_frame,
    unit_directions,
    viewpoints,
)

GENERATOR_VERSION = "0.2.0"  # 0.2: the published renderer's sphere and look-at by default (issue 13)
#: HUP-3D's lamp (REFERENCE.md), in the camera frame of the published renderer
LAMP_LOW = np.array([-0.6, 0.1, 0.5])
LAMP_HIGH = np.array([0.6, 0.4, 0.5])
#: what the camera can aim at besides a keypoint (by name): the centre of the 29 keypoints' box in
#: the world (probe) frame, hupbench's aim before issue 13
BOX_CENTRE = "box_centre"
#: the published renderer's aim: the right middle-finger MCP (SMPL-H joint 40, our keypoint 9)
PAPER_LOOK_AT = "middle_mcp"
#: pyrender intensity per Blender watt, calibrated so the middle of HUP-3D's 50-300 W range
#: exposes a gloved hand at 0.5 m like the preview
LAMP_INTENSITY_PER_WATT = 0.0075


#: the camera distances a dataset may use, metres: nearer than 0.1 m the hand and probe reach behind the
#: camera plane (z_ego 0.001: 8 keypoints behind it), beyond 10 m they cover a few pixels
Z_EGO_RANGE_M = (0.1, 10.0)
#: the largest image side the renderer is asked for (as predict's largest input)
MAX_IMAGE_SIDE = 8192


def _whole(name: str, value, low: int, high: int | None) -> None:
    if isinstance(value, bool) or not isinstance(value, int):
        raise ValueError(f"dataset.{name} must be a whole number, got {value!r}")
    if value < low or (high is not None and value > high):
        bound = f"in [{low}, {high}]" if high is not None else f">= {low}"
        raise ValueError(f"dataset.{name} must be {bound}, got {value}")


def _distances(z_ego_m) -> tuple:
    low, high = Z_EGO_RANGE_M
    values = list(z_ego_m) if not isinstance(z_ego_m, (str, bytes)) and hasattr(z_ego_m, "__iter__") else None
    if not values or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                             and low <= v <= high for v in values):
        raise ValueError(f"dataset.z_ego_m must be a non-empty list of camera distances from {low} to {high} m "
                         f"(e.g. [0.5, 0.8]), got {z_ego_m if values is None else values!r}")
    return tuple(float(v) for v in values)


@dataclass(frozen=True)
class DatasetSpec:
    """Everything that determines the frames.

    Attributes:
        z_ego_m: camera distances to the grasp, metres.
        splits: grasps per split, in the order of the grasps file (train, val, test).
        modalities: which of rgb, depth, seg to write.
        rgb_format: "jpg" or "png". jpeg_quality: 0-100.
        seed: lamp randomisation seed.
        sphere: the viewpoint sphere.
        look_at: the point each camera looks at from distance z_ego, which lands at
            (0, 0, z_ego) in the camera frame: a keypoint name (default "middle_mcp", keypoint 9,
            as the published renderer) or "box_centre" (centre of the 29 keypoints' box in the
            world frame).
        width, height, fx, fy, cx, cy: the camera.
        n_backgrounds, n_gloves: counts (backgrounds come from the background set).
    """

    z_ego_m: tuple = (0.5, 0.8)
    splits: dict = field(default_factory=lambda: {"train": 7, "val": 2, "test": 2})
    modalities: tuple = MODALITIES
    rgb_format: str = "jpg"
    jpeg_quality: int = 95
    seed: int = 0
    sphere: SphereSpec = SphereSpec()
    look_at: str = PAPER_LOOK_AT
    width: int = 256
    height: int = 256
    fx: float = 480.0
    fy: float = 480.0
    cx: float = 128.0
    cy: float = 128.0
    n_backgrounds: int = 8
    n_gloves: int = 2

    def __post_init__(self) -> None:
        object.__setattr__(self, "z_ego_m", _distances(self.z_ego_m))
        for name, low, high in (("jpeg_quality", 0, 100), ("seed", 0, None), ("width", 1, MAX_IMAGE_SIDE),
                                ("height", 1, MAX_IMAGE_SIDE), ("n_backgrounds", 1, None), ("n_gloves", 1, None)):
            _whole(name, getattr(self, name), low, high)
        splits = dict(self.splits)
        if set(splits) - set(SPLITS) or any(isinstance(v, bool) or not isinstance(v, int) or v < 0
                                            for v in splits.values()):
            raise ValueError(f"splits must map {SPLITS} to grasp counts >= 0, got {splits}")
        object.__setattr__(self, "splits", {s: splits.get(s, 0) for s in SPLITS})
        object.__setattr__(self, "modalities", check_modalities(self.modalities))
        if self.rgb_format not in ("jpg", "png"):
            raise ValueError(f"rgb_format must be 'jpg' or 'png', got {self.rgb_format!r}")
        Intrinsics(self.fx, self.fy, self.cx, self.cy, self.width, self.height)  # validates
        if self.n_gloves not in (1, 2):
            raise ValueError(f"n_gloves must be 1 or 2 (HUP-3D's two glove colours), got {self.n_gloves}")
        if self.look_at != BOX_CENTRE and self.look_at not in kp.KEYPOINT_NAMES:
            raise ValueError(f"look_at must be {BOX_CENTRE!r} or a keypoint name (e.g. {PAPER_LOOK_AT!r}), "
                             f"got {self.look_at!r}")

    @property
    def intrinsics(self) -> Intrinsics:
        return Intrinsics(self.fx, self.fy, self.cx, self.cy, self.width, self.height)


@dataclass(frozen=True)
class Layout:
    """The frame index <-> (grasp, z, background, glove, view) bijection."""

    n_grasps: int
    n_z: int
    n_backgrounds: int
    n_gloves: int
    n_views: int

    @property
    def shape(self) -> tuple[int, ...]:
        return (self.n_grasps, self.n_z, self.n_backgrounds, self.n_gloves, self.n_views)

    @property
    def size(self) -> int:
        return int(np.prod(self.shape))

    @property
    def chunk_size(self) -> int:
        return self.n_gloves * self.n_views

    @property
    def n_chunks(self) -> int:
        return self.n_grasps * self.n_z * self.n_backgrounds

    def index(self, grasp: int, z: int, background: int, glove: int, view: int) -> int:
        """Frame index of a tuple (each component in range)."""
        return int(np.ravel_multi_index((grasp, z, background, glove, view), self.shape))

    def tuple(self, index: int) -> tuple[int, int, int, int, int]:
        """Inverse of :meth:`index`."""
        if not 0 <= index < self.size:
            raise ValueError(f"frame index {index} out of range [0, {self.size})")
        return tuple(int(v) for v in np.unravel_index(index, self.shape))

    def chunk_frames(self, chunk: int) -> range:
        return range(chunk * self.chunk_size, (chunk + 1) * self.chunk_size)


def split_of_grasps(spec: DatasetSpec, n_grasps: int) -> dict[str, list[int]]:
    """Grasp indices of each split: consecutive in the grasps file, train first."""
    total = sum(spec.splits.values())
    if total != n_grasps:
        raise ValueError(f"splits {spec.splits} add up to {total} grasps but the grasps file holds {n_grasps}")
    out, start = {}, 0
    for name in SPLITS:
        out[name] = list(range(start, start + spec.splits[name]))
        start += spec.splits[name]
    return out


def lamp(spec: DatasetSpec, index: int) -> dict[str, np.ndarray]:
    """The frame's lamp, a pure function of (seed, frame index).

    Returns:
        "position_cam" (3,) metres in the OpenCV camera frame (HUP-3D's box with y up
        turned to y down), "color" (3,) = (c, c, b), "energy_w" Blender watts.
    """
    rng = np.random.default_rng([spec.seed, index])
    x, y, z = rng.uniform(LAMP_LOW, LAMP_HIGH)
    c, b = rng.uniform(0.6, 1.0, size=2)
    return {"position_cam": np.array([x, -y, z]), "color": np.array([c, c, b]),
            "energy_w": np.array(rng.uniform(50.0, 300.0))}


#: what a dataset needs of a grasps.npz: array -> (dtype kind: "f" float / "i" integer, row shape)
GRASP_FIELDS = {"hand_pose": ("f", (48,)), "hand_trans": ("f", (3,)), "grasp_id": ("i", ())}


def read_grasps(path: str | Path | bytes) -> dict[str, np.ndarray]:
    """Read and check the arrays a dataset is rendered from, out of a grasps.npz (``hupbench grasps``).

    Every array of :data:`GRASP_FIELDS` is read in full (the zip's CRC is checked on the way) and
    checked: a float (pose, translation) or integer (ids) dtype, the row shape, one row per grasp
    in each, at least one grasp, finite values, unique ids.

    Args:
        path: the file, or its bytes (what a Ray actor on another machine is sent).

    Returns:
        {"hand_pose": (G, 48) float64 axis-angle radians, "hand_trans": (G, 3) float64 metres,
        "grasp_id": (G,) int64}.

    Raises:
        FileNotFoundError: no such file. ValueError: anything else wrong; the message names the
        file and what was expected.
    """
    if isinstance(path, bytes):
        name, source = "grasps (bytes)", io.BytesIO(path)
    else:
        path = Path(path)
        name, source = str(path), path
        if path.is_dir():
            raise ValueError(f"grasps file {path} is a folder; expected a grasps.npz written by `hupbench grasps`")
        if not path.is_file():
            raise FileNotFoundError(f"grasps file {path} not found (run `hupbench grasps` or set grasps_path=null)")
        if path.stat().st_size == 0:
            raise ValueError(f"grasps file {path} is empty (0 bytes); expected a grasps.npz written by `hupbench grasps`")
    if not zipfile.is_zipfile(source):
        size = len(path) if isinstance(path, bytes) else path.stat().st_size
        raise ValueError(f"grasps file {name} is not an .npz archive ({size} bytes, no zip directory); expected a "
                         "grasps.npz written by `hupbench grasps`")
    if isinstance(source, io.BytesIO):
        source.seek(0)  # is_zipfile read the end of the buffer
    arrays = {}
    try:
        with np.load(source, allow_pickle=False) as data:
            if not hasattr(data, "files"):
                raise ValueError(f"grasps file {name} holds a single array, not an .npz archive of the arrays "
                                 f"{list(GRASP_FIELDS)}")
            absent = [k for k in GRASP_FIELDS if k not in data.files]
            if absent:
                raise ValueError(f"grasps file {name} lacks the arrays {absent} (it holds {sorted(data.files)}); "
                                 "expected a grasps.npz written by `hupbench grasps`")
            for key in GRASP_FIELDS:
                try:
                    arrays[key] = data[key]
                except ValueError as exc:  # object arrays: numpy refuses to unpickle them
                    raise ValueError(f"grasps file {name}: {key} cannot be read as a numeric array ({exc})") from None
    except ValueError as exc:
        if str(exc).startswith("grasps file"):
            raise
        raise ValueError(f"grasps file {name} is not an .npz archive ({exc})") from None
    except (zipfile.BadZipFile, zipfile.LargeZipFile, EOFError, KeyError, zlib.error, OSError) as exc:
        if isinstance(exc, FileNotFoundError):
            raise
        raise ValueError(f"grasps file {name} is damaged or not an .npz archive ({type(exc).__name__}: {exc}); "
                         "write it again with `hupbench grasps`") from None
    rows = {k: a.shape[0] if a.ndim else None for k, a in arrays.items()}
    for key, (kind, row_shape) in GRASP_FIELDS.items():
        array = arrays[key]
        if array.dtype.kind not in (("f", "i", "u") if kind == "f" else ("i", "u")):
            raise ValueError(f"grasps file {name}: {key} is {array.dtype}, expected "
                             + ("float numbers" if kind == "f" else "integer ids"))
        if array.ndim != 1 + len(row_shape) or array.shape[1:] != row_shape:
            raise ValueError(f"grasps file {name}: {key} has shape {array.shape}, expected (G, "
                             + ", ".join(str(v) for v in row_shape) + ")" if row_shape else f"grasps file {name}: "
                             f"{key} has shape {array.shape}, expected (G,)")
    if len(set(rows.values())) != 1:
        raise ValueError(f"grasps file {name}: the arrays have different numbers of rows {rows}; expected one row "
                         "per grasp in each")
    if rows["hand_pose"] == 0:
        raise ValueError(f"grasps file {name} holds no grasps (0 rows)")
    out = {"hand_pose": arrays["hand_pose"].astype(np.float64), "hand_trans": arrays["hand_trans"].astype(np.float64),
           "grasp_id": arrays["grasp_id"].astype(np.int64)}
    for key in ("hand_pose", "hand_trans"):
        bad = ~np.isfinite(out[key]).all(axis=1)
        if bad.any():
            raise ValueError(f"grasps file {name}: {key} must be finite; rows {np.flatnonzero(bad)[:10].tolist()} "
                             "hold NaN or inf")
    ids, counts = np.unique(out["grasp_id"], return_counts=True)
    if (counts > 1).any():
        raise ValueError(f"grasps file {name}: grasp_id must be unique, {ids[counts > 1][:10].tolist()} repeat")
    return out


class GraspSet:
    """The grasps a dataset is rendered from (``grasps.npz``), with derived geometry.

    Args:
        path: a grasps.npz, or its bytes (what a Ray actor on another machine is sent).
    """

    def __init__(self, path: str | Path | bytes) -> None:
        from datagen.assets.hand import build_hand
        from datagen.assets.probe import build_probe

        arrays = read_grasps(path)
        self.hand_pose, self.hand_trans, self.grasp_id = arrays["hand_pose"], arrays["hand_trans"], arrays["grasp_id"]
        self.path = None if isinstance(path, bytes) else Path(path)
        hand, probe = build_hand(), build_probe()
        self.keypoints_world = np.concatenate(
            [hand.keypoints(self.hand_pose, self.hand_trans, clamp=False),
             np.broadcast_to(probe.corners_probe, (len(self), kp.NUM_CORNERS, 3))], axis=1)
        R = axis_angle_to_matrix(self.hand_pose[:, :3])
        self.forearm_axis = -R[:, :, 0]
        self.dorsal = R[:, :, 1]
        self.box_centre = 0.5 * (self.keypoints_world.min(axis=1) + self.keypoints_world.max(axis=1))

    def __len__(self) -> int:
        return len(self.hand_pose)

    def look_at_points(self, look_at: str) -> np.ndarray:
        """(G, 3) float64, metres, world frame: each grasp's camera target (see ``DatasetSpec.look_at``)."""
        if look_at == BOX_CENTRE:
            return self.box_centre
        if look_at not in kp.KEYPOINT_NAMES:
            raise ValueError(f"look_at must be {BOX_CENTRE!r} or a keypoint name, got {look_at!r}")
        return self.keypoints_world[:, kp.KEYPOINT_NAMES.index(look_at)]


def frame_camera(spec: DatasetSpec, grasps: GraspSet, layout: Layout, index: int) -> dict:
    """Camera and annotation geometry of one frame (no rendering)."""
    g, z, b, c, v = layout.tuple(index)
    view_ids, angles = viewpoints(spec.sphere)
    theta, phi = angles[v]
    frame = sphere_frame(grasps.forearm_axis[g], grasps.dorsal[g], spec.sphere.axis)
    T_cam_world = camera_pose(theta, phi, spec.z_ego_m[z], grasps.look_at_points(spec.look_at)[g], frame,
                              spec.sphere.axis)
    keypoints_cam = transform_points(T_cam_world, grasps.keypoints_world[g])
    return {"grasp": g, "z": z, "background": b, "glove": c, "view": v, "view_id": int(view_ids[v]),
            "theta": theta, "phi": phi, "T_cam_world": T_cam_world, "keypoints_cam": keypoints_cam,
            "keypoints_2d": project_points(keypoints_cam, spec.intrinsics.K)}


def view_directions_arm(sphere: SphereSpec, angles: np.ndarray) -> np.ndarray:
    """(V, 3) float64 unit vectors from the target to the camera in the arm frame.

    The arm frame's columns are hand -> elbow, dorsal and their cross product (the thumb side of
    a right hand), :func:`datagen.dataset.sphere.arm_frame`; ``angles`` is (V, 2) (theta, phi) radians.
    """
    # the sphere frame of an arm frame equal to the identity gives the sphere's axes in arm coordinates
    frame = sphere_frame(np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]), sphere.axis)
    return unit_directions(angles) @ frame.T


def protocol(spec: DatasetSpec) -> dict:
    """The viewing protocol of a dataset, for its manifest.

    "name" is "paper" when the sphere, its exclusions and the look-at are the published
    renderer's, "forearm_box_centre" when they are hupbench's before issue 13, else "custom".
    """
    s = spec.sphere
    geometry = (s.r_sph_m, s.r_circ_m, s.variant) == (0.8, 0.15, "ceil")
    if geometry and s.axis == "body" and s.exclude == ("elbow",) and s.elbow_cone_deg == 10.0 \
            and spec.look_at == PAPER_LOOK_AT:
        name = "paper"
    elif geometry and s.axis == "forearm" and s.exclude == ("poles",) and spec.look_at == BOX_CENTRE:
        name = "forearm_box_centre"
    else:
        name = "custom"
    polar = {"body": "dorsal (back of the hand: the body's vertical, perpendicular to the forearm)",
             "forearm": "forearm (north = hand -> elbow)"}[s.axis]
    up = {"body": "towards the north pole along the meridian (the body's vertical), defined at the poles",
          "forearm": "the fingers (-north); at the poles the dorsal direction"}[s.axis]
    return {"name": name, "sphere_axis": s.axis, "polar_axis": polar, "image_up": up,
            "exclude": list(s.exclude), "elbow_cone_deg": s.elbow_cone_deg,
            "excluded_view_ids": list(excluded_view_ids(s)), "look_at": spec.look_at,
            "look_at_index": None if spec.look_at == BOX_CENTRE else kp.KEYPOINT_NAMES.index(spec.look_at)}


def visibility(keypoints_cam: np.ndarray, keypoints_2d: np.ndarray, depth: np.ndarray, seg: np.ndarray,
               slack_m: float = 0.0) -> np.ndarray:
    """(29,) bool: inside the image and not occluded (definitions in :mod:`datagen.tolerances`).

    Args:
        keypoints_cam: (29, 3) metres, camera frame. keypoints_2d: (29, 2) pixels.
        depth: (H, W) metres, 0 = background. seg: (H, W) labels.
        slack_m: widens the depth bounds (a stored depth map is quantised).
    """
    h, w = depth.shape
    uv = np.round(keypoints_2d).astype(np.int64)
    inside = (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) & (uv[:, 1] < h)
    out = np.zeros(kp.NUM_KEYPOINTS, dtype=bool)
    for i in np.flatnonzero(inside):
        d, label, z = depth[uv[i, 1], uv[i, 0]], seg[uv[i, 1], uv[i, 0]], keypoints_cam[i, 2]
        if i < kp.NUM_HAND:
            out[i] = (label == SEG_LABELS["hand"]
                      and z - tol.VISIBLE_HAND_DEPTH_M - slack_m <= d <= z + tol.VISIBLE_HAND_BEHIND_M + slack_m)
        else:
            out[i] = d == 0 or d >= z - tol.VISIBLE_CORNER_DEPTH_M - slack_m
    return out


# --- rendering chunks ----------------------------------------------------------------


@dataclass
class ChunkOutput:
    """One rendered chunk, encoded and ready to write.

    Attributes:
        chunk: chunk index. split: the split its grasp belongs to.
        files: (modality, frame_id, encoded bytes) per image file, in frame order.
        rows: annotation rows, ``ANNOTATION_DTYPES`` keys, each (chunk_size, ...).
    """

    chunk: int
    split: str
    files: list[tuple[str, int, bytes]]
    rows: dict[str, np.ndarray]


class ChunkRenderer:
    """Renders chunks of a dataset; owns one GL renderer (build one per process and reuse it).

    Both launchers use it: the local worker processes and the Ray actors
    (:mod:`datagen.dataset.ray_launcher`), so a frame comes out the same whichever ran it.

    Args:
        spec: the dataset spec.
        grasps: path of the dataset's grasps.npz, or its bytes (a Ray actor on another machine).
        backgrounds_dir: folder of background photographs, None for the built-ins.
        platform: "egl", "osmesa" or None (automatic), see :mod:`datagen.render.gl`.
    """

    def __init__(self, spec: DatasetSpec, grasps: str | Path | bytes, backgrounds_dir: str | None,
                 platform: str | None) -> None:
        from datagen.assets.backgrounds import BackgroundSet
        from datagen.render.renderer import Renderer

        import torch

        # one torch thread per renderer process: the parallelism is across processes (or actors)
        torch.set_num_threads(1)
        self.spec = spec
        self.grasps = GraspSet(grasps)
        self.backgrounds = BackgroundSet.from_dir(backgrounds_dir) if backgrounds_dir else BackgroundSet.builtin()
        self.renderer = Renderer(spec.intrinsics, platform=platform)
        self._grasp_loaded = None

    def render(self, chunk: int, split: str, layout: Layout) -> ChunkOutput:
        """Render and encode every frame of one chunk (nothing is written).

        Args:
            chunk: chunk index in ``range(layout.n_chunks)``. split: its split. layout: the frame layout.

        Returns:
            The chunk's encoded image files and annotation rows.
        """
        from datagen.assets.backgrounds import composite

        spec, grasps, renderer = self.spec, self.grasps, self.renderer
        rows, files = [], []
        for index in layout.chunk_frames(chunk):
            cam = frame_camera(spec, grasps, layout, index)
            g = cam["grasp"]
            if self._grasp_loaded != g:
                renderer.set_parts(scene_parts(Grasp(grasps.hand_pose[g], grasps.hand_trans[g])))
                self._grasp_loaded = g
            renderer.set_color("hand", GLOVE_RGB[cam["glove"]])
            light = lamp(spec, index)
            T_world_cam = invert_transform(cam["T_cam_world"])
            position_world = transform_points(T_world_cam, light["position_cam"][None])[0]
            settings = RenderSettings(background_rgb=(1.0, 1.0, 1.0), ambient=0.3, lights=[
                PointLight(position_world, tuple(light["color"]), float(light["energy_w"]) * LAMP_INTENSITY_PER_WATT)])
            wanted = set(spec.modalities) | {"depth", "seg"}  # depth and labels decide visibility
            frames = renderer.render(cam["T_cam_world"], tuple(m for m in MODALITIES if m in wanted), settings,
                                     alpha=True)
            if "rgb" in spec.modalities:
                background = self.backgrounds.image(cam["background"], spec.width, spec.height)
                rgb = composite(frames["rgb"], background)
                ext = ".jpg" if spec.rgb_format == "jpg" else ".png"
                params = [cv2.IMWRITE_JPEG_QUALITY, spec.jpeg_quality] if ext == ".jpg" else []
                files.append(("rgb", index, _encode(ext, rgb[..., ::-1], params)))
            if "depth" in spec.modalities:
                depth_u16 = np.round(frames["depth"] / DEPTH_SCALE_M).astype(np.uint16)
                files.append(("depth", index, _encode(".png", depth_u16)))
            if "seg" in spec.modalities:
                files.append(("seg", index, _encode(".png", frames["seg"])))
            rows.append({
                "frame_id": index, "keypoints_3d_cam": cam["keypoints_cam"], "keypoints_2d": cam["keypoints_2d"],
                "visible": visibility(cam["keypoints_cam"], cam["keypoints_2d"], frames["depth"], frames["seg"]),
                "K": spec.intrinsics.K, "T_cam_world": cam["T_cam_world"], "grasp_id": grasps.grasp_id[g],
                "grasp_index": g, "view_id": cam["view_id"], "theta": cam["theta"], "phi": cam["phi"],
                "z_ego": spec.z_ego_m[cam["z"]], "background_id": cam["background"], "glove_id": cam["glove"],
                "hand_pose": grasps.hand_pose[g], "hand_trans": grasps.hand_trans[g],
                "light_position_cam": light["position_cam"], "light_color": light["color"],
                "light_energy_w": light["energy_w"],
            })
        return ChunkOutput(chunk, split, files, _stack_rows(rows))


def _encode(ext: str, image: np.ndarray, params: list[int] | None = None) -> bytes:
    ok, buf = cv2.imencode(ext, image, params or [])
    if not ok:
        raise RuntimeError(f"OpenCV could not encode a {image.shape} {image.dtype} image as {ext}")
    return buf.tobytes()


def write_chunk(root: Path, output: ChunkOutput, rgb_format: str) -> int:
    """Write a rendered chunk: its image files atomically, then its annotation rows (the done mark).

    Writing a chunk twice (a retried range) overwrites the same files with the same bytes.

    Returns:
        The number of frames written.
    """
    for modality, frame_id, data in output.files:
        write_bytes(frame_path(root, output.split, modality, frame_id, rgb_format), data)
    save_npz(_chunk_path(root, output.split, output.chunk), output.rows)
    return len(output.rows["frame_id"])


# the local launcher's per-process state: one ChunkRenderer per worker process
_worker: dict = {}
#: how often a worker's watchdog looks for its parent, seconds
PARENT_POLL_S = 0.2
_PR_SET_PDEATHSIG = 1  # <linux/prctl.h>


def die_with_parent(parent_pid: int) -> None:
    """End this process (SIGKILL) as soon as ``parent_pid``, its parent, dies.

    A worker that outlives a killed ``generate`` would go on writing chunks into the folder, beside
    (and racing) the next run there. On Linux the kernel sends the signal (``PR_SET_PDEATHSIG``);
    a watchdog thread that polls ``os.getppid()`` covers the other systems and a parent that died
    before this was called. Anything a killed worker was writing is a temporary file, removed by the
    next run (:func:`datagen.io.clean_stale_tmp`).

    Args:
        parent_pid: the pid of the process that started this one.
    """
    if sys.platform.startswith("linux"):
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
        except (OSError, AttributeError):
            pass  # no prctl here: the watchdog below does the job, a little later
    if os.getppid() != parent_pid:  # the parent died before the kernel was asked to tell us
        os.kill(os.getpid(), signal.SIGKILL)

    def watch() -> None:
        while os.getppid() == parent_pid:
            time.sleep(PARENT_POLL_S)
        os.kill(os.getpid(), signal.SIGKILL)

    threading.Thread(target=watch, name="parent-watchdog", daemon=True).start()


def _worker_init(spec: DatasetSpec, grasps_path: str, backgrounds_dir: str | None, platform: str | None,
                 parent_pid: int | None = None) -> None:
    if parent_pid is not None:
        die_with_parent(parent_pid)
    _worker["chunks"] = ChunkRenderer(spec, grasps_path, backgrounds_dir, platform)


def _render_chunk(args) -> tuple[int, int]:
    """Render and write one chunk in a local worker; return (chunk, frames written)."""
    chunk, root, split, layout = args
    chunks = _worker["chunks"]
    return chunk, write_chunk(Path(root), chunks.render(chunk, split, layout), chunks.spec.rgb_format)


class _WorkerDiskFull(Exception):
    """A worker's :class:`DiskFullError` on its way to the parent (args: the file's path).

    DiskFullError does not survive pickling (its constructor takes the path, pickle gives it
    OSError's arguments), and a result the pool cannot unpickle stops its result thread: the
    parent would wait forever.
    """


def _render_chunk_in_worker(args) -> tuple[int, int]:
    """:func:`_render_chunk` in a pool worker, raising only exceptions that reach the parent intact."""
    try:
        return _render_chunk(args)
    except DiskFullError as exc:
        raise _WorkerDiskFull(exc.filename) from None
    except Exception as exc:
        try:
            pickle.loads(pickle.dumps(exc))
        except Exception:  # any failure to round-trip would hang the parent: send the message instead
            raise RuntimeError(f"{type(exc).__name__}: {exc}") from None
        raise


def _stack_rows(rows: list[dict]) -> dict[str, np.ndarray]:
    return {k: np.stack([np.asarray(r[k]) for r in rows]).astype(dt) for k, dt in ANNOTATION_DTYPES.items()}


def _chunk_path(root: Path, split: str, chunk: int) -> Path:
    return Path(root) / split / ".chunks" / f"{chunk:05d}.npz"


# --- the run -------------------------------------------------------------------------


def config_hash(resolved: dict) -> str:
    """sha256 of the resolved config with the keys that do not change frames removed."""
    keep = {k: v for k, v in resolved.items()
            if k not in ("workers", "shard", "out_dir", "progress", "launcher", "ray", "_provenance")}
    return hashlib.sha256(json.dumps(keep, sort_keys=True, default=str).encode()).hexdigest()


def check_output_dir(out_dir: Path) -> None:
    """Fail early (before rendering) if the output folder cannot be written."""
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise ValueError(f"out_dir {out_dir} is a file, not a folder")
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
        probe_file = out_dir / f".write_test.tmp{os.getpid()}"  # a temporary name: a killed run's is cleaned
        probe_file.write_bytes(b"")
        probe_file.unlink()
    except OSError as exc:
        raise ValueError(f"output path {out_dir} is not writable: {exc.strerror or exc}") from exc


def parse_shard(shard: str | None) -> tuple[int, int]:
    """"k/n" -> (k, n) with 0 <= k < n; None -> (0, 1)."""
    if shard in (None, "", "0/1"):
        return 0, 1
    try:
        k, n = (int(x) for x in str(shard).split("/"))
    except ValueError as exc:
        raise ValueError(f"shard must look like k/n (e.g. 0/4), got {shard!r}") from exc
    if not (n >= 1 and 0 <= k < n):
        raise ValueError(f"shard {shard!r}: need 0 <= k < n")
    return k, n


LOCKS_DIR = ".locks"


def shard_lock_folder(out_dir: Path, k: int, n: int) -> Path:
    """Where shard ``k/n`` of a dataset keeps its lock (an unsharded run locks ``out_dir`` itself)."""
    return Path(out_dir) / LOCKS_DIR / f"shard-{k}-of-{n}"


@contextlib.contextmanager
def run_lock(out_dir: Path, shard: str | None = None) -> Iterator[OutputLock]:
    """Hold the output folder for one generate run (see :class:`datagen.io.OutputLock`).

    An unsharded run holds ``out_dir`` itself and refuses to start while a shard run is live there.
    Shard ``k/n`` holds its own lock, so that several machines can render the shards of one dataset
    into one (shared) folder at once, and refuses to start while an unsharded run holds the folder;
    the shard that finds every chunk done takes the folder's lock to write the annotations and the
    manifest.

    Raises:
        LockedError: another live run holds what this one needs; the message names its pid and host.
    """
    out_dir = Path(out_dir)
    k, n = parse_shard(shard)
    if n == 1:
        with OutputLock(out_dir, "generate") as lock:
            for folder in sorted((out_dir / LOCKS_DIR).glob("shard-*")):
                with OutputLock(folder, "generate"):  # a live shard's lock raises; a dead one's is removed
                    pass
            yield lock
    else:
        with OutputLock(shard_lock_folder(out_dir, k, n), f"generate shard {k}/{n}") as lock:
            with OutputLock(out_dir, "generate"):  # an unsharded run on the folder raises
                pass
            yield lock
    if (out_dir / "manifest.json").is_file():
        _remove_lock_folders(out_dir)


def _remove_lock_folders(out_dir: Path) -> None:
    """Remove the empty shard-lock folders of a finished dataset (a live shard's stays)."""
    for folder in sorted((out_dir / LOCKS_DIR).glob("shard-*")):
        with contextlib.suppress(OSError):
            folder.rmdir()
    with contextlib.suppress(OSError):
        (out_dir / LOCKS_DIR).rmdir()


def _remove_all_tmp(out_dir: Path) -> list[Path]:
    """Remove every temporary file (:data:`datagen.io.TMP_PATTERN`) under ``out_dir``.

    Only called while this run holds the folder and no worker of it is running: every such file
    is then the remains of a killed writer, whatever its pid (a pid can be reused, or belong to
    another machine sharing the folder).
    """
    removed = []
    for path in out_dir.rglob(".*.tmp*"):
        if TMP_PATTERN.match(path.name) and path.is_file():
            path.unlink(missing_ok=True)
            removed.append(path)
    return removed


def _remove_tmp_of(out_dir: Path, pids: set[int] | None) -> None:
    """After a failed run: remove the temporary files of ``pids`` (None: all of them, for a run that
    holds the whole folder). The write that failed removed its own; the workers stopped with it
    may have been in the middle of one."""
    for path in out_dir.rglob(".*.tmp*"):
        match = TMP_PATTERN.match(path.name)
        if match and (pids is None or int(match.group(1)) in pids):
            path.unlink(missing_ok=True)


def _file_digest(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def check_workers(workers, launcher: str = "local") -> None:
    """Refuse a worker count that is not a whole number >= 1, or, for the local launcher, more processes
    than :func:`datagen.processes.check_workers` allows (Ray actors may live on other machines)."""
    if launcher == "local":
        check_processes(workers)
    elif isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ValueError(f"workers must be a whole number >= 1, got {workers!r}")


def generate(spec: DatasetSpec, out_dir: Path, grasps_path: Path, resolved_config: dict,
             backgrounds_dir: str | None = None, workers: int = 1, shard: str | None = None,
             platform: str | None = None, progress: bool = True, log=print, launcher: str = "local",
             ray: RayOptions | None = None, lock: OutputLock | None = None) -> dict:
    """Render (or resume) a dataset. See the module docstring for the layout and the guarantees.

    Everything is checked before anything is written; then the run holds the output folder
    (:func:`run_lock`) until it returns, removes the temporary files of killed runs, and renders
    what is missing.

    Args:
        launcher: "local" renders in ``workers`` processes on this machine; "ray" on Ray actors
            (:mod:`datagen.dataset.ray_launcher`, options in ``ray``). Both write the same files.
        ray: :class:`datagen.dataset.ray_launcher.RayOptions` (None: the defaults, a private runtime
            with ``workers`` actors).
        lock: the lock of this run when the caller already holds it (``with run_lock(out_dir,
            shard) as lock``); None takes it here.

    Returns:
        dict with "out_dir", "frames_total", "frames_rendered" (this run), "seconds",
        "complete" (manifest written) and "counts" per split.

    Raises:
        LockedError: another live generate run holds the folder (or this shard).
    """
    from datagen.assets.backgrounds import BackgroundSet
    check_launcher(launcher)
    if ray is not None and not isinstance(ray, RayOptions):
        raise TypeError(f"ray must be a RayOptions or None, got {type(ray).__name__}")
    if not isinstance(spec, DatasetSpec):
        raise TypeError(f"spec must be a DatasetSpec, got {type(spec).__name__}")
    out_dir = Path(out_dir)
    k, n = parse_shard(shard)
    check_workers(workers, launcher)
    if platform is not None and platform not in gl.PLATFORMS:
        raise ValueError(f"render.platform must be one of {', '.join(gl.PLATFORMS)} or null (automatic), "
                         f"got {platform!r}")
    if not isinstance(progress, bool):
        raise ValueError(f"progress must be true or false, got {progress!r}")
    backgrounds = BackgroundSet.from_dir(backgrounds_dir) if backgrounds_dir else BackgroundSet.builtin()
    if len(backgrounds) < spec.n_backgrounds:
        raise ValueError(f"dataset.n_backgrounds={spec.n_backgrounds} but the background set holds only "
                         f"{len(backgrounds)} image(s)" + (f" ({backgrounds_dir})" if backgrounds_dir else ""))
    check_output_dir(out_dir)
    grasps = GraspSet(grasps_path)
    splits = split_of_grasps(spec, len(grasps))
    view_ids, _ = viewpoints(spec.sphere)
    layout = Layout(len(grasps), len(spec.z_ego_m), spec.n_backgrounds, spec.n_gloves, len(view_ids))
    chash = config_hash(resolved_config)
    with contextlib.ExitStack() as stack:
        if lock is None:
            lock = stack.enter_context(run_lock(out_dir, shard))
        elif lock.folder.resolve() != (out_dir if n == 1 else shard_lock_folder(out_dir, k, n)).resolve():
            raise ValueError(f"the lock given holds {lock.folder}, not this run's folder {out_dir} (shard {k}/{n})")
        if lock.taken_over:
            log(f"took over the lock of a generate run that is gone (pid {lock.taken_over.get('pid')} on "
                f"{lock.taken_over.get('host')})")
        result = _generate_locked(spec, out_dir, Path(grasps_path), grasps, splits, layout, chash, resolved_config,
                                  backgrounds, backgrounds_dir, workers, k, n, platform, progress, log, launcher,
                                  ray, stack)
    return result


def _generate_locked(spec, out_dir, grasps_path, grasps, splits, layout, chash, resolved_config, backgrounds,
                     backgrounds_dir, workers, k, n, platform, progress, log, launcher, ray, stack) -> dict:
    """The part of :func:`generate` that runs while it holds the folder (or its shard)."""
    if n == 1:
        # no other run is live here (the lock): whatever temporary files lie around are a killed run's.
        # A shard leaves them to the finishing run, since other shards may be writing theirs
        _remove_all_tmp(out_dir)
    progress_file = out_dir / ".progress.json"
    manifest_file = out_dir / "manifest.json"
    if manifest_file.is_file():
        return _finished(out_dir, layout, chash)
    if progress_file.is_file():
        try:
            started = json.loads(progress_file.read_text())
        except ValueError as exc:
            raise ValueError(f"{progress_file} is not valid JSON ({exc}); delete it to start the dataset "
                             "again") from None
        if not isinstance(started, dict) or started.get("config_hash") != chash:
            raise ValueError(f"{out_dir} holds a partial dataset started with another config; "
                             "resume it with the same config or choose a new out_dir")
        copied = out_dir / "grasps.npz"
        if copied.is_file() and copied.resolve() != grasps_path.resolve() \
                and _file_digest(copied) != _file_digest(grasps_path):
            raise ValueError(f"{out_dir} holds a partial dataset started with other grasps than {grasps_path} "
                             "(its grasps.npz differs); resume it with the same grasps or choose a new out_dir")
    else:
        write_json(progress_file, {"config_hash": chash, "layout": asdict(layout)})
    if not (out_dir / "grasps.npz").is_file() or grasps_path.resolve() != (out_dir / "grasps.npz").resolve():
        write_with(out_dir / "grasps.npz", lambda tmp: shutil.copyfile(grasps_path, tmp))

    split_of = {g: s for s, gs in splits.items() for g in gs}
    chunk_split = [split_of[layout.tuple(c * layout.chunk_size)[0]] for c in range(layout.n_chunks)]
    todo = [c for c in range(layout.n_chunks) if c % n == k and not _chunk_path(out_dir, chunk_split[c], c).is_file()]
    start = time.perf_counter()
    rendered = 0
    if todo:
        log(f"rendering {len(todo) * layout.chunk_size} frames ({len(todo)} chunks) with "
            + (f"{workers} worker(s)" if launcher == "local" else "Ray") + (f", shard {k}/{n}" if n > 1 else ""))
        for split in SPLITS:
            for m in spec.modalities:
                (out_dir / split / m).mkdir(parents=True, exist_ok=True)
            (out_dir / split / ".chunks").mkdir(parents=True, exist_ok=True)
        jobs = [(c, str(out_dir), chunk_split[c], layout) for c in todo]
        init = (spec, str(out_dir / "grasps.npz"), backgrounds_dir, platform)
        bar = _progress(len(todo) * layout.chunk_size, progress, "rendering")
        writers = {os.getpid()}
        try:
            if launcher == "ray":
                from datagen.dataset.ray_launcher import render_chunks

                def on_chunk(output: ChunkOutput) -> None:
                    nonlocal rendered
                    count = write_chunk(out_dir, output, spec.rgb_format)
                    rendered += count
                    bar.update(count)

                render_chunks(f"{__name__}:ChunkRenderer", [(c, chunk_split[c]) for c in todo], layout, spec,
                              (out_dir / "grasps.npz").read_bytes(), backgrounds_dir, platform, ray or RayOptions(),
                              workers, on_chunk, log=log)
            elif workers == 1:
                _worker_init(*init)
                for _, count in map(_render_chunk, jobs):
                    rendered += count
                    bar.update(count)
            else:
                ctx = multiprocessing.get_context("spawn")
                with ctx.Pool(min(workers, len(jobs)), initializer=_worker_init, initargs=(*init, os.getpid())) as pool:
                    writers.update(p.pid for p in multiprocessing.active_children())
                    try:
                        for _, count in pool.imap_unordered(_render_chunk_in_worker, jobs):
                            rendered += count
                            bar.update(count)
                    except _WorkerDiskFull as exc:
                        raise DiskFullError(exc.args[0]) from None
                    finally:
                        writers.update(p.pid for p in multiprocessing.active_children())
                # leaving the pool stopped its workers (SIGTERM), maybe in the middle of a file
        except BaseException:
            _remove_tmp_of(out_dir, None if n == 1 else writers)
            raise
        finally:
            bar.close()
    seconds = time.perf_counter() - start
    partial = {"out_dir": str(out_dir), "frames_total": layout.size, "frames_rendered": rendered,
               "seconds": seconds, "complete": False, "counts": {}}
    if n > 1:
        # the shards that find every chunk done race to finish the dataset: one at a time, and once
        try:
            stack.enter_context(OutputLock(out_dir, "generate"))
        except LockedError as exc:
            log(f"not finishing the dataset: {exc}")
            return partial
        if manifest_file.is_file():
            return {**_finished(out_dir, layout, chash), "frames_rendered": rendered, "seconds": seconds}
    missing = [c for c in range(layout.n_chunks) if not _chunk_path(out_dir, chunk_split[c], c).is_file()]
    if missing:
        log(f"{len(missing)} chunks still missing (other shards); the manifest is written when all are done")
        return partial
    counts = _finalise(out_dir, spec, layout, splits, chunk_split, resolved_config, chash, backgrounds, grasps)
    return {"out_dir": str(out_dir), "frames_total": layout.size, "frames_rendered": rendered, "seconds": seconds,
            "complete": True, "counts": counts}


def _finished(out_dir: Path, layout: Layout, chash: str) -> dict:
    """The answer for a folder whose manifest exists: done if it is this config's dataset."""
    from datagen.dataset.contract import read_manifest

    manifest = read_manifest(out_dir)
    if manifest.get("config_hash") != chash:
        raise ValueError(f"{out_dir} holds a finished dataset made with another config; choose a new out_dir")
    _remove_scaffolding(out_dir)
    return {"out_dir": str(out_dir), "frames_total": layout.size, "frames_rendered": 0, "seconds": 0.0,
            "complete": True, "counts": manifest["counts"]}


def _progress(total: int, enabled: bool, desc: str | None = None, unit: str = "frame"):
    from tqdm import tqdm

    return tqdm(total=total, unit=unit, desc=desc, disable=not enabled, smoothing=0.1, dynamic_ncols=True)


def _finalise(out_dir, spec, layout, splits, chunk_split, resolved_config, chash, backgrounds, grasps) -> dict:
    """Merge the chunk rows per split, then write the manifest (last)."""
    counts = {}
    for split in SPLITS:
        chunks = [c for c in range(layout.n_chunks) if chunk_split[c] == split]
        parts = []
        for c in chunks:
            with np.load(_chunk_path(out_dir, split, c)) as data:
                parts.append({key: data[key] for key in data.files})
        merged = {key: np.concatenate([p[key] for p in parts]) for key in ANNOTATION_DTYPES} if parts else \
            {key: np.zeros((0,), dtype=dt) for key, dt in ANNOTATION_DTYPES.items()}
        counts[split] = int(len(merged["frame_id"]))
        if counts[split]:
            save_npz(out_dir / split / "annotations.npz", merged)
    view_ids, angles = viewpoints(spec.sphere)
    manifest = {
        "schema_version": SCHEMA_VERSION,
        "generator": {"name": "hupbench.datagen", "version": GENERATOR_VERSION,
                      "git_commit": resolved_config.get("_provenance", {}).get("git_commit", "unknown")},
        "config": resolved_config,
        "config_hash": chash,
        "counts": counts,
        "grasp_ids": {split: [int(grasps.grasp_id[g]) for g in gs] for split, gs in splits.items()},
        "grasp_indices": splits,
        "layout": {"order": ["grasp", "z_ego", "background", "glove", "view"], "shape": list(layout.shape),
                   "index": "i = (((grasp * n_z + z) * n_bg + bg) * n_glove + glove) * n_view + view",
                   "chunk_size": layout.chunk_size},
        "image_size": [spec.width, spec.height],
        "K": spec.intrinsics.K.tolist(),
        "modalities": list(spec.modalities),
        "rgb_format": spec.rgb_format,
        "keypoint_names": list(kp.KEYPOINT_NAMES),
        "skeleton_edges": [list(e) for e in kp.SKELETON_EDGES],
        "seg_labels": SEG_LABELS,
        "depth_scale_m": DEPTH_SCALE_M,
        "z_ego_m": list(spec.z_ego_m),
        "viewpoints": {"ids": view_ids.tolist(), "theta_rad": angles[:, 0].tolist(), "phi_rad": angles[:, 1].tolist(),
                       "sphere": asdict(spec.sphere),
                       # target -> camera per view in the arm frame (hand -> elbow, dorsal, thumb side):
                       # the same for every grasp, whichever way the sphere is attached
                       "direction_arm": view_directions_arm(spec.sphere, angles).round(12).tolist()},
        "protocol": protocol(spec),
        "backgrounds": {"names": list(backgrounds.names[: spec.n_backgrounds]),
                        "fingerprint": backgrounds.fingerprint()},
        "gloves_rgb": [list(c) for c in GLOVE_RGB[: spec.n_gloves]],
        "arm_rgb": list(ARM_RGB),
    }
    write_json(out_dir / "manifest.json", manifest)
    _remove_scaffolding(out_dir)
    return counts


def _remove_scaffolding(out_dir: Path) -> None:
    """The manifest is the completion mark; the chunk rows, the progress file and temporary files
    left by killed runs are scaffolding. Also called on a finished folder: a run killed between the
    manifest and this leaves some behind."""
    for split in SPLITS:
        shutil.rmtree(out_dir / split / ".chunks", ignore_errors=True)
    _remove_all_tmp(out_dir)
    (out_dir / ".progress.json").unlink(missing_ok=True)
