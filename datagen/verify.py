"""Re-check a dataset against its manifest and against geometry.

Failure kinds (each names the frame):
    ``missing_file``, ``undecodable_file``, ``count_mismatch``, ``frame_ids``,
    ``reprojection`` (2D != projection of 3D), ``pose_mismatch`` (3D != the
    keypoints of the stored hand pose and probe corners seen by the stored
    camera), ``look_at`` (the point the manifest's protocol aims at is not at
    (0, 0, z_ego) in the camera frame), ``visible_not_on_hand`` (a visible
    hand keypoint whose pixel is not hand in the mask or whose depth is not
    just in front of it),
    ``probe_depth`` (probe pixels unprojected with their depth are off the
    probe surface by more than max(3 mm, 1.5 pixel footprints)). Thresholds are in :mod:`datagen.tolerances`.
"""

from __future__ import annotations

import json
import multiprocessing
from pathlib import Path

import cv2
import numpy as np

from datagen import keypoints as kp
from datagen import tolerances as tol
from datagen.camera import project_points
from datagen.dataset import SPLITS, frame_path, visibility
from datagen.geometry import invert_transform, transform_points
from datagen.render import SEG_LABELS

KINDS = ("missing_file", "undecodable_file", "count_mismatch", "frame_ids", "reprojection", "pose_mismatch",
         "look_at", "visible_not_on_hand", "probe_depth")
#: more than this fraction of a frame's probe pixels off the surface fails it
PROBE_BAD_FRACTION = 0.05


def _problem(split, frame_id, kind, detail) -> dict:
    return {"split": split, "frame_id": None if frame_id is None else int(frame_id), "kind": kind, "detail": detail}


def check_geometry(ann: dict, split: str) -> list[dict]:
    """Checks that need no image: reprojection and the stored pose."""
    from datagen.hand import build_hand
    from datagen.probe import build_probe

    problems = []
    uv = project_points(ann["keypoints_3d_cam"].astype(np.float64), ann["K"], behind="nan")
    err = np.abs(uv - ann["keypoints_2d"]).max(axis=(1, 2))
    for i in np.flatnonzero(~(err <= tol.VERIFY_REPROJECTION_PX)):
        problems.append(_problem(split, ann["frame_id"][i], "reprojection", f"2D off the projection by {err[i]:.4f} px"))
    hand, probe = build_hand(), build_probe()
    world = np.concatenate([hand.keypoints(ann["hand_pose"], ann["hand_trans"], clamp=False),
                            np.broadcast_to(probe.corners_probe, (len(ann["frame_id"]), 8, 3))], axis=1)
    cam = transform_points(ann["T_cam_world"], world)
    err3 = np.linalg.norm(cam - ann["keypoints_3d_cam"], axis=-1).max(axis=1)
    for i in np.flatnonzero(~(err3 <= tol.VERIFY_KEYPOINT_M)):
        problems.append(_problem(split, ann["frame_id"][i], "pose_mismatch",
                                 f"3D keypoints {1000 * err3[i]:.2f} mm from the stored pose"))
    return problems


def check_look_at(ann: dict, split: str, look_at: str) -> list[dict]:
    """The camera's aim: ``look_at`` (a keypoint name or "box_centre", the centre of the 29
    keypoints' box in the world frame) must sit at (0, 0, z_ego) in every frame's camera frame."""
    cam = ann["keypoints_3d_cam"].astype(np.float64)
    if look_at == "box_centre":
        world = transform_points(invert_transform(ann["T_cam_world"]), cam)
        centre = 0.5 * (world.min(axis=1) + world.max(axis=1))
        point = transform_points(ann["T_cam_world"], centre[:, None])[:, 0]
    elif look_at in kp.KEYPOINT_NAMES:
        point = cam[:, kp.KEYPOINT_NAMES.index(look_at)]
    else:
        raise ValueError(f"manifest protocol look_at must be 'box_centre' or a keypoint name, got {look_at!r}")
    expected = np.zeros_like(point)
    expected[:, 2] = ann["z_ego"]
    err = np.linalg.norm(point - expected, axis=1)
    return [_problem(split, ann["frame_id"][i], "look_at",
                     f"{look_at} at {np.round(1000 * point[i], 3).tolist()} mm, expected (0, 0, z_ego) "
                     f"({1000 * err[i]:.4f} mm off)")
            for i in np.flatnonzero(~(err <= tol.VERIFY_LOOK_AT_M))]


def _read(path: Path, flags):
    if not path.is_file():
        return None, "missing_file"
    image = cv2.imread(str(path), flags)
    if image is None:
        return None, "undecodable_file"
    return image, None


def check_frame(args) -> list[dict]:
    """Image checks of one frame (files, mask and depth against the keypoints and the probe)."""
    root, split, manifest, row = args
    problems = []
    frame_id = int(row["frame_id"])
    images = {}
    for m in manifest["modalities"]:
        path = frame_path(Path(root), split, m, frame_id, manifest["rgb_format"])
        flags = cv2.IMREAD_COLOR if m == "rgb" else cv2.IMREAD_UNCHANGED
        image, kind = _read(path, flags)
        w, h = manifest["image_size"]
        if kind is None and image.shape[:2] != (h, w):
            kind = "undecodable_file"
        if kind is None and m == "depth" and image.dtype != np.uint16:
            kind = "undecodable_file"
        if kind:
            problems.append(_problem(split, frame_id, kind, f"{m}: {path.name}"))
        else:
            images[m] = image
    if "depth" not in images or "seg" not in images:
        return problems
    depth = images["depth"].astype(np.float64) * manifest["depth_scale_m"]
    seg = images["seg"]
    h, w = seg.shape
    # the stored flags must follow the documented rule on the stored images
    seen = visibility(row["keypoints_3d_cam"].astype(np.float64), row["keypoints_2d"].astype(np.float64), depth, seg,
                      slack_m=manifest["depth_scale_m"])
    uv = np.round(row["keypoints_2d"]).astype(np.int64)
    for i in np.flatnonzero(row["visible"][: kp.NUM_HAND] & ~seen[: kp.NUM_HAND]):
        u, v = np.clip(uv[i], 0, [w - 1, h - 1])
        problems.append(_problem(split, frame_id, "visible_not_on_hand",
                                 f"{kp.KEYPOINT_NAMES[i]}: label {int(seg[v, u])}, depth {depth[v, u]:.4f} m "
                                 f"vs z {row['keypoints_3d_cam'][i, 2]:.4f} m"))
    probe_mask = cv2.erode((seg == SEG_LABELS["probe"]).astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    ys, xs = np.nonzero(probe_mask & (depth > 0))
    if len(xs):
        pick = np.linspace(0, len(xs) - 1, min(len(xs), 200)).astype(int)
        K = np.asarray(row["K"])
        z = depth[ys[pick], xs[pick]]
        cam = np.stack([(xs[pick] - K[0, 2]) * z / K[0, 0], (ys[pick] - K[1, 2]) * z / K[1, 1], z], axis=1)
        world = transform_points(invert_transform(row["T_cam_world"]), cam)
        from datagen.probe import build_probe

        off = np.abs(build_probe().signed_distance(world))
        # a pixel's depth stands for its whole footprint (z / f metres wide): on slanted
        # surfaces that footprint, not the geometry, bounds the error
        limit = np.maximum(tol.VERIFY_PROBE_SURFACE_M, 1.5 * z / K[0, 0])
        bad = np.mean(off > limit)
        if bad > PROBE_BAD_FRACTION:
            problems.append(_problem(split, frame_id, "probe_depth",
                                     f"{100 * bad:.0f}% of probe pixels off the probe surface (max {1000 * off.max():.1f} mm)"))
    return problems


def verify(root, workers: int = 2, log=print) -> dict:
    """Verify a dataset folder.

    Returns:
        dict with "frames" checked, "problems" (list of dicts with split, frame_id, kind, detail),
        "by_kind" counts and "ok".
    """
    root = Path(root)
    manifest_path = root / "manifest.json"
    if not manifest_path.is_file():
        raise FileNotFoundError(f"{root} has no manifest.json: not a finished dataset")
    manifest = json.loads(manifest_path.read_text())
    problems, jobs, all_ids = [], [], []
    for split in SPLITS:
        expected = manifest["counts"].get(split, 0)
        path = root / split / "annotations.npz"
        if expected == 0:
            continue
        if not path.is_file():
            problems.append(_problem(split, None, "missing_file", "annotations.npz"))
            continue
        with np.load(path) as data:
            ann = {k: data[k] for k in data.files}
        if len(ann["frame_id"]) != expected:
            problems.append(_problem(split, None, "count_mismatch",
                                     f"{len(ann['frame_id'])} annotated frames, manifest says {expected}"))
        all_ids.append(ann["frame_id"])
        problems += check_geometry(ann, split)
        # datasets made before the manifest recorded a protocol have no look-at to check
        if "protocol" in manifest:
            problems += check_look_at(ann, split, manifest["protocol"]["look_at"])
        for i in range(len(ann["frame_id"])):
            jobs.append((str(root), split, manifest, {k: v[i] for k, v in ann.items()}))
    ids = np.concatenate(all_ids) if all_ids else np.zeros(0, dtype=np.int64)
    total = int(np.prod(manifest["layout"]["shape"]))
    if len(np.unique(ids)) != len(ids) or len(ids) != total:
        problems.append(_problem(None, None, "frame_ids", f"{len(ids)} frame ids, {len(np.unique(ids))} unique, "
                                                          f"layout holds {total}"))
    log(f"checking {len(jobs)} frames with {workers} worker(s)")
    if workers > 1 and len(jobs) > 64:
        with multiprocessing.get_context("fork").Pool(workers) as pool:
            for result in pool.imap(check_frame, jobs, chunksize=64):
                problems += result
    else:
        for job in jobs:
            problems += check_frame(job)
    by_kind = {kind: sum(p["kind"] == kind for p in problems) for kind in KINDS}
    return {"frames": len(jobs), "problems": problems, "by_kind": by_kind, "ok": not problems}


def sample_sheet(root, split: str = "train", view: int = 40, tile_px: int = 128) -> np.ndarray:
    """One frame per (background, glove) of a dataset: RGB, depth, mask and keypoints side by side.

    Takes the split's first grasp at the first distance and the given view index (by default view
    40 of the paper protocol's sphere: the grip and the probe's green orientation marker both show).

    Returns:
        (H, W, 3) uint8 RGB: one row per background, both gloves in a row.
    """
    from datagen.draw import colorize_depth, colorize_labels, draw_keypoints, grid, titled

    root = Path(root)
    manifest = json.loads((root / "manifest.json").read_text())
    missing = {"rgb", "depth", "seg"} - set(manifest["modalities"])
    if missing:
        raise ValueError(f"a sample sheet needs rgb, depth and seg; the dataset lacks {sorted(missing)}")
    with np.load(root / split / "annotations.npz") as data:
        ann = {k: data[k] for k in ("frame_id", "keypoints_2d", "visible", "background_id", "glove_id",
                                    "grasp_index", "z_ego")}
    n_view = manifest["layout"]["shape"][4]
    if not 0 <= view < n_view:
        raise ValueError(f"view must be in [0, {n_view}), got {view}")
    first = (ann["grasp_index"] == ann["grasp_index"].min()) & (ann["z_ego"] == ann["z_ego"].min())
    names = manifest["backgrounds"]["names"]
    tiles = []
    scale = tile_px / manifest["image_size"][0]
    for b in sorted(set(ann["background_id"].tolist())):
        for glove in sorted(set(ann["glove_id"].tolist())):
            rows = np.flatnonzero(first & (ann["background_id"] == b) & (ann["glove_id"] == glove))
            i = rows[min(view, len(rows) - 1)]
            fid = int(ann["frame_id"][i])
            rgb = cv2.imread(str(frame_path(root, split, "rgb", fid, manifest["rgb_format"])))[..., ::-1]
            depth = cv2.imread(str(frame_path(root, split, "depth", fid)), cv2.IMREAD_UNCHANGED)
            seg = cv2.imread(str(frame_path(root, split, "seg", fid)), cv2.IMREAD_UNCHANGED)
            size = (tile_px, tile_px)
            panels = [cv2.resize(np.ascontiguousarray(rgb), size, interpolation=cv2.INTER_AREA),
                      cv2.resize(colorize_depth(depth * manifest["depth_scale_m"]), size, interpolation=cv2.INTER_NEAREST),
                      cv2.resize(colorize_labels(seg), size, interpolation=cv2.INTER_NEAREST)]
            kps = draw_keypoints(panels[0], ann["keypoints_2d"][i] * scale + 0.5 * (scale - 1), ann["visible"][i],
                                 radius=1.5)
            label = f"{names[b]} / glove {glove}"
            tiles += [titled(panels[0], label[:22]), titled(panels[1], "depth"), titled(panels[2], "mask"),
                      titled(kps, f"frame {fid}")]
    return grid(tiles, columns=8)
