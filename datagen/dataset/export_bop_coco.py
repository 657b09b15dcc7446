"""``hupbench export-dataset``: a finished hupbench dataset written in the BOP format (the probe as the object)
or as COCO keypoints (the hand and the probe), for the tools the field already uses.

BOP (``--format bop``, the layout of ``bop_toolkit_lib.dataset_params``, BOP-scenewise)::

    OUT/camera.json                             the dataset camera (fx, fy, cx, cy, width, height, depth_scale)
    OUT/models/obj_000001.ply                   the probe, object id 1, ASCII PLY with vertex normals, mm
    OUT/models/models_info.json                 diameter, min_x/y/z, size_x/y/z (mm), symmetries_discrete
    OUT/<split>/<grasp_id:06d>/                 one scene per grasp of the split (the probe and hand are
                                                still in the world frame; the camera moves)
        scene_camera.json                       per image: cam_K, depth_scale, cam_R_w2c, cam_t_w2c (mm)
        scene_gt.json                           per image: [{obj_id 1, cam_R_m2c, cam_t_m2c (mm)}]
        scene_gt_info.json                      per image: bbox_obj, bbox_visib, px_count_all/valid/visib,
                                                visib_fract
        rgb/<frame_id:06d>.jpg|png              the dataset's image (hard link or copy)
        depth/<frame_id:06d>.png                the dataset's uint16 depth (hard link or copy): mm = value *
                                                depth_scale
        mask/<frame_id:06d>_000000.png          the probe's whole silhouette, rendered alone (0 / 255)
        mask_visib/<frame_id:06d>_000000.png    its visible part: the dataset's seg == probe (0 / 255)

Image ids are the dataset's frame ids. The model frame is hupbench's probe frame (origin at the lens apex,
+z along the handle), not BOP's box centre, so ``cam_R_m2c``/``cam_t_m2c`` are the dataset's ``T_cam_world``
(world = probe frame) and the box of ``models_info`` is the probe's eight corner keypoints. The whole
silhouette is rendered with the dataset's renderer on a canvas three times the image's size, as BOP's
``calc_gt_info.py`` does, so ``px_count_all`` and ``bbox_obj`` count what falls outside the image; visibility
comes from the rendered labels, not from BOP's depth test.

COCO keypoints (``--format coco``)::

    OUT/annotations/keypoints_<split>.json      images, annotations, categories (hand: 21, probe: 8)
    OUT/images/<split>/<frame_id:06d>.jpg|png   the dataset's image (hard link or copy)

Two categories, because COCO tools hold one keypoint list per category: ``hand`` (id 1, the 21 joints of
:mod:`hupbench.core.keypoints`) and ``probe`` (id 2, its 8 box corners), two annotations per image. A keypoint is
``[x, y, v]``: pixel coordinates of the stored image (centres at integers, COCO's keypoint convention), v = 2
visible, 1 inside the image but hidden, 0 outside the image (then x = y = 0). ``bbox``, ``area`` and the
(uncompressed RLE) ``segmentation`` come from the dataset's seg labels (hand 1, probe 3); without seg, from the
box of the labelled keypoints. Extra fields: ``keypoints_3d`` (K, 3) mm, OpenCV camera frame, on each
annotation; ``cam_K`` (3, 3), ``frame_id``, ``grasp_id``, ``view_id`` on each image.

Both formats write ``OUT/hupbench_export.json`` (options, counts, provenance). The export is built in a
temporary folder beside OUT and renamed into place when complete.
"""

from __future__ import annotations

import errno
import json
import os
import shutil
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from hupbench.core import keypoints as kp
from hupbench.core.contract import (
    SEG_LABELS,
    SPLITS,
    frame_path,
    read_annotations,
    read_manifest,
)
from hupbench.core.errors import BadValueError, MissingFileError
from hupbench.core.io import atomic_folder, check_writable, encode_image, write_bytes, write_json

FORMATS = ("bop", "coco")
#: how the dataset's image files reach OUT: hard links (a copy where the file system refuses one) or copies
IMAGE_MODES = ("hardlink", "copy")
EXPORT_RECORD = "hupbench_export.json"
#: the probe's BOP object id
PROBE_OBJ_ID = 1
#: BOP's ground-truth index of the probe in each image (one object per image)
PROBE_GT_ID = 0
#: COCO category ids
HAND_CATEGORY_ID, PROBE_CATEGORY_ID = 1, 2
MM_PER_M = 1000.0
#: BOP renders the whole silhouette on a canvas this many times the image's size, centred on the image
BOP_CANVAS_SCALE = 3


@dataclass(frozen=True)
class ExportOptions:
    """What ``hupbench export-dataset`` was asked for, checked here (the verb's arguments).

    Attributes:
        dataset: a finished hupbench dataset folder.
        out: the output folder: new, empty, or (with ``force``) an earlier export, which is replaced.
        format: one of ``FORMATS``.
        images: one of ``IMAGE_MODES``.
        force: replace ``out`` when it holds an earlier export (``EXPORT_RECORD``).
        symmetry: BOP only: write the probe's half turn about its long axis into ``models_info.json``
            (when the dataset's box corners have it, as ``hupbench eval``'s symmetric probe error assumes).
    """

    dataset: str | Path
    out: str | Path
    format: str
    images: str = "hardlink"
    force: bool = False
    symmetry: bool = True

    def __post_init__(self) -> None:
        for what, value, allowed in (("format", self.format, FORMATS), ("image mode", self.images, IMAGE_MODES)):
            if value not in allowed:
                raise BadValueError(f"unknown {what} {value!r}: choose one of {', '.join(allowed)}")


def dataset_probe_mesh(root: Path, manifest: dict):
    """The probe a dataset was rendered with, as a ``trimesh.Trimesh`` in metres, probe frame (shared: copy it
    before changing it): :func:`hupbench.datagen.dataset.grasps_file.probe_of_dataset` of the folder and the
    manifest the export read."""
    from hupbench.datagen.dataset.grasps_file import probe_of_dataset

    return probe_of_dataset(root, manifest).mesh


def run_export_dataset(opts: ExportOptions, provenance: dict | None = None, log=print) -> dict:
    """Export a dataset (see the module docstring for the layouts).

    Args:
        opts: the checked options.
        provenance: what made the export (git commit, package versions, ...), written into ``EXPORT_RECORD``
            beside the options (``{"config": options and counts, **provenance}``).
        log: where the per-split lines go.

    Returns:
        {"out", "format", "frames": {split: n}, "scenes" (BOP: scene folders; COCO: 0), "linked", "copied"
        (image files), "seconds"}.

    Raises:
        UserError: no dataset or a damaged one (a frame's mask all background), OUT not empty (and not an
            earlier export with ``force``), OUT overlapping the dataset, OUT not writable, a dataset without
            the modality the format needs, a probe mesh whose box is not the dataset's corner keypoints.
    """
    start = time.perf_counter()
    root = Path(opts.dataset)
    manifest = read_manifest(root)
    out = _check_out(Path(opts.out), root, opts.force)
    needed = {"bop": "seg", "coco": "rgb"}[opts.format]
    if needed not in manifest["modalities"]:
        raise BadValueError(f"a {opts.format.upper()} export needs the dataset's {needed} images; {root} has only "
                            f"{', '.join(manifest['modalities'])}")
    splits = [s for s in SPLITS if manifest["counts"].get(s, 0) > 0]
    files = _Files(opts.images)
    # an earlier export that --force replaces (checked above) goes only once the new one is complete
    with atomic_folder(out) as stage:
        writer = _write_bop if opts.format == "bop" else _write_coco
        frames, scenes = writer(root, manifest, splits, stage, files, opts, log)
        record = {"format": opts.format, "dataset": str(root.resolve()), "images": opts.images,
                  "symmetry": opts.symmetry if opts.format == "bop" else None, "frames": frames, "scenes": scenes,
                  "linked": files.linked, "copied": files.copied}
        write_json(stage / EXPORT_RECORD, {"config": record, **(provenance or {})})
    return {"out": str(out), "format": opts.format, "frames": frames, "scenes": scenes, "linked": files.linked,
            "copied": files.copied, "seconds": time.perf_counter() - start}


def _check_out(out: Path, dataset: Path, force: bool) -> Path:
    """``out`` may be written: new or empty, or an earlier export when ``force`` (then it is replaced);
    never the dataset, a folder holding it or one inside it (replacing OUT would delete the dataset, an
    export inside it would add to it)."""
    check_writable(out, "OUT")
    a, b = out.resolve(), dataset.resolve()
    if a == b or a in b.parents or b in a.parents:
        how = "is" if a == b else ("holds" if a in b.parents else "lies inside")
        raise BadValueError(f"OUT {out} {how} the dataset {dataset} being exported: choose a folder outside the "
                            "dataset (replacing OUT would delete it)")
    if out.is_dir() and any(out.iterdir()):
        n = sum(1 for _ in out.iterdir())
        if not force:
            raise BadValueError(f"OUT {out} is not empty ({n} entries): choose a new or empty folder, or --force "
                                f"to replace an earlier export")
        if not (out / EXPORT_RECORD).is_file():
            raise BadValueError(f"OUT {out} is not empty ({n} entries) and not an earlier export (no "
                                f"{EXPORT_RECORD}): --force replaces only an export")
    return out


class _Files:
    """Puts the dataset's files into the export: hard links or copies, counted."""

    def __init__(self, mode: str) -> None:
        self.mode, self.linked, self.copied = mode, 0, 0

    def put(self, src: Path, dst: Path) -> None:
        _check_frame_file(src)
        dst.parent.mkdir(parents=True, exist_ok=True)
        if self.mode == "hardlink":
            try:
                os.link(src, dst)
                self.linked += 1
                return
            except OSError as exc:
                # another file system, or one without hard links: a copy keeps the export whole
                if exc.errno not in (errno.EXDEV, errno.EPERM, errno.EMLINK, errno.ENOTSUP):
                    raise
        shutil.copyfile(src, dst)
        self.copied += 1


def _check_frame_file(path: Path) -> None:
    if not path.is_file():
        raise MissingFileError(f"{path} does not exist (a frame the annotations list)")


def _read_png(path: Path, dtype) -> np.ndarray:
    """A single-channel PNG of a frame (seg uint8, depth uint16), as stored."""
    _check_frame_file(path)
    data = np.fromfile(path, dtype=np.uint8)
    image = cv2.imdecode(data, cv2.IMREAD_UNCHANGED) if data.size else None
    if image is None or image.ndim != 2 or image.dtype != dtype:
        raise BadValueError(f"{path} is not a single-channel {np.dtype(dtype)} PNG (damaged?)")
    return image


def _read_seg(root: Path, split: str, frame: int) -> np.ndarray:
    """(H, W) uint8 labels of a frame; a mask that is background everywhere (the frame shows neither hand
    nor probe, so the dataset is damaged) is refused."""
    path = frame_path(root, split, "seg", frame)
    seg = _read_png(path, np.uint8)
    if not (seg != SEG_LABELS["background"]).any():
        raise BadValueError(f"{path}: the mask is background everywhere, the frame shows neither hand nor probe "
                            "(`hupbench verify` reports it as empty_frame): nothing to export")
    return seg


def _write_png(path: Path, image: np.ndarray) -> None:
    write_bytes(path, encode_image(".png", image))


def _write_json(path: Path, data: dict) -> None:
    """A dict as JSON with one top-level key a line (the BOP toolkit's ``save_json`` layout)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    lines = [f"  {json.dumps(str(key))}: {json.dumps(value, sort_keys=True)}" for key, value in data.items()]
    path.write_text("{\n" + ",\n".join(lines) + "\n}\n")


# --------------------------------------------------------------------------- BOP


def write_ply_mm(path: Path, mesh_m) -> None:
    """An ASCII PLY of ``mesh_m`` (``trimesh.Trimesh``, metres) in millimetres with vertex normals, as BOP's
    models are (``bop_toolkit_lib.inout.load_ply`` reads it)."""
    vertices = np.asarray(mesh_m.vertices, np.float64) * MM_PER_M        # (V, 3) mm
    normals = np.asarray(mesh_m.vertex_normals, np.float64)              # (V, 3) unit
    faces = np.asarray(mesh_m.faces, np.int64)                           # (F, 3)
    header = ["ply", "format ascii 1.0", "comment hupbench probe, millimetres, probe frame",
              f"element vertex {len(vertices)}", *(f"property float {c}" for c in ("x", "y", "z", "nx", "ny", "nz")),
              f"element face {len(faces)}", "property list uchar int vertex_indices", "end_header"]
    rows = [f"{x:.6f} {y:.6f} {z:.6f} {a:.6f} {b:.6f} {c:.6f}" for (x, y, z), (a, b, c) in zip(vertices, normals)]
    rows += [f"3 {i} {j} {k}" for i, j, k in faces]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(header + rows) + "\n")


def models_info(mesh_m, symmetric: bool) -> dict:
    """BOP's ``models_info`` entry of the probe: the box and the diameter (largest distance between two vertices)
    in mm, and, when ``symmetric``, the half turn about the model's z axis as ``symmetries_discrete`` (a
    row-major 4 x 4, mm)."""
    from hupbench.core.probe_symmetry import object_diameter_m

    vertices = np.asarray(mesh_m.vertices, np.float64) * MM_PER_M
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    info = {"diameter": object_diameter_m(mesh_m.vertices) * MM_PER_M,
            **{f"min_{a}": float(v) for a, v in zip("xyz", lo)}, **{f"size_{a}": float(v) for a, v in zip("xyz", hi - lo)}}
    if symmetric:
        from hupbench.core.probe_symmetry import HALF_TURN_Z

        half_turn = np.eye(4)
        half_turn[:3, :3] = HALF_TURN_Z
        info["symmetries_discrete"] = [half_turn.ravel().tolist()]
    return info


def _probe_symmetric(ann_by_split: dict) -> bool:
    """Whether the dataset's box corners are symmetric under the half turn about the probe's long axis, as
    ``hupbench eval`` decides for its symmetric probe error."""
    from hupbench.core.probe_symmetry import probe_symmetry_group

    corners = np.concatenate([a["keypoints_3d_cam"] for a in ann_by_split.values()])
    T = np.concatenate([a["T_cam_world"] for a in ann_by_split.values()])
    try:
        probe_symmetry_group(corners, T)
    except BadValueError:
        return False
    return True


def _check_probe_frame(mesh_m, ann: dict, where: Path) -> None:
    """The mesh's box corners, moved by ``T_cam_world``, are the annotated corner keypoints: the mesh is the
    dataset's probe and world = probe frame, so ``T_cam_world`` is the model -> camera pose."""
    from hupbench.core.geometry import transform_points
    from hupbench.core.tolerances import CORNER_FRAME_TOL_M
    from hupbench.datagen.assets.probe_mesh import box_corners

    corners_cam = transform_points(ann["T_cam_world"], box_corners(mesh_m.bounds))     # (N, 8, 3) metres
    error = np.abs(corners_cam - ann["keypoints_3d_cam"][:, kp.CORNER_SLICE]).max()
    if error > CORNER_FRAME_TOL_M:
        raise BadValueError(f"{where}: the probe mesh's box, placed by T_cam_world, is {error * MM_PER_M:.3f} mm from "
                            f"the annotated probe corners: the mesh is not the probe this dataset was rendered with")


def _bbox_xywh(mask: np.ndarray, offset: tuple[int, int] = (0, 0)) -> list[int]:
    """BOP's ``calc_2d_bbox`` of a mask: [x, y, w, h] with w = x_max - x_min (pixel indices), or [-1] * 4."""
    ys, xs = np.nonzero(mask)
    if len(xs) == 0:
        return [-1, -1, -1, -1]
    x0, y0 = int(xs.min()) - offset[0], int(ys.min()) - offset[1]
    return [x0, y0, int(xs.max()) - offset[0] - x0, int(ys.max()) - offset[1] - y0]


class _SilhouetteRenderer:
    """The probe alone, rendered with the dataset's renderer on a canvas ``BOP_CANVAS_SCALE`` times the image,
    one renderer per camera matrix."""

    def __init__(self, mesh_m, width: int, height: int) -> None:
        self.mesh, self.width, self.height = mesh_m, width, height
        self._renderers: dict[tuple, object] = {}

    def __call__(self, K: np.ndarray, T_cam_probe: np.ndarray) -> np.ndarray:
        """(3H, 3W) bool, the image at rows H..2H, columns W..2W."""
        key = tuple(np.asarray(K, np.float64).ravel().tolist())
        if key not in self._renderers:
            from hupbench.core.camera import Intrinsics
            from hupbench.datagen.render.renderer import MeshPart, Renderer

            pad_x, pad_y = (BOP_CANVAS_SCALE - 1) // 2 * self.width, (BOP_CANVAS_SCALE - 1) // 2 * self.height
            renderer = Renderer(Intrinsics(K[0, 0], K[1, 1], K[0, 2] + pad_x, K[1, 2] + pad_y,
                                           BOP_CANVAS_SCALE * self.width, BOP_CANVAS_SCALE * self.height))
            renderer.set_parts([MeshPart("probe", self.mesh, SEG_LABELS["probe"])])
            self._renderers[key] = renderer
        return self._renderers[key].render(T_cam_probe, ("seg",))["seg"] == SEG_LABELS["probe"]

    def close(self) -> None:
        for renderer in self._renderers.values():
            renderer.close()


def _write_bop(root: Path, manifest: dict, splits: list[str], stage: Path, files: _Files, opts: ExportOptions,
               log) -> tuple[dict, int]:
    mesh_m = dataset_probe_mesh(root, manifest)
    keys = ["keypoints_3d_cam", "K", "T_cam_world", "grasp_id"]
    ann_by_split = {s: read_annotations(root, s, keys, manifest) for s in splits}
    for split, ann in ann_by_split.items():
        _check_probe_frame(mesh_m, ann, root / split)
    symmetric = opts.symmetry and _probe_symmetric(ann_by_split)
    write_ply_mm(stage / "models" / f"obj_{PROBE_OBJ_ID:06d}.ply", mesh_m)
    _write_json(stage / "models" / "models_info.json", {str(PROBE_OBJ_ID): models_info(mesh_m, symmetric)})
    width, height = manifest["image_size"]
    K = np.asarray(manifest["K"], np.float64)
    depth_scale_mm = float(manifest["depth_scale_m"]) * MM_PER_M
    has_depth, has_rgb = "depth" in manifest["modalities"], "rgb" in manifest["modalities"]
    camera = {"fx": K[0, 0], "fy": K[1, 1], "cx": K[0, 2], "cy": K[1, 2], "width": width, "height": height}
    _write_json(stage / "camera.json", camera | ({"depth_scale": depth_scale_mm} if has_depth else {}))
    silhouette = _SilhouetteRenderer(mesh_m, width, height)
    pad = ((BOP_CANVAS_SCALE - 1) // 2 * width, (BOP_CANVAS_SCALE - 1) // 2 * height)
    frames, scenes = {}, 0
    try:
        for split, ann in ann_by_split.items():
            frames[split] = len(ann["frame_id"])
            for grasp in np.unique(ann["grasp_id"]):
                rows = np.flatnonzero(ann["grasp_id"] == grasp)
                scene = stage / split / f"{int(grasp):06d}"
                scene_camera, scene_gt, scene_gt_info = {}, {}, {}
                for i in rows:
                    frame = int(ann["frame_id"][i])
                    T = ann["T_cam_world"][i]
                    R, t_mm = T[:3, :3].ravel().tolist(), (T[:3, 3] * MM_PER_M).tolist()
                    scene_camera[str(frame)] = {"cam_K": ann["K"][i].ravel().tolist(), "cam_R_w2c": R, "cam_t_w2c": t_mm,
                                                **({"depth_scale": depth_scale_mm} if has_depth else {})}
                    scene_gt[str(frame)] = [{"obj_id": PROBE_OBJ_ID, "cam_R_m2c": R, "cam_t_m2c": t_mm}]
                    seg = _read_seg(root, split, frame)
                    visib = seg == SEG_LABELS["probe"]
                    whole_canvas = silhouette(ann["K"][i], T)
                    whole = whole_canvas[pad[1]:pad[1] + height, pad[0]:pad[0] + width]
                    name = f"{frame:06d}_{PROBE_GT_ID:06d}.png"
                    _write_png(scene / "mask_visib" / name, visib.astype(np.uint8) * 255)
                    _write_png(scene / "mask" / name, whole.astype(np.uint8) * 255)
                    info = {"px_count_all": int(whole_canvas.sum()), "px_count_visib": int(visib.sum())}
                    info["visib_fract"] = info["px_count_visib"] / info["px_count_all"] if info["px_count_all"] else 0.0
                    seen = info["px_count_visib"] > 0
                    # BOP writes both boxes as [-1] * 4 when nothing of the object is visible
                    info["bbox_obj"] = _bbox_xywh(whole_canvas, pad) if seen else [-1, -1, -1, -1]
                    info["bbox_visib"] = _bbox_xywh(visib)
                    if has_depth:
                        depth_file = frame_path(root, split, "depth", frame)
                        info["px_count_valid"] = int((_read_png(depth_file, np.uint16)[whole] > 0).sum())
                        files.put(depth_file, scene / "depth" / depth_file.name)
                    if has_rgb:
                        rgb_file = frame_path(root, split, "rgb", frame, manifest["rgb_format"])
                        files.put(rgb_file, scene / "rgb" / rgb_file.name)
                    scene_gt_info[str(frame)] = [info]
                _write_json(scene / "scene_camera.json", scene_camera)
                _write_json(scene / "scene_gt.json", scene_gt)
                _write_json(scene / "scene_gt_info.json", scene_gt_info)
                scenes += 1
                log(f"bop: {split} scene {int(grasp):06d}: {len(rows)} images")
    finally:
        silhouette.close()
    return frames, scenes


# --------------------------------------------------------------------------- COCO


def coco_categories() -> list[dict]:
    """The two COCO categories with their keypoint names and 1-based skeletons (:mod:`hupbench.core.keypoints`)."""
    def skeleton(edges, first):
        return [[a - first + 1, b - first + 1] for a, b in edges]

    return [{"id": HAND_CATEGORY_ID, "name": "hand", "supercategory": "hand", "keypoints": list(kp.HAND_NAMES),
             "skeleton": skeleton(kp.HAND_EDGES, 0)},
            {"id": PROBE_CATEGORY_ID, "name": "probe", "supercategory": "object", "keypoints": list(kp.CORNER_NAMES),
             "skeleton": skeleton(kp.CORNER_EDGES, kp.NUM_HAND)}]


def rle_uncompressed(mask: np.ndarray) -> dict:
    """COCO's uncompressed RLE of an (H, W) bool mask: run lengths over the column-major pixels, background first."""
    flat = np.asarray(mask, bool).T.ravel()
    edges = np.flatnonzero(flat[1:] != flat[:-1]) + 1
    counts = np.diff(np.concatenate([[0], edges, [flat.size]])).tolist()
    return {"counts": ([0] + counts) if flat[0] else counts, "size": list(mask.shape)}


def coco_keypoints(points_2d: np.ndarray, visible: np.ndarray, width: int, height: int) -> tuple[list[float], int]:
    """(COCO ``keypoints`` [x1, y1, v1, ...], ``num_keypoints``) of (K, 2) pixels and (K,) visibility: v = 2
    visible, 1 inside the image (the pixel its rounded position names) but hidden, 0 outside (x = y = 0)."""
    uv = np.round(points_2d).astype(np.int64)
    inside = (uv[:, 0] >= 0) & (uv[:, 0] < width) & (uv[:, 1] >= 0) & (uv[:, 1] < height)
    v = np.where(visible & inside, 2, np.where(inside, 1, 0))
    xy = np.where(inside[:, None], points_2d.astype(np.float64), 0.0)
    return np.column_stack([xy, v]).ravel().tolist(), int((v > 0).sum())


def _box_of_points(points_2d: np.ndarray, labelled: np.ndarray) -> list[float]:
    """COCO [x, y, w, h] (pixel edges) around the labelled keypoints' pixels; zeros when none is labelled."""
    if not labelled.any():
        return [0.0, 0.0, 0.0, 0.0]
    lo, hi = points_2d[labelled].min(axis=0) - 0.5, points_2d[labelled].max(axis=0) + 0.5
    return [float(lo[0]), float(lo[1]), float(hi[0] - lo[0]), float(hi[1] - lo[1])]


def _write_coco(root: Path, manifest: dict, splits: list[str], stage: Path, files: _Files, opts: ExportOptions,
                log) -> tuple[dict, int]:
    width, height = manifest["image_size"]
    has_seg = "seg" in manifest["modalities"]
    keys = ["keypoints_2d", "keypoints_3d_cam", "visible", "K", "grasp_id", "view_id"]
    parts = ((HAND_CATEGORY_ID, kp.HAND_SLICE, SEG_LABELS["hand"]), (PROBE_CATEGORY_ID, kp.CORNER_SLICE,
                                                                     SEG_LABELS["probe"]))
    frames = {}
    for split in splits:
        ann = read_annotations(root, split, keys, manifest)
        images, annotations = [], []
        for i, frame in enumerate(ann["frame_id"].tolist()):
            rgb_file = frame_path(root, split, "rgb", frame, manifest["rgb_format"])
            files.put(rgb_file, stage / "images" / split / rgb_file.name)
            images.append({"id": frame, "file_name": f"{split}/{rgb_file.name}", "width": width, "height": height,
                           "frame_id": frame, "grasp_id": int(ann["grasp_id"][i]), "view_id": int(ann["view_id"][i]),
                           "cam_K": ann["K"][i].tolist()})
            seg = _read_seg(root, split, frame) if has_seg else None
            for category, sl, label in parts:
                keypoints, n = coco_keypoints(ann["keypoints_2d"][i, sl], ann["visible"][i, sl], width, height)
                entry = {"id": len(annotations) + 1, "image_id": frame, "category_id": category, "iscrowd": 0,
                         "keypoints": keypoints, "num_keypoints": n,
                         "keypoints_3d": (ann["keypoints_3d_cam"][i, sl].astype(np.float64) * MM_PER_M).tolist()}
                if seg is not None:
                    mask = seg == label
                    ys, xs = np.nonzero(mask)
                    box = [int(xs.min()), int(ys.min()), int(xs.max() - xs.min() + 1), int(ys.max() - ys.min() + 1)] \
                        if len(xs) else [0, 0, 0, 0]
                    entry |= {"bbox": box, "area": int(mask.sum()), "segmentation": rle_uncompressed(mask)}
                else:
                    box = _box_of_points(ann["keypoints_2d"][i, sl], np.asarray(keypoints[2::3]) > 0)
                    entry |= {"bbox": box, "area": box[2] * box[3]}
                annotations.append(entry)
        generator = manifest.get("generator") if isinstance(manifest.get("generator"), dict) else {}
        info = {"description": f"hupbench dataset {root.resolve()}, split {split}",
                "version": str(generator.get("version", "")), "date_created": time.strftime("%Y-%m-%d", time.gmtime())}
        _write_json(stage / "annotations" / f"keypoints_{split}.json",
                    {"info": info, "licenses": [], "images": images, "annotations": annotations,
                     "categories": coco_categories()})
        frames[split] = len(images)
        log(f"coco: {split}: {len(images)} images, {len(annotations)} annotations")
    return frames, 0
