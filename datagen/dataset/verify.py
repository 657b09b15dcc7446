"""Re-check a dataset against its manifest, against geometry and against its own images.

verify reads through :mod:`hupbench.core.contract`. Two kinds of answer:

* **fatal** (``ValueError`` / ``FileNotFoundError``, one error line from the CLI): nothing to check
  against: the dataset folder or its ``manifest.json`` is missing or unreadable, or a manifest
  field is missing or malformed (:func:`hupbench.core.contract.read_manifest`: keypoint names other than
  the 29 of :mod:`hupbench.core.keypoints`, a K that is not 3 x 3, image_size not [w, h], ...; here also
  an unknown ``protocol.look_at``, a malformed ``gloves_rgb`` and ``seg_labels`` other than the contract's).
* **problems**, reported with a kind, the split, the frame and the file; the other splits and
  frames are still checked and the verdict is FAILED. Kinds:

  ``count_mismatch``    the manifest's counts disagree with its layout, or a split's annotated
                        frames with the manifest's count (the frames are still checked)
  ``missing_file``      a file the manifest implies is absent (annotations.npz or an image)
  ``damaged_file``      annotations.npz cannot be read whole: empty, truncated, not a zip, bad CRC
  ``bad_annotations``   annotations.npz reads but breaks the contract: an array missing or of
                        another dtype or row shape (e.g. 21 keypoints), NaN or inf, a glove,
                        background or view id the manifest does not have, a K that is no camera
  ``frame_ids``         frame ids repeated or out of order, or not the layout's ids
  ``manifest_mismatch`` the manifest disagrees with the files: its K with the annotations' K, its
                        image_size with every image
  ``undecodable_file``  an image file that is empty, truncated (no end marker) or not a PNG/JPEG
  ``image_format``      an image that decodes but has another size, bit depth or channel count
                        than the contract, or seg labels outside ``SEG_LABELS``
  ``reprojection``      2D keypoints != the projection of the 3D ones
  ``pose_mismatch``     3D keypoints != those of the stored hand pose and probe seen by the stored camera
  ``look_at``           the point the manifest's protocol aims at is not at (0, 0, z_ego) in the camera frame
  ``visible_not_on_hand`` a visible hand keypoint whose pixel is not hand in the mask or whose depth
                        is not just in front of it
  ``marked_invisible``  keypoints marked invisible that the depth and mask show in view and unoccluded
  ``empty_frame``       the mask (or, without one, the depth) shows nothing in front of the background
  ``probe_depth``       probe pixels unprojected with their depth are off the probe surface by more
                        than max(3 mm, 1.5 pixel footprints)
  ``image_shift``       the depth and mask sit off the labels: probe pixels unprojected with their
                        depth fit the probe (placed by the labels) only after a shift of the image
                        by more than ``VERIFY_IMAGE_SHIFT_PX`` (:func:`image_shift_px`); the
                        frames' median shift is reported beside the verdict
  ``mask_depth``        depth and seg disagree on foreground away from the silhouette's edge: one of
                        them belongs to another frame
  ``split_floors``      the manifest's floor of a split (:mod:`hupbench.datagen.dataset.floors`) differs from
                        the one its annotations give
  ``rgb_mismatch``      the RGB image does not show this frame: pixels the mask calls background
                        differ from the frame's background image, or the hand's colour is explained
                        better by another glove than by the frame's glove under the frame's lamp
  ``rgb_channels``      the forearm's pixels have red and blue the other way round from its colour
                        (``arm_rgb``): the image was stored as RGB, or its channels swapped
  ``grasps_file``       grasps.npz is missing, unreadable, or not the grasps the frames were rendered
                        with (their hand poses, translations and ids in the annotations)

How the per-frame checks work: :mod:`hupbench.datagen.dataset.verify_frames`.
"""

from __future__ import annotations

import json
import math
import multiprocessing
import sys
import zipfile
from pathlib import Path

import numpy as np

from hupbench.core import keypoints as kp
from hupbench.core import tolerances as tol
from hupbench.core.camera import project_points
from hupbench.core.input_checks import is_whole
from hupbench.core.contract import (
    ANNOTATIONS,
    MANIFEST,
    SEG_LABELS,
    SPLITS,
    DamagedFileError,
    annotations_path,
    check_manifest,
    read_annotations,
    read_manifest,
)
from hupbench.datagen.dataset.floors import split_floors
from hupbench.core.geometry import invert_transform, transform_points
from hupbench.core.processes import check_workers, workers_ignore_ctrl_c
from hupbench.datagen.dataset.verify_frames import _CONTEXT, _problem, check_frame
from hupbench.core.errors import BadValueError


KINDS = ("count_mismatch", "missing_file", "damaged_file", "bad_annotations", "frame_ids", "manifest_mismatch",
         "undecodable_file", "image_format", "reprojection", "pose_mismatch", "look_at", "visible_not_on_hand",
         "marked_invisible", "empty_frame", "probe_depth", "image_shift", "mask_depth", "split_floors", "rgb_mismatch",
         "rgb_channels", "grasps_file")
#: what verify leaves out on a dataset converted from another format (manifest "imported"), and why
IMPORTED_SKIPS = (
    ("pose_mismatch: the stored hand pose is the source's MANO parameters and the probe its own mesh; hupbench's "
     "hand and probe cannot rebuild the keypoints"),
    "probe_depth, image_shift: they measure against hupbench's probe surface, not the source's mesh",
    "grasps_file: an imported dataset has no grasps.npz",
    "look_at, rgb_channels: the source records no protocol and no forearm colour",
)
#: fewer frames than this are checked in this process (starting workers would take longer)
POOL_MIN_FRAMES = 64
#: annotation fields the per-frame checks use
FRAME_KEYS = ("frame_id", "keypoints_3d_cam", "keypoints_2d", "visible", "K", "T_cam_world", "background_id",
              "glove_id", "light_color")
#: per-row fields the contract does not require finite but the checks compute with
ROW_FINITE = ("hand_pose", "hand_trans", "light_position_cam", "light_color", "light_energy_w")


def _message(exc: Exception, path: Path) -> str:
    """The contract's message without the absolute path it starts with (the problem names the file)."""
    text = str(exc)
    return text[len(str(path)) + 2:] if text.startswith(f"{path}: ") else text


# --- reading the manifest and the annotations -----------------------------------------------


def _manifest_but_for_counts(root: Path) -> dict | None:
    """The manifest when its only fault is a counts total other than its layout's, else None."""
    path = root / MANIFEST
    try:
        manifest = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return None
    if not isinstance(manifest, dict) or not isinstance(manifest.get("counts"), dict) \
            or not isinstance(manifest.get("layout"), dict):
        return None
    layout = manifest["layout"]
    try:
        # every other field passes with counts that fill the layout, and the counts themselves are
        # well formed when they fill a layout of their own total
        check_manifest(dict(manifest, counts={"train": math.prod(layout.get("shape"))}), path)
        check_manifest(dict(manifest, layout=dict(layout, shape=[sum(manifest["counts"].values()), 1, 1, 1, 1])), path)
    except (TypeError, ValueError):
        return None
    return manifest


def _read_manifest(root: Path) -> tuple[dict, list[dict]]:
    try:
        return read_manifest(root, needs="verify checks"), []
    except ValueError as exc:
        manifest = _manifest_but_for_counts(root)
        if manifest is None:
            raise
        # counts that disagree with the layout are what verify reports: each split is then checked
        # against its own count
        return manifest, [_problem(None, None, "count_mismatch", _message(exc, root / MANIFEST), MANIFEST)]


def _check_manifest_extras(manifest: dict, root: Path) -> None:
    """Manifest fields verify relies on beyond the contract's: protocol.look_at, gloves_rgb and seg_labels."""
    path = root / MANIFEST
    labels = manifest.get("seg_labels", SEG_LABELS)
    if labels != SEG_LABELS:
        raise BadValueError(f"{path}: seg_labels must be the contract's {SEG_LABELS}, got {labels!r}")
    protocol = manifest.get("protocol")
    if protocol is not None:
        look_at = protocol.get("look_at") if isinstance(protocol, dict) else None
        if look_at != "box_centre" and look_at not in kp.KEYPOINT_NAMES:
            raise BadValueError(f"{path}: protocol.look_at must be 'box_centre' or a keypoint name, got {look_at!r}")
    imported = manifest.get("imported")
    error = imported.get("depth", {}).get("error_max_m") if isinstance(imported, dict) and \
        isinstance(imported.get("depth"), dict) else None
    if imported is not None and (isinstance(error, bool) or not isinstance(error, (int, float))
                                 or not math.isfinite(error) or error < 0):
        raise BadValueError(f"{path}: imported.depth.error_max_m must be a number >= 0 (metres), got {error!r}")
    gloves = manifest.get("gloves_rgb")
    if gloves is not None:
        try:
            array = np.asarray(gloves, dtype=np.float64)
        except (TypeError, ValueError):
            array = np.zeros((0, 0))
        if array.ndim != 2 or array.shape[0] < 1 or array.shape[1] != 3 or not np.isfinite(array).all() \
                or array.min() < 0 or array.max() > 1:
            raise BadValueError(f"{path}: gloves_rgb must be a list of [r, g, b] colours in [0, 1], got {gloves!r}")


def _frame_ids(path: Path) -> np.ndarray | None:
    """The frame_id column of an annotations file the contract could open, or None."""
    try:
        with np.load(path, allow_pickle=False) as data:
            ids = data["frame_id"]
    except (ValueError, KeyError, OSError, EOFError, zipfile.BadZipFile):
        return None
    return ids if ids.ndim == 1 and np.issubdtype(ids.dtype, np.integer) else None


def _read_split(root: Path, split: str, manifest: dict) -> tuple[dict | None, list[dict]]:
    """A split's annotations through the contract, or None and the problems that stopped it."""
    path = annotations_path(root, split)
    rel = f"{split}/{ANNOTATIONS}"
    expected = manifest["counts"][split]
    try:
        return read_annotations(root, split, manifest=manifest), []
    except FileNotFoundError:
        return None, [_problem(split, None, "missing_file", f"missing (the manifest counts {expected} {split} frames)", rel)]
    except DamagedFileError as exc:
        return None, [_problem(split, None, "damaged_file", _message(exc, path), rel)]
    except ValueError as exc:
        rejected = exc
    problems = []
    ids = _frame_ids(path)
    if ids is not None and len(ids) != expected:
        problems.append(_problem(split, None, "count_mismatch",
                                 f"{len(ids)} annotated frames, the manifest counts {expected}", rel))
        try:
            counted = dict(manifest, counts=dict(manifest["counts"], **{split: len(ids)}))
            return read_annotations(root, split, manifest=counted), problems
        except ValueError as exc:
            rejected = exc
    if ids is not None and len(ids) > 1 and not (np.diff(ids) > 0).all():
        repeated = len(ids) - len(np.unique(ids))
        problems.append(_problem(split, None, "frame_ids", f"frame_id is not strictly ascending ({repeated} repeated, "
                                                           f"{len(ids)} rows)", rel))
    else:
        problems.append(_problem(split, None, "bad_annotations", _message(rejected, path), rel))
    return None, problems


def _check_rows(ann: dict, split: str, manifest: dict) -> tuple[list[dict], np.ndarray]:
    """Row values the contract does not check: finiteness of the pose and lamp, glove and background
    ids within the manifest's, K equal to the manifest's.

    Returns:
        problems, and (N,) bool: the rows the geometry and image checks can use.
    """
    rel = f"{split}/{ANNOTATIONS}"
    problems = []
    usable = np.ones(len(ann["frame_id"]), dtype=bool)
    for key in ROW_FINITE:
        bad = ~np.isfinite(ann[key].reshape(len(usable), -1)).all(axis=1)
        for i in np.flatnonzero(bad):
            problems.append(_problem(split, ann["frame_id"][i], "bad_annotations",
                                     f"{key} of frame {int(ann['frame_id'][i]):06d} holds NaN or inf", rel))
        usable &= ~bad
    limits = {"glove_id": ("gloves_rgb", manifest.get("gloves_rgb")),
              "background_id": ("backgrounds.names", (manifest.get("backgrounds") or {}).get("names")
                                if isinstance(manifest.get("backgrounds"), dict) else None)}
    viewpoints = manifest.get("viewpoints")
    limits["view_id"] = ("viewpoints.ids", viewpoints.get("ids") if isinstance(viewpoints, dict) else None)
    for key, (field, values) in limits.items():
        if not isinstance(values, list):
            continue  # an older manifest without the record: nothing to compare with
        allowed = np.arange(len(values)) if key != "view_id" else np.asarray(values, dtype=np.int64)
        bad = ~np.isin(ann[key], allowed)
        for i in np.flatnonzero(bad):
            problems.append(_problem(split, ann["frame_id"][i], "bad_annotations",
                                     f"{key} {int(ann[key][i])} of frame {int(ann['frame_id'][i]):06d} is not one of "
                                     f"the manifest's {len(values)} ({field})", rel))
        usable &= ~bad
    # a K without positive focal lengths would divide the per-frame checks by zero
    bad = ~((ann["K"][:, 0, 0] > 0) & (ann["K"][:, 1, 1] > 0) & (ann["K"][:, 2] == [0, 0, 1]).all(axis=1))
    for i in np.flatnonzero(bad):
        problems.append(_problem(split, ann["frame_id"][i], "bad_annotations",
                                 f"K of frame {int(ann['frame_id'][i]):06d} is not a camera matrix (fx, fy > 0, last row "
                                 f"0 0 1): {ann['K'][i].tolist()}", rel))
    usable &= ~bad
    K = np.asarray(manifest["K"], dtype=np.float64)
    off = np.abs(ann["K"] - K).max(axis=(1, 2))
    differ = np.flatnonzero(off > tol.VERIFY_K_PX)
    if len(differ):
        i = differ[0]
        problems.append(_problem(split, None, "manifest_mismatch",
                                 f"K of {len(differ)} frames (first {int(ann['frame_id'][i]):06d}) differs from the "
                                 f"manifest's K by up to {off[differ].max():.4g} px", rel))
    return problems, usable


def _load_backgrounds(manifest: dict):
    """The BackgroundSet the dataset was rendered with (its fingerprint matches), or None and why."""
    from hupbench.datagen.assets.backgrounds import BackgroundSet

    record = manifest.get("backgrounds")
    if not isinstance(record, dict) or not isinstance(record.get("fingerprint"), str):
        return None, "the manifest records no backgrounds fingerprint"
    config = manifest.get("config")
    folder = None
    if isinstance(config, dict) and isinstance(config.get("backgrounds"), dict):
        folder = config["backgrounds"].get("dir")
    candidates = [("the built-in backgrounds", BackgroundSet.builtin)]
    if isinstance(folder, str):
        candidates.insert(0, (f"backgrounds.dir {folder}", lambda: BackgroundSet.from_dir(folder)))
    for _, make in candidates:
        try:
            backgrounds = make()
        except ValueError:  # the photographs' folder is gone or unreadable here
            continue
        if backgrounds.fingerprint() == record["fingerprint"]:
            return backgrounds, None
    tried = " or ".join(what for what, _ in candidates)
    return None, f"the backgrounds it was rendered with are not here (fingerprint differs from {tried})"


def check_split_floors(annotations: dict[str, dict], manifest: dict) -> tuple[dict | None, list[dict]]:
    """The splits' floors (:mod:`hupbench.datagen.dataset.floors`) recomputed from the annotations, and a problem
    when the manifest records others (beyond ``tol.VERIFY_FLOOR_MM``).

    Returns:
        (floors or None when there is no training split, problems).
    """
    if "train" not in annotations or not len(annotations["train"]["frame_id"]):
        return None, []
    try:
        floors = split_floors(annotations)
    except ValueError as exc:
        return None, [_problem(None, None, "split_floors", str(exc), ANNOTATIONS)]
    recorded = (manifest.get("split_floors") or {}).get("splits") if isinstance(manifest.get("split_floors"), dict) \
        else None
    if recorded is None:
        return floors, []  # a dataset made before the manifest recorded its floors
    problems = []
    for split, entry in floors.items():
        mine = entry["floor_mm"]
        theirs = (recorded.get(split) or {}).get("floor_mm") if isinstance(recorded.get(split), dict) else None
        if not isinstance(theirs, dict) or any(not isinstance(theirs.get(k), (int, float))
                                               or abs(theirs[k] - mine[k]) > tol.VERIFY_FLOOR_MM for k in mine):
            problems.append(_problem(split, None, "split_floors",
                                     f"the manifest's floor of {split} is {theirs}, the annotations give "
                                     + ", ".join(f"{k} {v:.3f}" for k, v in mine.items()) + " mm", MANIFEST))
    return floors, problems


def check_geometry(ann: dict, split: str, stored_pose: bool = True, probe=None) -> list[dict]:
    """Checks that need no image: reprojection and (``stored_pose``) the stored pose, against ``probe``
    (the dataset's, :func:`hupbench.datagen.dataset.grasps_file.probe_of_dataset`; None: the procedural one)."""
    from hupbench.datagen.assets.hand import build_hand
    from hupbench.datagen.assets.probe import build_probe

    rel = f"{split}/{ANNOTATIONS}"
    problems = []
    if not len(ann["frame_id"]):
        return problems
    uv = project_points(ann["keypoints_3d_cam"].astype(np.float64), ann["K"], behind="nan")
    err = np.abs(uv - ann["keypoints_2d"]).max(axis=(1, 2))
    for i in np.flatnonzero(~(err <= tol.VERIFY_REPROJECTION_PX)):
        problems.append(_problem(split, ann["frame_id"][i], "reprojection", f"2D off the projection by {err[i]:.4f} px",
                                 rel))
    if not stored_pose:
        return problems
    hand, probe = build_hand(), probe or build_probe()
    world = np.concatenate([hand.keypoints(ann["hand_pose"], ann["hand_trans"], clamp=False),
                            np.broadcast_to(probe.corners_probe, (len(ann["frame_id"]), 8, 3))], axis=1)
    cam = transform_points(ann["T_cam_world"], world)
    err3 = np.linalg.norm(cam - ann["keypoints_3d_cam"], axis=-1).max(axis=1)
    for i in np.flatnonzero(~(err3 <= tol.VERIFY_KEYPOINT_M)):
        problems.append(_problem(split, ann["frame_id"][i], "pose_mismatch",
                                 f"3D keypoints {1000 * err3[i]:.2f} mm from the stored pose", rel))
    return problems


def check_look_at(ann: dict, split: str, look_at: str) -> list[dict]:
    """The camera's aim: ``look_at`` (a keypoint name or "box_centre", the centre of the 29
    keypoints' box in the world frame) must sit at (0, 0, z_ego) in every frame's camera frame."""
    cam = ann["keypoints_3d_cam"].astype(np.float64)
    if look_at == "box_centre":
        world = transform_points(invert_transform(ann["T_cam_world"]), cam)
        centre = 0.5 * (world.min(axis=1) + world.max(axis=1))
        point = transform_points(ann["T_cam_world"], centre[:, None])[:, 0]
    else:
        point = cam[:, kp.KEYPOINT_NAMES.index(look_at)]  # _check_manifest_extras checked the name
    expected = np.zeros_like(point)
    expected[:, 2] = ann["z_ego"]
    err = np.linalg.norm(point - expected, axis=1)
    return [_problem(split, ann["frame_id"][i], "look_at",
                     f"{look_at} at {np.round(1000 * point[i], 3).tolist()} mm, expected (0, 0, z_ego) "
                     f"({1000 * err[i]:.4f} mm off)", f"{split}/{ANNOTATIONS}")
            for i in np.flatnonzero(~(err <= tol.VERIFY_LOOK_AT_M))]


def check_grasps_file(root: Path, annotations: dict[str, dict]) -> list[dict]:
    """grasps.npz against the frames: each row's hand pose, translation and grasp id must be those of its
    grasp (``grasp_index``) in the file, as the writer copied them."""
    from hupbench.datagen.dataset.grasps_file import read_grasps, rendered_with

    path = root / "grasps.npz"
    if not path.is_file():
        return [_problem(None, None, "grasps_file", "missing: the grasps the frames were rendered with", path.name)]
    try:
        grasps = read_grasps(path)
    except ValueError as exc:
        return [_problem(None, None, "grasps_file", _message(exc, path), path.name)]
    problems = []
    for split, ann in annotations.items():
        same = rendered_with(grasps, ann)
        if not same.all():
            first = int(ann["frame_id"][np.flatnonzero(~same)[0]])
            problems.append(_problem(split, first, "grasps_file",
                                     f"not the grasps the frames were rendered with: {int((~same).sum())} {split} frames' "
                                     f"grasp (id, hand pose, translation) differ from it (first {first:06d})",
                                     path.name))
    return problems


def _glove_partners(ann: dict) -> dict[int, int]:
    """{row: partner row} for frames of one view (grasp, distance, background, view) in two gloves;
    each pair once, from its lower frame id."""
    groups: dict[tuple, list[int]] = {}
    for i, key in enumerate(zip(ann["grasp_index"].tolist(), ann["z_ego"].tolist(), ann["background_id"].tolist(),
                                ann["view_id"].tolist())):
        groups.setdefault(key, []).append(i)
    return {rows[0]: rows[1] for rows in groups.values()
            if len(rows) == 2 and ann["glove_id"][rows[0]] != ann["glove_id"][rows[1]]}


def _jpeg_quality(manifest: dict) -> int | None:
    """The dataset's JPEG quality (None for PNG images); the generator's default when not recorded."""
    from hupbench.datagen.dataset.spec import DatasetSpec

    if manifest["rgb_format"] == "png":
        return None
    config = manifest.get("config")
    dataset = config.get("dataset") if isinstance(config, dict) else None
    quality = dataset.get("jpeg_quality") if isinstance(dataset, dict) else None
    if is_whole(quality) and 0 <= quality <= 100:
        return quality
    return DatasetSpec.jpeg_quality


def _collapse_image_size(problems: list[dict], frames: int, size: tuple[int, int]) -> list[dict]:
    """Every image of a modality with the same other size: one manifest_mismatch on image_size."""
    sizes: dict[str, set] = {}
    counts: dict[str, int] = {}
    for p in problems:
        if "_size" in p:
            m, w, h = p["_size"]
            sizes.setdefault(m, set()).add((w, h))
            counts[m] = counts.get(m, 0) + 1
    whole = {m for m in sizes if len(sizes[m]) == 1 and counts[m] == frames and frames > 0}
    out = [p for p in problems if p.get("_size", (None,))[0] not in whole]
    for m in sorted(whole):
        (w, h), = sizes[m]
        out.append(_problem(None, None, "manifest_mismatch", f"image_size is {size[0]} x {size[1]} but all {frames} "
                                                             f"{m} images are {w} x {h}", MANIFEST))
    for p in out:
        p.pop("_size", None)
    return out


def _check_frames(jobs: list, workers: int, progress: bool | None) -> tuple[list[dict], list]:
    """:func:`check_frame` over ``jobs`` (in ``workers`` processes when there are enough), with a progress bar:
    (the problems found, the image shifts measured)."""
    from tqdm import tqdm

    bar = tqdm(total=len(jobs), unit="frame", desc="verify", disable=not (sys.stderr.isatty() if progress is None
                                                                          else progress),
               dynamic_ncols=True, smoothing=0.1)
    frame_problems, shifts = [], []
    try:
        if workers > 1 and len(jobs) > POOL_MIN_FRAMES:
            with workers_ignore_ctrl_c():
                pool = multiprocessing.get_context("fork").Pool(workers)
            with pool:
                results = pool.imap(check_frame, jobs, chunksize=64)
                for found, shift in results:
                    frame_problems += found
                    shifts += [] if shift is None else [shift]
                    bar.update()
        else:
            for job in jobs:
                found, shift = check_frame(job)
                frame_problems += found
                shifts += [] if shift is None else [shift]
                bar.update()
    finally:
        bar.close()
    return frame_problems, shifts


def verify(root, workers: int = 2, log=print, progress: bool | None = None) -> dict:
    """Verify a dataset folder (module docstring: what is fatal, what is a problem).

    Args:
        root: the dataset folder.
        workers: processes for the per-frame image checks (>= 1).
        log: where the progress lines go.
        progress: a progress bar with ETA on stderr; None: when stderr is a terminal.

    Returns:
        dict with "frames" (frames whose images were checked), "problems" (dicts with split,
        frame_id, kind, file, detail), "by_kind" counts, "skipped" (checks that could not run, and
        why), "ok", "split_floors" (:func:`hupbench.datagen.dataset.floors.split_floors` of the annotations, None
        without a training split) and "image_shift" ({"median_px": [du, dv], "frames"}: the frames'
        median :func:`image_shift_px`, None when no frame allowed the measurement).

    Raises:
        FileNotFoundError, ValueError: nothing to verify against (module docstring).
    """
    check_workers(workers)
    root = Path(root)
    manifest, problems = _read_manifest(root)
    _check_manifest_extras(manifest, root)
    skipped = []
    imported = manifest.get("imported")
    # the probe the frames show (a mesh probe's geometry is in the dataset's grasps.npz)
    from hupbench.datagen.dataset.grasps_file import probe_of_dataset

    probe = probe_of_dataset(root) if imported is None else None
    if imported is not None:
        skipped += IMPORTED_SKIPS
    backgrounds, gloves, quality = None, None, _jpeg_quality(manifest)
    if "rgb" in manifest["modalities"] and "seg" in manifest["modalities"]:
        backgrounds, why = _load_backgrounds(manifest)
        if why:
            skipped.append(f"RGB against background images: {why}")
        gloves = manifest.get("gloves_rgb")
        if gloves is None:
            skipped.append("RGB against glove colours: the manifest records no gloves_rgb")
    jobs, all_ids, complete, annotations = [], [], True, {}
    for split in SPLITS:
        if manifest["counts"].get(split, 0) == 0:
            continue
        ann, found = _read_split(root, split, manifest)
        problems += found
        if ann is None:
            complete = False
            continue
        all_ids.append(ann["frame_id"])
        found, usable = _check_rows(ann, split, manifest)
        problems += found
        ann = {k: v[usable] for k, v in ann.items()}
        annotations[split] = ann
        problems += check_geometry(ann, split, stored_pose=imported is None, probe=probe)
        # datasets made before the manifest recorded a protocol have no look-at to check
        if "protocol" in manifest:
            problems += check_look_at(ann, split, manifest["protocol"]["look_at"])
        partners = _glove_partners(ann) if gloves is not None and len(gloves) > 1 else {}
        for i in range(len(ann["frame_id"])):
            row = {k: ann[k][i] for k in FRAME_KEYS}
            p = partners.get(i)
            row["partner"] = None if p is None else {k: ann[k][p] for k in ("frame_id", "glove_id", "light_color")}
            jobs.append((split, row))
    if complete:
        ids = np.concatenate(all_ids) if all_ids else np.zeros(0, dtype=np.int64)
        total = math.prod(manifest["layout"]["shape"])
        if len(np.unique(ids)) != len(ids) or len(ids) != total or (len(ids) and (ids.min() < 0 or ids.max() >= total)):
            problems.append(_problem(None, None, "frame_ids", f"{len(ids)} frame ids, {len(np.unique(ids))} unique, "
                                                              f"the layout holds ids 0 to {total - 1}"))
    floors, found = check_split_floors(annotations, manifest) if complete else (None, [])
    problems += found
    if imported is None:
        problems += check_grasps_file(root, annotations)
    for note in skipped:
        log(f"not checked: {note}")
    if imported is not None:
        log(f"imported ({imported.get('format')}): visibility checked with the depth's precision, "
            f"{1000 * imported['depth']['error_max_m']:.2f} mm")
    log(f"checking {len(jobs)} frames with {workers} worker(s)")
    _CONTEXT.update(root=root, manifest=manifest, backgrounds=backgrounds, jpeg_quality=quality, probe=probe,
                    gloves=None if gloves is None else np.asarray(gloves, dtype=np.float64))
    try:
        frame_problems, shifts = _check_frames(jobs, workers, progress)
    finally:
        _CONTEXT.clear()
    problems += _collapse_image_size(frame_problems, len(jobs), tuple(manifest["image_size"]))
    by_kind = {kind: sum(p["kind"] == kind for p in problems) for kind in KINDS}
    image_shift = {"median_px": np.median(shifts, axis=0).tolist(), "frames": len(shifts)} if shifts else None
    return {"frames": len(jobs), "problems": problems, "by_kind": by_kind, "skipped": skipped, "ok": not problems,
            "split_floors": floors, "image_shift": image_shift}


def report_lines(result: dict, max_report: int) -> list[str]:
    """What ``hupbench verify`` prints of :func:`verify`'s ``result``: the first ``max_report`` problems, the
    images' shift against the labels, each split's floor and the verdict."""
    lines = []
    for p in result["problems"][:max_report]:
        where = p["file"] or (f"split {p['split']}" if p["split"] else "dataset")
        frame = "" if p["frame_id"] is None else f" (frame {p['frame_id']})"
        lines.append(f"  {p['kind']:18s} {where}{frame}: {p['detail']}")
    hidden = len(result["problems"]) - max_report
    if hidden > 0:
        lines.append(f"  ... and {hidden} more (--max-report {len(result['problems'])} prints all)")
    if result["image_shift"]:
        du, dv = result["image_shift"]["median_px"]
        lines.append(f"  images against labels: median shift ({du:+.3f}, {dv:+.3f}) px over "
                     f"{result['image_shift']['frames']} frames (probe pixels unprojected with their depth, fitted to "
                     "the probe)")
    for split, floor in (result["split_floors"] or {}).items():
        lines.append(f"  floor of {split}: " + _floor_line(floor))
    if not result["ok"]:
        counts = ", ".join(f"{k} {v}" for k, v in result["by_kind"].items() if v)
        lines.append(f"hupbench verify: FAILED, {len(result['problems'])} problem(s) in {result['frames']} frames: "
                     f"{counts}")
    else:
        lines.append(f"hupbench verify: OK, {result['frames']} frames checked")
    return lines


def _floor_line(floor: dict) -> str:
    """One split's floors (:mod:`hupbench.datagen.dataset.floors`) in one line."""
    def mm(t: dict) -> str:
        return f"hand {t['hand']:.1f} / probe {t['probe']:.1f} / all {t['all']:.1f} mm"

    parts = [f"nearest training grasp under the true camera {mm(floor['nearest_train_grasp_mm'])}"]
    if floor["nearest_train_view_mm"] is not None:
        parts.append(f"nearest training view of the same grasp {mm(floor['nearest_train_view_mm'])}")
    parts.append(f"mean training grasp {mm(floor['train_mean_mm'])}")
    return "; ".join(parts) + (f" (a model that only recalls training labels scores no better than the "
                               f"{floor['floor_kind']} one)")
