"""The dataset on disk: the one contract between the generator and every reader (numpy only).

The layout::

    DATASET/manifest.json                  written last: a dataset without it is not finished
    DATASET/grasps.npz
    DATASET/<split>/annotations.npz        ANNOTATION_DTYPES, one row per frame, sorted by frame_id
    DATASET/<split>/rgb/<frame_id>.jpg     (or .png, manifest "rgb_format")
    DATASET/<split>/depth/<frame_id>.png   uint16, metres = value * depth_scale_m, 0 = background
    DATASET/<split>/seg/<frame_id>.png     uint8, SEG_LABELS
    DATASET/<split>/sensor_depth/<frame_id>.png  uint16 as depth, 0 = none measured (a dataset with a depth sensor)

The generator writes through these names; training, verify, eval, export and the quickstart read
through :func:`read_manifest` and :func:`read_annotations`, which check what they return (the
manifest's fields, the npz's integrity, every array's dtype and shape, the row count against the
manifest, the camera's focal lengths) and raise a :class:`hupbench.core.errors.BadValueError` naming the
file, the field and what was wrong. This module imports numpy
and the keypoint order only: a reader never pulls in the renderer.

Convention:
    Annotations are in the OpenCV camera frame (x right, y down, z forward), metres; 2D keypoints
    in pixels of the stored image; K (3, 3) of the stored image. Pixel centres are at integers:
    the pixel in row r, column c covers [c - 0.5, c + 0.5) x [r - 0.5, r + 0.5), and a camera-frame
    point (x, y, z) is seen at u = fx x / z + cx, v = fy y / z + cy in those coordinates. The images
    follow it (the renderer shifts GL's half-integer pixel centres by half a pixel), so the mask of
    a small sphere centred on the optical axis has its centroid at (cx, cy).
"""

from __future__ import annotations

import json
import math
import zipfile
from pathlib import Path
from typing import Iterable

import numpy as np

from hupbench.core import keypoints as kp
from hupbench.core.input_checks import is_number, is_whole
from hupbench.core.errors import BadValueError, MissingFileError

SCHEMA_VERSION = 1
SPLITS = ("train", "val", "test")
MODALITIES = ("rgb", "depth", "seg")
#: a depth camera's measurement (hupbench.core.depth_sensor), stored beside the clean depth when the dataset has one:
#: uint16 in the depth's unit, 0 = no depth measured; the manifest's "depth_sensor" names the preset and its parameters
SENSOR_DEPTH = "sensor_depth"
STORED_MODALITIES = MODALITIES + (SENSOR_DEPTH,)
RGB_FORMATS = ("jpg", "png")
#: what a dataset's evaluation splits hold out (manifest ``protocol.track``): whole grasps (HUP-3D's
#: protocol), views of the sphere, or whole grasps and their subjects in the clinic's world (a hand per
#: grasp, a patient under the probe, a room behind, cameras where a sonographer's head can be)
UNSEEN_GRASPS, UNSEEN_VIEWS, CLINIC = "unseen_grasps", "unseen_views", "clinic"
TRACKS = (UNSEEN_GRASPS, UNSEEN_VIEWS, CLINIC)
#: the mask's labels; the room of the clinic track is background (0) with depth
SEG_LABELS = {"background": 0, "hand": 1, "arm": 2, "probe": 3}
#: the clinic track's labels: the patient's body is 4
CLINIC_SEG_LABELS = {**SEG_LABELS, "patient": 4}
DEPTH_SCALE_M = 1e-4  # uint16 depth unit: 0.1 mm, up to 6.55 m
MANIFEST = "manifest.json"
ANNOTATIONS = "annotations.npz"

#: annotations.npz: array name -> (dtype, shape of one row); N rows, one per frame
ANNOTATION_FIELDS: dict[str, tuple[type, tuple[int, ...]]] = {
    "frame_id": (np.int64, ()),
    "keypoints_3d_cam": (np.float32, (kp.NUM_KEYPOINTS, 3)),
    "keypoints_2d": (np.float32, (kp.NUM_KEYPOINTS, 2)),
    "visible": (np.bool_, (kp.NUM_KEYPOINTS,)),
    "K": (np.float64, (3, 3)),
    "T_cam_world": (np.float64, (4, 4)),
    "grasp_id": (np.int64, ()),
    "grasp_index": (np.int64, ()),
    "view_id": (np.int64, ()),
    "theta": (np.float64, ()),
    "phi": (np.float64, ()),
    "z_ego": (np.float64, ()),
    "background_id": (np.int64, ()),
    "glove_id": (np.int64, ()),
    "hand_pose": (np.float64, (48,)),
    "hand_trans": (np.float64, (3,)),
    "light_position_cam": (np.float64, (3,)),
    "light_color": (np.float64, (3,)),
    "light_energy_w": (np.float64, ()),
}
ANNOTATION_DTYPES = {name: dtype for name, (dtype, _) in ANNOTATION_FIELDS.items()}
#: what the clinic track's annotations hold beyond ANNOTATION_FIELDS: the subject's hand as measured on the
#: rendered hand (length wrist to middle fingertip, metacarpal breadth; mm) and sex (0 woman, 1 man), the skin
#: tone drawn for the frame, the head's roll about the optical axis (degrees) and where keypoint 9 was aimed
#: (pixels). ``theta`` and ``phi`` hold the camera's polar angle from the room's vertical and its azimuth,
#: ``z_ego`` its distance to keypoint 9 (metres), ``view_id`` the camera's index among its grasp's
CLINIC_ANNOTATION_FIELDS: dict[str, tuple[type, tuple[int, ...]]] = {
    "hand_length_mm": (np.float64, ()),
    "hand_breadth_mm": (np.float64, ()),
    "subject_sex": (np.int64, ()),
    "skin_tone_id": (np.int64, ()),
    "roll_deg": (np.float64, ()),
    "aim_px": (np.float64, (2,)),
}


#: what a dataset of clips (a clinic dataset whose manifest has a "sequence" record: ``hupbench generate
#: +track=clinic_sequences``) holds beyond the clinic track's: the clip (numbered across the dataset, in its
#: grasp's order), the frame's place in it and its time from the clip's start (seconds), and the patient's body
#: frame in the world (probe) frame, which moves as the probe scans. On these frames ``theta``, ``phi``,
#: ``z_ego``, ``roll_deg`` and ``aim_px`` are measured on the frame's camera (``roll_deg``: the room's vertical's
#: angle in the image), ``view_id`` is the head camera the clip started at
SEQUENCE_ANNOTATION_FIELDS: dict[str, tuple[type, tuple[int, ...]]] = {
    "clip_id": (np.int64, ()),
    "frame_in_clip": (np.int64, ()),
    "time_s": (np.float64, ()),
    "T_world_body": (np.float64, (4, 4)),
}
#: the manifest's record of a dataset of clips
SEQUENCE = "sequence"


def track_of(manifest: dict) -> str:
    """A manifest's track (``protocol.track``; datasets that predate the record are the paper protocol's)."""
    protocol = manifest.get("protocol")
    track = protocol.get("track", UNSEEN_GRASPS) if isinstance(protocol, dict) else UNSEEN_GRASPS
    return track if track in TRACKS else UNSEEN_GRASPS


def is_sequence(manifest: dict) -> bool:
    """Whether a manifest's dataset is made of clips (it has a "sequence" record)."""
    return isinstance(manifest.get(SEQUENCE), dict)


def annotation_fields(track: str, sequence: bool = False) -> dict[str, tuple[type, tuple[int, ...]]]:
    """The annotation arrays of a track's datasets, of clips when ``sequence``: name -> (dtype, row shape)."""
    if track != CLINIC:
        return dict(ANNOTATION_FIELDS)
    return {**ANNOTATION_FIELDS, **CLINIC_ANNOTATION_FIELDS, **(SEQUENCE_ANNOTATION_FIELDS if sequence else {})}


def seg_labels(track: str) -> dict[str, int]:
    """The mask's labels of a track's datasets."""
    return dict(CLINIC_SEG_LABELS) if track == CLINIC else dict(SEG_LABELS)


#: the classes a segmenting model predicts per pixel (class i is ``SEGMENT_CLASSES[i]``): what the fits need to tell
#: apart; the arm, the patient and the room are all "other"
SEGMENT_CLASSES = ("other", "hand", "probe")


def segment_classes(seg: np.ndarray, labels: dict[str, int]) -> np.ndarray:
    """A stored seg map (any shape, uint8, ``labels`` a manifest's ``seg_labels``) as ``SEGMENT_CLASSES`` indices,
    uint8: 1 the hand, 2 the probe, 0 everything else."""
    classes = np.zeros(np.shape(seg), dtype=np.uint8)
    for index, name in enumerate(SEGMENT_CLASSES[1:], start=1):
        classes[np.asarray(seg) == labels[name]] = index
    return classes
#: arrays whose values must be finite
FINITE_FIELDS = ("keypoints_3d_cam", "keypoints_2d", "K", "T_cam_world", "theta", "phi", "z_ego", "time_s",
                 "T_world_body")


class DamagedFileError(BadValueError):
    """A dataset file cannot be read at all (not an archive, truncated, bad CRC): regenerate it."""


def frame_path(root: str | Path, split: str, modality: str, frame_id: int, rgb_format: str = "jpg") -> Path:
    """``root/<split>/<modality>/<frame_id:06d>.<ext>``: rgb takes ``rgb_format``, depth and seg PNG."""
    ext = rgb_format if modality == "rgb" else "png"
    return Path(root) / split / modality / f"{int(frame_id):06d}.{ext}"


def annotations_path(root: str | Path, split: str) -> Path:
    return Path(root) / split / ANNOTATIONS


def _fail(path: Path, what: str) -> BadValueError:
    return BadValueError(f"{path}: {what}")


def read_manifest(root: str | Path, split: str | None = None, needs: str = "this reader expects") -> dict:
    """Read a finished dataset's ``manifest.json`` and check every field a reader relies on.

    Checks: valid JSON object; schema_version; counts per split (ints >= 0) adding up to the
    layout's frames; keypoint_names equal to :mod:`hupbench.core.keypoints`' 29 names in order;
    image_size; K (3, 3) finite with positive focal lengths; modalities; rgb_format; depth_scale_m.

    Args:
        root: dataset folder.
        split: when given, it must be a split of the dataset with at least one frame.
        needs: how the keypoint error names the consumer, e.g. "the models are built for".

    Returns:
        The manifest dict.

    Raises:
        FileNotFoundError: no folder, or no manifest (an unfinished dataset).
        ValueError: the manifest is not valid JSON or a field is missing or wrong (the message
            names the file and the field).
    """
    root = Path(root)
    if not root.exists():
        raise MissingFileError(f"dataset {root} does not exist")
    if not root.is_dir():
        raise BadValueError(f"dataset {root} is a file; a dataset is a folder holding {MANIFEST}")
    path = root / MANIFEST
    if not path.is_file():
        raise MissingFileError(f"{root} has no {MANIFEST}: not a finished hupbench dataset "
                                "(make one with `hupbench generate`, or finish it by running the same command again)")
    try:
        manifest = json.loads(path.read_text())
    except UnicodeDecodeError as exc:
        raise _fail(path, f"not a text file ({exc.reason})") from exc
    except json.JSONDecodeError as exc:
        raise _fail(path, f"not valid JSON ({exc.msg} at line {exc.lineno}, column {exc.colno})") from exc
    if not isinstance(manifest, dict):
        raise _fail(path, f"expected a JSON object, got {type(manifest).__name__}")
    check_manifest(manifest, path, needs)
    if split is not None:
        counts = manifest["counts"]
        if split not in SPLITS:
            raise BadValueError(f"split must be one of {list(SPLITS)}, got {split!r}")
        if counts.get(split, 0) == 0:
            raise BadValueError(f"split {split!r} of {root} is empty (counts: {counts})")
    return manifest


def check_manifest(manifest: dict, path: Path, needs: str = "this reader expects") -> None:
    """Raise ValueError naming ``path`` and the field for any field of ``manifest`` that is wrong."""
    missing = [k for k in ("schema_version", "counts", "keypoint_names", "image_size", "K", "modalities",
                           "rgb_format", "depth_scale_m", "layout") if k not in manifest]
    if missing:
        raise _fail(path, f"lacks {', '.join(missing)}")
    if manifest["schema_version"] != SCHEMA_VERSION:
        raise _fail(path, f"schema_version is {manifest['schema_version']!r}; this hupbench reads {SCHEMA_VERSION}")
    if manifest["keypoint_names"] != list(kp.KEYPOINT_NAMES):
        raise _fail(path, _names_problem(manifest["keypoint_names"], needs))
    counts = manifest["counts"]
    if not isinstance(counts, dict) or set(counts) - set(SPLITS) or \
            any(not is_whole(v) or v < 0 for v in counts.values()):
        raise _fail(path, f"counts must map {list(SPLITS)} to frame counts >= 0, got {counts!r}")
    size = manifest["image_size"]
    if not (isinstance(size, list) and len(size) == 2 and all(is_whole(v) and v > 0 for v in size)):
        raise _fail(path, f"image_size must be [width, height] in pixels, got {size!r}")
    try:
        K = np.asarray(manifest["K"], dtype=np.float64)
    except (TypeError, ValueError):
        K = np.zeros(0)
    if K.shape != (3, 3) or not np.isfinite(K).all() or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise _fail(path, f"K must be a finite 3 x 3 matrix with fx, fy > 0, got {manifest['K']!r}")
    modalities = manifest["modalities"]
    if not isinstance(modalities, list) or not modalities or any(m not in STORED_MODALITIES for m in modalities):
        raise _fail(path, f"modalities must be a non-empty list from {list(STORED_MODALITIES)}, got {modalities!r}")
    if (SENSOR_DEPTH in modalities) != isinstance(manifest.get("depth_sensor"), dict):
        raise _fail(path, "modalities holds sensor_depth exactly when depth_sensor names the sensor's preset, got "
                    f"{modalities!r} and depth_sensor {manifest.get('depth_sensor')!r}")
    if manifest["rgb_format"] not in RGB_FORMATS:
        raise _fail(path, f"rgb_format must be one of {list(RGB_FORMATS)}, got {manifest['rgb_format']!r}")
    scale = manifest["depth_scale_m"]
    if not (is_number(scale) and scale > 0):
        raise _fail(path, f"depth_scale_m must be a positive number, got {scale!r}")
    shape = (manifest["layout"] or {}).get("shape") if isinstance(manifest["layout"], dict) else None
    if not (isinstance(shape, list) and len(shape) == 5 and all(is_whole(v) and v > 0 for v in shape)):
        raise _fail(path, f"layout.shape must be 5 positive ints (grasp, z_ego, background, glove, view), "
                          f"got {shape!r}")
    if sum(counts.values()) != math.prod(shape):
        raise _fail(path, f"counts {counts} add up to {sum(counts.values())} frames but layout.shape {shape} "
                          f"holds {math.prod(shape)}")


def read_annotations(root: str | Path, split: str, keys: Iterable[str] | None = None,
                     manifest: dict | None = None) -> dict[str, np.ndarray]:
    """Read and check ``<split>/annotations.npz``.

    Every returned array is read in full (the zip's CRC is checked on the way), has the dtype and
    row shape of :data:`ANNOTATION_FIELDS` and as many rows as the manifest counts for the split;
    frame ids are unique and ascending and the geometric fields finite.

    Args:
        root: dataset folder.
        split: "train", "val" or "test".
        keys: the arrays to return (default: all of the track's :func:`annotation_fields`; "frame_id" is
            always read and checked).
        manifest: the dataset's manifest (read with :func:`read_manifest` when None).

    Returns:
        {name: array} with N rows each.

    Raises:
        FileNotFoundError: the file is missing. DamagedFileError (a ValueError): it cannot be read
        (not a zip, truncated, bad CRC). ValueError: an array is missing or has another dtype, shape
        or row count (the message names the file and the array).
    """
    root = Path(root)
    if manifest is None:
        manifest = read_manifest(root)
    # the split and the keys come from code (a user's split went through read_manifest)
    assert split in SPLITS, split
    fields = annotation_fields(track_of(manifest), is_sequence(manifest))
    keys = list(fields) if keys is None else list(dict.fromkeys(["frame_id", *keys]))
    assert set(keys) <= set(fields), keys
    path = annotations_path(root, split)
    if not path.is_file():
        raise MissingFileError(f"{path} is missing (the manifest counts {manifest['counts'].get(split, 0)} "
                                f"{split} frames)")
    arrays = {}
    if not zipfile.is_zipfile(path):
        size = path.stat().st_size
        what = "empty" if size == 0 else f"{size} bytes, no zip directory"
        raise DamagedFileError(f"{path}: damaged, not an npz archive ({what}); regenerate the dataset")
    try:
        with np.load(path, allow_pickle=False) as data:
            absent = [k for k in keys if k not in data.files]
            if absent:
                raise _fail(path, f"lacks the arrays {absent}")
            for key in keys:
                arrays[key] = data[key]
    except (ValueError, zipfile.BadZipFile, EOFError, KeyError, OSError, zipfile.LargeZipFile) as exc:
        if isinstance(exc, FileNotFoundError) or str(exc).startswith(str(path)):  # gone meanwhile; our own refusal
            raise
        raise DamagedFileError(f"{path}: damaged or not an annotations file ({type(exc).__name__}: {exc}); "
                               "regenerate the dataset") from exc
    for key in keys:
        problem = _array_problem(key, fields[key], arrays[key], manifest["counts"].get(split, 0), split)
        if problem is not None:
            raise _fail(path, problem)
    ids = arrays["frame_id"]
    if len(ids) > 1 and not (np.diff(ids) > 0).all():
        raise _fail(path, "frame_id is not strictly ascending (repeated or shuffled rows)")
    return arrays


def _names_problem(names, needs: str) -> str:
    """How a manifest's ``keypoint_names`` differ from :mod:`hupbench.core.keypoints`' names in order: their
    count (``needs`` names who expects the 29), or the first name out of place."""
    if not isinstance(names, list) or len(names) != kp.NUM_KEYPOINTS:
        n = len(names) if isinstance(names, list) else type(names).__name__
        return (f"keypoint_names: the dataset has {n} keypoints; {needs} {kp.NUM_KEYPOINTS} "
                f"({kp.NUM_HAND} hand + {kp.NUM_CORNERS} probe corners)")
    i = next(i for i, (a, b) in enumerate(zip(names, kp.KEYPOINT_NAMES)) if a != b)
    return f"keypoint_names[{i}] is {names[i]!r}, expected {kp.KEYPOINT_NAMES[i]!r} (hupbench.core.keypoints' order)"


def _array_problem(key: str, field: tuple, array: np.ndarray, rows: int, split: str) -> str | None:
    """What annotation array ``key`` breaks of the contract, in words (None: nothing): its dtype and row shape
    (``field``, from :func:`annotation_fields`), its ``rows`` (the manifest's count for ``split``), finite values
    (:data:`FINITE_FIELDS`), and for K, positive focal lengths (a K of zeros projects every point to the
    origin)."""
    dtype, row_shape = field
    if array.dtype != np.dtype(dtype):
        return f"{key} is {array.dtype}, expected {np.dtype(dtype)}"
    if array.shape != (rows, *row_shape):
        return (f"{key} has shape {array.shape}, expected {(rows, *row_shape)} ({rows} rows as the manifest counts "
                f"for {split!r})")
    if key in FINITE_FIELDS and not np.isfinite(array).all():
        return f"{key} holds NaN or inf in {int((~np.isfinite(array.reshape(rows, -1))).any(axis=1).sum())} rows"
    bad = np.flatnonzero((array[:, 0, 0] <= 0) | (array[:, 1, 1] <= 0)) if key == "K" else []
    if len(bad):
        return (f"K has fx or fy <= 0 in {len(bad)} rows (the first: row {bad[0]}); each frame's K must be a camera "
                "matrix with focal lengths > 0 (pixels)")
    return None
