"""Rendering one chunk of frames and writing it.

A chunk is the frames of one (grasp, z_ego, background) block in one split (:func:`hupbench.datagen.dataset.spec.chunk_plan`),
sharing the meshes. Its
image files are written atomically, then its annotation rows, also atomically: a chunk whose rows exist
is done. :class:`ChunkRenderer` renders chunks in the local worker processes (which die with their
parent) and on Ray actors (:mod:`hupbench.datagen.dataset.ray_launcher`); :func:`write_chunk` writes them.

Convention:
    Annotations are in the OpenCV camera frame, metres; 2D in pixels of the stored image. World =
    probe frame.
"""

from __future__ import annotations

import ctypes
import json
import os
import pickle
import signal
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from hupbench.core.camera import project_points
from hupbench.core.contract import (ANNOTATION_DTYPES, CLINIC, DEPTH_SCALE_M, SENSOR_DEPTH, annotation_fields, frame_path,
                                    seg_labels)
from hupbench.core.depth_sensor import stored_sensor_depth
from hupbench.datagen.dataset.grasps_file import GraspSet
from hupbench.datagen.dataset.spec import DatasetSpec, LAMP_INTENSITY_PER_WATT, Layout, lamp
from hupbench.datagen.dataset.sphere import camera_pose, sphere_frame, viewpoints
from hupbench.core.geometry import invert_transform, transform_points
from hupbench.core.io import DiskFullError, encode_image, save_npz, write_bytes
from hupbench.datagen.render.renderer import SEG_LABELS, PointLight, RenderSettings
from hupbench.datagen.render.scene import GLOVE_RGB, Grasp, models_of, scene_parts
from hupbench.core import keypoints as kp
from hupbench.core import tolerances as tol
from hupbench.core.errors import RunFailedError


def frame_camera(spec: DatasetSpec, grasps: GraspSet, layout: Layout, index: int, world=None) -> dict:
    """Camera and annotation geometry of one frame (no rendering).

    Args:
        spec, grasps, layout: the dataset's. index: the frame.
        world: the clinic track's :class:`hupbench.datagen.dataset.clinic.ClinicWorld` (its cameras replace the
            sphere's), None on the other tracks.
    """
    g, z, b, c, v = layout.tuple(index)
    if world is not None:
        cams = world.cameras(g)
        T_cam_world, view_id = cams["T_cam_world"][v], v
        theta, phi, z_ego = np.radians(90.0 - cams["elevation_deg"][v]), np.radians(cams["azimuth_deg"][v]), \
            cams["distance_m"][v]
    else:
        view_ids, angles = viewpoints(spec.sphere)
        theta, phi = angles[v]
        frame = sphere_frame(grasps.forearm_axis[g], grasps.dorsal[g], spec.sphere.axis)
        T_cam_world = camera_pose(theta, phi, spec.z_ego_m[z], grasps.look_at_points(spec.look_at)[g], frame,
                                  spec.sphere.axis)
        view_id, z_ego = int(view_ids[v]), spec.z_ego_m[z]
    keypoints_cam = transform_points(T_cam_world, grasps.keypoints_world[g])
    return {"grasp": g, "z": z, "background": b, "glove": c, "view": v, "view_id": view_id,
            "theta": theta, "phi": phi, "z_ego": z_ego, "T_cam_world": T_cam_world, "keypoints_cam": keypoints_cam,
            "keypoints_2d": project_points(keypoints_cam, spec.intrinsics.K)}


def visibility(keypoints_cam: np.ndarray, keypoints_2d: np.ndarray, depth: np.ndarray, seg: np.ndarray,
               slack_m: float = 0.0) -> np.ndarray:
    """(29,) bool: inside the image and not occluded (definitions in :mod:`hupbench.core.tolerances`).

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


def stored_visibility(cam: dict, depth: np.ndarray, seg: np.ndarray) -> np.ndarray:
    """(29,) bool :func:`visibility` of a frame's keypoints as the annotations store them (float32).

    Verify recomputes visibility from the stored keypoints; a 2D coordinate within float32's rounding
    of a half pixel (e.g. 139.4999939 stored as 139.5) would otherwise pick another pixel here than there.

    Args:
        cam: :func:`frame_camera`'s dict ("keypoints_cam", "keypoints_2d"). depth, seg: the frame's
            label pass, metres and labels.
    """
    as_stored = [np.asarray(cam[key], ANNOTATION_DTYPES[field]).astype(np.float64)
                 for key, field in (("keypoints_cam", "keypoints_3d_cam"), ("keypoints_2d", "keypoints_2d"))]
    return visibility(*as_stored, depth, seg)


# --- rendering chunks ----------------------------------------------------------------


@dataclass
class ChunkOutput:
    """One rendered chunk, encoded and ready to write.

    Attributes:
        chunk: chunk index. split: the split its grasp belongs to.
        files: (modality, frame_id, encoded bytes) per image file, in frame order.
        rows: annotation rows, ``ANNOTATION_DTYPES`` keys, each (chunk_size, ...).
        clip: on a dataset of clips, the chunk's clip's record (:func:`hupbench.datagen.dataset.clips.clip_record`
            with "clip_id" and "grasp_index"), written beside its rows for the manifest; None otherwise.
    """

    chunk: int
    split: str
    files: list[tuple[str, int, bytes]]
    rows: dict[str, np.ndarray]
    clip: dict | None = None


class ChunkRenderer:
    """Renders chunks of a dataset; owns one GL renderer (build one per process and reuse it).

    Both launchers use it: the local worker processes and the Ray actors
    (:mod:`hupbench.datagen.dataset.ray_launcher`), so a frame comes out the same whichever ran it.

    Args:
        spec: the dataset spec.
        grasps: path of the dataset's grasps.npz, or its bytes (a Ray actor on another machine).
        backgrounds_dir: folder of background photographs, None for the built-ins.
        platform: "egl", "osmesa" or None (automatic), see :mod:`hupbench.datagen.render.gl`.
    """

    def __init__(self, spec: DatasetSpec, grasps: str | Path | bytes, backgrounds_dir: str | None,
                 platform: str | None) -> None:
        from hupbench.datagen.assets.backgrounds import BackgroundSet
        from hupbench.datagen.render.renderer import Renderer

        import torch

        # one torch thread per renderer process: the parallelism is across processes (or actors)
        torch.set_num_threads(1)
        self.spec = spec
        self.grasps = GraspSet(grasps)
        self.backgrounds = BackgroundSet.from_dir(backgrounds_dir) if backgrounds_dir else BackgroundSet.builtin()
        self.renderer = Renderer(spec.intrinsics, platform=platform)
        #: the clinic track's patients, rooms and cameras (None on the other tracks)
        self.world = None
        if spec.track == CLINIC:
            from hupbench.datagen.dataset.clinic import ClinicWorld

            self.world = ClinicWorld(spec, self.grasps)
        self._grasp_loaded = None
        #: (grasp, z, view) -> what the view's frames share (:meth:`_view`)
        self._views: dict[tuple[int, int, int], dict] = {}

    def render(self, chunk: int, split: str, frames: tuple[int, ...], layout: Layout) -> ChunkOutput:
        """Render and encode every frame of one chunk (nothing is written).

        Args:
            chunk: chunk number (:func:`hupbench.datagen.dataset.spec.chunk_plan`). split: its split.
            frames: its frame indices. layout: the frame layout.

        Returns:
            The chunk's encoded image files and annotation rows.
        """
        if self.spec.sequence:
            return self._render_clip_chunk(chunk, split, frames, layout)
        spec, grasps, world = self.spec, self.grasps, self.world
        rows, files = [], []
        for index in frames:
            cam = frame_camera(spec, grasps, layout, index, world)
            g = cam["grasp"]
            self._load_grasp(g)
            view = self._view(cam)
            light = lamp(spec, index)
            if "rgb" in spec.modalities:
                files.append(("rgb", index, self._encode_rgb(
                    self._colour(g, cam["T_cam_world"], cam["background"], cam["glove"], light))))
            files.extend((modality, index, data) for modality, data in view["files"])
            if spec.sensor is not None:
                files.append(self._sensor_file(index, view["depth"], view["seg"]))
            rows.append(self._row(index, cam, view["visible"], light)
                        | ({} if world is None else world.rows(g, cam["background"], cam["view"])))
        return ChunkOutput(chunk, split, files, _stack_rows(rows, annotation_fields(spec.track)))

    def _render_clip_chunk(self, chunk: int, split: str, frames: tuple[int, ...], layout: Layout) -> ChunkOutput:
        """:meth:`render` on a dataset of clips, whose chunk is one clip (grasp, clip): every frame rendered at its
        own camera and patient pose, the clip's lamp that of its first frame."""
        from hupbench.datagen.dataset.clips import clip_cameras, clip_record, draw_clip

        spec, world = self.spec, self.world
        g, c = layout.tuple(frames[0])[:2]
        assert len(frames) == layout.n_views and frames[0] % layout.n_views == 0, (chunk, frames[0], len(frames))
        clip = draw_clip(world, g, c)
        light = lamp(spec, frames[0])
        measured = clip_cameras(world, g, clip)
        clip_id = g * layout.n_z + c
        rows, files = [], []
        for f, (index, frame) in enumerate(zip(frames, self.render_clip(g, clip, clip["background"], clip["glove"],
                                                                         light))):
            if "rgb" in spec.modalities:
                files.append(("rgb", index, self._encode_rgb(frame["rgb"])))
            label_files, depth = self._label_files(frame["depth"], frame["seg"])
            files.extend((modality, index, data) for modality, data in label_files)
            if spec.sensor is not None:
                files.append(self._sensor_file(index, depth, frame["seg"]))
            cam = {"grasp": g, "background": clip["background"], "glove": clip["glove"], "view_id": c,
                   "T_cam_world": clip["T_cam_world"][f], "keypoints_cam": clip["keypoints_cam"][f],
                   "keypoints_2d": clip["keypoints_2d"][f], **{key: measured[key][f] for key in ("theta", "phi",
                                                                                              "z_ego")}}
            rows.append(self._row(index, cam, frame["visible"], light) | world.rows(g, clip["background"], c)
                        | {"roll_deg": measured["roll_deg"][f], "aim_px": measured["aim_px"][f], "clip_id": clip_id,
                           "frame_in_clip": f, "time_s": clip["time_s"][f], "T_world_body": clip["T_world_body"][f],
                           "hand_pose": clip["hand_pose"][f]})
        record = {"clip_id": clip_id, "grasp_index": g, **clip_record(clip, spec.scan.fps)}
        return ChunkOutput(chunk, split, files, _stack_rows(rows, annotation_fields(spec.track, sequence=True)),
                           clip=record)

    def _row(self, index: int, cam: dict, visible: np.ndarray, light: dict) -> dict:
        """A frame's annotation values of every track (:data:`hupbench.core.contract.ANNOTATION_FIELDS`) from its
        camera (:func:`frame_camera`'s keys), its keypoints' visibility and its lamp."""
        grasps, g = self.grasps, cam["grasp"]
        return {"frame_id": index, "keypoints_3d_cam": cam["keypoints_cam"], "keypoints_2d": cam["keypoints_2d"],
                "visible": visible, "K": self.spec.intrinsics.K, "T_cam_world": cam["T_cam_world"],
                "grasp_id": grasps.grasp_id[g], "grasp_index": g, "view_id": cam["view_id"], "theta": cam["theta"],
                "phi": cam["phi"], "z_ego": cam["z_ego"], "background_id": cam["background"],
                "glove_id": cam["glove"], "hand_pose": grasps.hand_pose[g], "hand_trans": grasps.hand_trans[g],
                "light_position_cam": light["position_cam"], "light_color": light["color"],
                "light_energy_w": light["energy_w"]}

    def _encode_rgb(self, rgb: np.ndarray) -> bytes:
        """An (H, W, 3) uint8 RGB image encoded in the spec's format."""
        ext = ".jpg" if self.spec.rgb_format == "jpg" else ".png"
        params = [cv2.IMWRITE_JPEG_QUALITY, self.spec.jpeg_quality] if ext == ".jpg" else []
        return encode_image(ext, rgb[..., ::-1], params)

    def _label_files(self, depth_m: np.ndarray, seg: np.ndarray) -> tuple[list[tuple[str, bytes]], np.ndarray]:
        """The label pass's files as the spec asks ((modality, encoded bytes) of depth and seg) and the depth as
        stored: uint16 in ``DEPTH_SCALE_M`` units."""
        depth = np.round(depth_m / DEPTH_SCALE_M).astype(np.uint16)
        files = []
        if "depth" in self.spec.modalities:
            files.append(("depth", encode_image(".png", depth)))
        if "seg" in self.spec.modalities:
            files.append(("seg", encode_image(".png", seg)))
        return files, depth

    def _sensor_file(self, index: int, depth: np.ndarray, seg: np.ndarray) -> tuple[str, int, bytes]:
        """Frame ``index``'s depth camera measurement of its stored depth and labels, encoded."""
        spec = self.spec
        sensor = stored_sensor_depth(depth, seg, spec.intrinsics.K, spec.sensor, seg_labels(spec.track),
                                     DEPTH_SCALE_M, spec.seed, index)
        return SENSOR_DEPTH, index, encode_image(".png", sensor)

    def _colour(self, g: int, T_cam_world: np.ndarray, background: int, glove: int, light: dict) -> np.ndarray:
        """(H, W, 3) uint8 RGB of the loaded grasp ``g`` from one camera: the glove's and (clinic) the room's and
        skin's colours, the frame's lamp, composited over the background image."""
        from hupbench.datagen.assets.backgrounds import composite

        renderer, spec = self.renderer, self.spec
        renderer.set_color("hand", GLOVE_RGB[glove])
        if self.world is not None:
            for name, rgb in self.world.colours(g, background).items():
                renderer.set_color(name, rgb)
        position_world = transform_points(invert_transform(T_cam_world), light["position_cam"][None])[0]
        settings = RenderSettings(background_rgb=(1.0, 1.0, 1.0), ambient=0.3, lights=[PointLight(
            position_world, tuple(light["color"]), float(light["energy_w"]) * LAMP_INTENSITY_PER_WATT)])
        rgba = renderer.render(T_cam_world, ("rgb",), settings, alpha=True)["rgb"]
        return composite(rgba, self.backgrounds.image(background, spec.width, spec.height))

    def _load_grasp(self, g: int) -> None:
        """The grasp's hand, probe and (clinic) patient and room as the renderer's parts, unless loaded."""
        if self._grasp_loaded != g:
            grasps, world = self.grasps, self.world
            grasp = Grasp(grasps.hand_pose[g], grasps.hand_trans[g])
            if world is None:
                self.renderer.set_parts(scene_parts(grasp, probe=grasps.probe))
            else:
                self.renderer.set_parts(scene_parts(grasp, models_of(grasps.hand_spec(g)), probe=grasps.probe)
                                        + world.parts(g))
            self._grasp_loaded = g

    def render_clip(self, g: int, clip: dict, background: int, glove: int, light: dict) -> list[dict]:
        """Render every frame of one clip of grasp ``g`` on the clinic track (nothing is encoded or written).

        The patient and the room move with the clip's body pose; the probe and the wrist stay where the grasp puts
        them (the world is the probe frame), the fingers take each frame's pose; one lamp lights the whole clip.

        Args:
            g: the grasp. clip: :func:`hupbench.datagen.dataset.clips.clip_geometry`'s dict.
            background, glove: the clip's background (room palette and skin tone) and glove.
            light: the clip's lamp (:func:`hupbench.datagen.dataset.spec.lamp`'s dict).

        Returns:
            Per frame {"rgb": (H, W, 3) uint8 when the spec stores RGB; "depth": (H, W) float32 metres; "seg":
            (H, W) uint8; "visible": (29,) bool}.
        """
        assert self.world is not None, "clips are rendered on the clinic track's world"
        from hupbench.datagen.assets.hand import build_hand

        self._load_grasp(g)
        moving = list(self.world.colours(g, background))  # the patient and the room's parts
        T_world_body0 = self.world.placements[g].T_world_body
        hand, grasp_pose, trans = build_hand(self.grasps.hand_spec(g)), self.grasps.hand_pose[g], self.grasps.hand_trans[g]
        posed = grasp_pose
        frames = []
        try:
            for f, T_cam_world in enumerate(clip["T_cam_world"]):
                T_move = clip["T_world_body"][f] @ invert_transform(T_world_body0)
                for name in moving:
                    self.renderer.move_part(name, T_move)
                if (clip["hand_pose"][f] != posed).any():
                    posed = clip["hand_pose"][f]
                    self.renderer.set_part_mesh("hand", hand.mesh(posed, trans))
                labels = self.renderer.render(T_cam_world, ("depth", "seg"))
                cam = {"keypoints_cam": clip["keypoints_cam"][f], "keypoints_2d": clip["keypoints_2d"][f]}
                frame = {"depth": labels["depth"], "seg": labels["seg"],
                         "visible": stored_visibility(cam, labels["depth"], labels["seg"])}
                if "rgb" in self.spec.modalities:
                    frame["rgb"] = self._colour(g, T_cam_world, background, glove, light)
                frames.append(frame)
        finally:
            for name in moving:
                self.renderer.move_part(name, np.eye(4))
            if (posed != grasp_pose).any():
                self.renderer.set_part_mesh("hand", hand.mesh(grasp_pose, trans))
        return frames

    def _view(self, cam: dict) -> dict:
        """What the frames of one view of the loaded grasp share: the label pass's depth and labels,
        encoded as the spec asks, and the keypoints' visibility (backgrounds, gloves and lamps
        change the colours only). Kept for the views of the current (grasp, z_ego)."""
        key = (cam["grasp"], cam["z"], cam["view"])
        if key not in self._views:
            self._views = {k: v for k, v in self._views.items() if k[:2] == key[:2]}
            labels = self.renderer.render(cam["T_cam_world"], ("depth", "seg"))
            files, depth = self._label_files(labels["depth"], labels["seg"])
            self._views[key] = {"files": files, "visible": stored_visibility(cam, labels["depth"], labels["seg"]),
                                "depth": depth, "seg": labels["seg"]}
        return self._views[key]


def write_chunk(root: Path, output: ChunkOutput, rgb_format: str) -> int:
    """Write a rendered chunk: its image files atomically, then its annotation rows (the done mark).

    Writing a chunk twice (a retried range) overwrites the same files with the same bytes.

    Returns:
        The number of frames written.
    """
    for modality, frame_id, data in output.files:
        write_bytes(frame_path(root, output.split, modality, frame_id, rgb_format), data)
    clip = {} if output.clip is None else {CLIP_RECORD: np.array(json.dumps(output.clip))}
    save_npz(_chunk_path(root, output.split, output.chunk), output.rows | clip)
    return len(output.rows["frame_id"])


#: the array of a chunk's rows file holding its clip's record (JSON), beside the annotation arrays
CLIP_RECORD = "clip_record"

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
    next run (:func:`hupbench.core.io.clean_stale_tmp`).

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


def _worker_init(run, grasps_path: str, parent_pid: int | None = None) -> None:
    """Build this process's :class:`ChunkRenderer` for ``run`` (a :class:`hupbench.datagen.dataset.writer.GenerateRun`)
    from the dataset's grasps file; a pool worker (``parent_pid`` given) dies with its parent."""
    if parent_pid is not None:
        die_with_parent(parent_pid)
    _worker["chunks"] = ChunkRenderer(run.dataset, grasps_path, run.job.backgrounds_dir, run.job.platform)


def _render_chunk(args) -> tuple[int, int]:
    """Render and write one chunk in a local worker; return (chunk, frames written)."""
    chunk, root, split, frames, layout = args
    chunks = _worker["chunks"]
    return chunk, write_chunk(Path(root), chunks.render(chunk, split, frames, layout), chunks.spec.rgb_format)


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
            raise RunFailedError(f"{type(exc).__name__}: {exc}") from None
        raise


def _stack_rows(rows: list[dict], fields: dict) -> dict[str, np.ndarray]:
    """The rows' arrays of ``fields`` (:func:`hupbench.core.contract.annotation_fields`), stacked in their dtypes."""
    return {k: np.stack([np.asarray(r[k]) for r in rows]).astype(dtype) for k, (dtype, _) in fields.items()}


def read_clip_record(root: Path, split: str, chunk: int) -> dict:
    """The clip record :func:`write_chunk` wrote beside a chunk's rows (a dataset of clips)."""
    with np.load(_chunk_path(root, split, chunk)) as data:
        return json.loads(str(data[CLIP_RECORD]))


def _chunk_path(root: Path, split: str, chunk: int) -> Path:
    return Path(root) / split / ".chunks" / f"{chunk:05d}.npz"

