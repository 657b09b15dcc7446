"""The checks of :mod:`hupbench.datagen.dataset.verify` that need no image: the manifest's fields beyond the
contract's, its modalities against the folders, the annotations' rows, their geometry (reprojection, the
stored pose, the camera's aim), the splits' floors and the grasps file.

Each returns problems (:func:`hupbench.datagen.dataset.verify_frames._problem` dicts), except
:func:`check_manifest_extras`, which raises: a malformed field leaves nothing to check against.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from hupbench.core import keypoints as kp
from hupbench.core import tolerances as tol
from hupbench.core.camera import project_points
from hupbench.core.contract import (ANNOTATIONS, CLINIC, MANIFEST, SEQUENCE, SPLITS, STORED_MODALITIES, seg_labels,
                                    track_of)
from hupbench.core.errors import BadValueError
from hupbench.core.input_checks import is_number, is_whole
from hupbench.core.geometry import invert_transform, transform_points
from hupbench.core.io import file_sha256
from hupbench.datagen.dataset.floors import split_floors
from hupbench.datagen.dataset.verify_frames import _problem

#: per-row fields the contract does not require finite but the checks compute with
ROW_FINITE = ("hand_pose", "hand_trans", "light_position_cam", "light_color", "light_energy_w")
#: per-row fields with a physical range (inclusive): the lamp's colour is a fraction per channel, its power
#: is not negative (the generator draws 0.6-1 and 50-300 W, an import writes zeros)
ROW_RANGES = {"light_color": (0.0, 1.0), "light_energy_w": (0.0, math.inf)}


def problem_detail(exc: Exception, path: Path) -> str:
    """The contract's message without the absolute path it starts with (the problem names the file)."""
    text = str(exc)
    return text[len(str(path)) + 2:] if text.startswith(f"{path}: ") else text


def check_manifest_extras(manifest: dict, root: Path) -> None:
    """Manifest fields verify relies on beyond the contract's: protocol.look_at, gloves_rgb and seg_labels (the
    track's, :func:`hupbench.core.contract.seg_labels`)."""
    path = root / MANIFEST
    track_labels = seg_labels(track_of(manifest))
    labels = manifest.get("seg_labels", track_labels)
    if labels != track_labels:
        raise BadValueError(f"{path}: seg_labels must be the contract's {track_labels}, got {labels!r}")
    protocol = manifest.get("protocol")
    if protocol is not None:
        look_at = protocol.get("look_at") if isinstance(protocol, dict) else None
        if look_at != "box_centre" and look_at not in kp.KEYPOINT_NAMES:
            raise BadValueError(f"{path}: protocol.look_at must be 'box_centre' or a keypoint name, got {look_at!r}")
        if track_of(manifest) == CLINIC and look_at not in kp.KEYPOINT_NAMES:
            raise BadValueError(f"{path}: protocol.look_at must be a keypoint name on the clinic track (the head "
                                f"aims at a keypoint), got {look_at!r}")
    imported = manifest.get("imported")
    error = imported.get("depth", {}).get("error_max_m") if isinstance(imported, dict) and \
        isinstance(imported.get("depth"), dict) else None
    if imported is not None and (isinstance(error, bool) or not isinstance(error, (int, float))
                                 or not math.isfinite(error) or error < 0):
        raise BadValueError(f"{path}: imported.depth.error_max_m must be a number >= 0 (metres), got {error!r}")
    if SEQUENCE in manifest:
        record = manifest[SEQUENCE]
        fields = (record.get("fps"), record.get("frames_per_clip"), record.get("clips")) if isinstance(record, dict) \
            else (None, None, None)
        if track_of(manifest) != CLINIC or not (is_number(fields[0]) and fields[0] > 0 and is_whole(fields[1])
                                                and fields[1] > 0 and isinstance(fields[2], list)):
            raise BadValueError(f"{path}: {SEQUENCE} must be a clinic dataset's record of its clips with fps > 0, "
                                f"frames_per_clip > 0 and a list of clips, got {str(record)[:200]!r}")
    gloves = manifest.get("gloves_rgb")
    if gloves is not None:
        try:
            array = np.asarray(gloves, dtype=np.float64)
        except (TypeError, ValueError):
            array = np.zeros((0, 0))
        if array.ndim != 2 or array.shape[0] < 1 or array.shape[1] != 3 or not np.isfinite(array).all() \
                or array.min() < 0 or array.max() > 1:
            raise BadValueError(f"{path}: gloves_rgb must be a list of [r, g, b] colours in [0, 1], got {gloves!r}")


def check_rows(ann: dict, split: str, manifest: dict) -> tuple[list[dict], np.ndarray]:
    """Row values the contract does not check: finiteness of the pose and lamp, the lamp's colour and power
    within :data:`ROW_RANGES`, glove and background ids within the manifest's, K's last row 0 0 1 and K equal to
    the manifest's.

    Returns:
        problems, and (N,) bool: the rows the geometry and image checks can use.
    """
    rel = f"{split}/{ANNOTATIONS}"
    problems = []
    usable = np.ones(len(ann["frame_id"]), dtype=bool)
    for key in ROW_FINITE:
        values = ann[key].reshape(len(usable), -1)
        finite = np.isfinite(values).all(axis=1)
        low, high = ROW_RANGES.get(key, (-math.inf, math.inf))
        good = finite & ((values >= low) & (values <= high)).all(axis=1)
        for i in np.flatnonzero(~good):
            why = "holds NaN or inf" if not finite[i] else \
                f"is {np.round(values[i], 6).tolist()}, expected values in [{low:g}, {high:g}]"
            problems.append(_problem(split, ann["frame_id"][i], "bad_annotations",
                                     f"{key} of frame {int(ann['frame_id'][i]):06d} {why}", rel))
        usable &= good
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
    # the contract's reader refused focal lengths <= 0; a last row other than 0 0 1 is no pinhole camera either
    bad = ~(ann["K"][:, 2] == [0, 0, 1]).all(axis=1)
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


def check_split_floors(annotations: dict[str, dict], manifest: dict) -> tuple[dict | None, list[dict]]:
    """The splits' floors (:mod:`hupbench.datagen.dataset.floors`) recomputed from the annotations, and a problem
    when the manifest records others (beyond ``tol.VERIFY_FLOOR_MM``).

    Returns:
        (floors or None when there is no training split, problems).
    """
    if "train" not in annotations or not len(annotations["train"]["frame_id"]):
        return None, []
    try:
        floors = split_floors(annotations, track_of(manifest))
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


def check_geometry(ann: dict, split: str, stored_pose: bool = True, probe=None, hand_spec=None) -> list[dict]:
    """Checks that need no image: reprojection and (``stored_pose``) the stored pose, against ``probe``
    (the dataset's, :func:`hupbench.datagen.dataset.grasps_file.probe_of_dataset`; None: the procedural one)
    and the hand: ``hand_spec`` maps a row's ``grasp_index`` to its grasp's
    :class:`hupbench.datagen.assets.hand_anatomy.HandSpec`, or None for an index the grasps file lacks (the
    clinic track's subjects); None: the default hand for every row."""
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
    probe = probe or build_probe()
    if hand_spec is None:
        hand_world = build_hand().keypoints(ann["hand_pose"], ann["hand_trans"], clamp=False)
    else:
        hand_world = np.full((len(ann["frame_id"]), kp.NUM_HAND, 3), np.nan)  # NaN: fails, a grasp the file lacks
        for g in np.unique(ann["grasp_index"]).tolist():
            rows = ann["grasp_index"] == g
            spec = hand_spec(g)
            if spec is not None:
                hand_world[rows] = build_hand(spec).keypoints(ann["hand_pose"][rows], ann["hand_trans"][rows],
                                                              clamp=False)
    world = np.concatenate([hand_world, np.broadcast_to(probe.corners_probe, (len(ann["frame_id"]), 8, 3))], axis=1)
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
        point = cam[:, kp.KEYPOINT_NAMES.index(look_at)]  # check_manifest_extras checked the name
    expected = np.zeros_like(point)
    expected[:, 2] = ann["z_ego"]
    err = np.linalg.norm(point - expected, axis=1)
    return [_problem(split, ann["frame_id"][i], "look_at",
                     f"{look_at} at {np.round(1000 * point[i], 3).tolist()} mm, expected (0, 0, z_ego) "
                     f"({1000 * err[i]:.4f} mm off)", f"{split}/{ANNOTATIONS}")
            for i in np.flatnonzero(~(err <= tol.VERIFY_LOOK_AT_M))]


def check_grasps_file(root: Path, annotations: dict[str, dict], manifest: dict) -> list[dict]:
    """grasps.npz against the frames and the manifest: each row's hand pose, translation and grasp id must
    be those of its grasp (``grasp_index``) in the file, as the writer copied them (on a dataset of clips the pose
    with its clip's finger adjustments), and the file's sha256
    the manifest's ``grasps_sha256`` where it records one."""
    from hupbench.datagen.dataset.grasps_file import read_grasps, rendered_with

    path = root / "grasps.npz"
    if not path.is_file():
        return [_problem(None, None, "grasps_file", "missing: the grasps the frames were rendered with", path.name)]
    try:
        grasps = read_grasps(path)
    except ValueError as exc:
        return [_problem(None, None, "grasps_file", problem_detail(exc, path), path.name)]
    problems = []
    recorded, actual = manifest.get("grasps_sha256"), file_sha256(path)
    if recorded is not None and recorded != actual:
        problems.append(_problem(None, None, "grasps_file", f"sha256 {actual} is not the manifest's grasps_sha256 "
                                                            f"{recorded!r}: the file was changed or replaced", path.name))
    for split, ann in annotations.items():
        same = rendered_with(grasps, ann, manifest)
        if not same.all():
            first = int(ann["frame_id"][np.flatnonzero(~same)[0]])
            problems.append(_problem(split, first, "grasps_file",
                                     f"not the grasps the frames were rendered with: {int((~same).sum())} {split} frames' "
                                     f"grasp (id, hand pose, translation) differ from it (first {first:06d})",
                                     path.name))
    return problems


def check_modalities(root: Path, manifest: dict) -> list[dict]:
    """Image folders of a modality the manifest does not list: a manifest that dropped it, or files of
    another dataset (the per-frame checks read only the listed modalities)."""
    problems = []
    for modality in (m for m in STORED_MODALITIES if m not in manifest["modalities"]):
        held = {split: sum(1 for _ in (root / split / modality).glob("*.*"))
                for split in SPLITS if (root / split / modality).is_dir()}
        if any(held.values()):
            where = ", ".join(f"{split}/{modality}/ {n}" for split, n in held.items() if n)
            problems.append(_problem(None, None, "manifest_mismatch",
                                     f"modalities {manifest['modalities']} do not list {modality}, but the dataset "
                                     f"holds {modality} images ({where} files): the manifest was edited, or the "
                                     "files are another dataset's", MANIFEST))
    return problems
