"""The results JSON: one file per evaluated model, schema version 5; ``hupbench eval`` writes it,
``hupbench leaderboard`` reads it.

The schema is checked exactly: every key present (``null`` where unknown), no unknown key, exact types,
finite numbers within what their unit allows (:data:`LIMITS`; a measured row's: :data:`MEASURED_LIMITS`). A
``"reported"`` row (quoted from a paper) needs only ``metrics.mpjpe_mm.all`` and a ``source``. A measured row's
``all`` is the keypoint-weighted mean of its ``hand`` and ``probe`` (:func:`keypoint_weighted_all_mm`); a reported
row's lies between them, as every mean over the 29 keypoints does. The dataset is named by ``name``,
``manifest_sha256`` and ``grasps_sha256`` (the sha256 of its manifest.json and of its grasps.npz), never by a path of
the machine that evaluated it, and, for a model that reads depth, by the ``depth_sensor`` it read. The ``intervals``
block holds the 95 % bootstrap intervals over the test grasps of the MPJPE and of the split floor
(:mod:`hupbench.evaluation.intervals`). Versions 1 to 4 load upgraded to 5 (docs/metrics.md), with no intervals; only 5
is written. Metrics of ``_OPTIONAL_METRIC_KEYS`` (the middle-MCP-relative hand MPJPE, the probe's BOP pose scores and
the split floor's) may be absent: readers take them as unknown. The file is read strictly (:func:`parse_json`): an
object naming a key twice is refused, where other JSON readers keep one of the two values without a word.

Convention: errors in millimetres, latencies in milliseconds per image, times in seconds, FLOPs per image
counted as 2 x multiply-adds, times of day in UTC as ``YYYY-MM-DDTHH:MM:SSZ``.
"""

from __future__ import annotations

import contextvars
import copy
import math
import re
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from hupbench.core.contract import TRACKS
from hupbench.core.depth_sensor import NONE, PRESETS
from hupbench.core.errors import BadValueError
from hupbench.provenance import RUN_NAME_PATTERN
from hupbench.core.input_checks import is_number, is_whole
from hupbench.core.io import parse_json, read_bytes, write_json
from hupbench.core.keypoints import NUM_CORNERS, NUM_HAND
from hupbench.datagen.dataset.floors import FLOOR_KINDS, NEAREST_TRAIN_FRAME, NEAREST_TRAIN_GRASP, NEAREST_TRAIN_VIEW

SCHEMA_VERSION = 5
#: versions :func:`load_results` reads (older ones are upgraded on load)
READABLE_VERSIONS = (1, 2, 3, 4, 5)
#: the version that added the track, the split's floor and the per-grasp breakdown
GRASP_FIELDS_VERSION = 3
#: the version that named the dataset by its grasps' sha256 instead of a path
DATASET_SHA_VERSION = 4
#: the version that added the intervals over test grasps
INTERVALS_VERSION = 5
KINDS = ("measured", "reported")
FORMATS = ("pytorch", "onnx")
SPLITS = ("train", "val", "test")
BREAKDOWNS = ("latitude", "z_ego", "background", "grasp", "theta_vol", "hand_visible")
_BREAKDOWNS_V2 = BREAKDOWNS[:3]
#: how a split's floor is made (datagen/dataset/floors.py), in plain words: each evaluated grasp replaced by its
#: nearest training grasp, or each evaluated frame by the nearest training view of the same grasp
FLOOR_NAMES = {
    NEAREST_TRAIN_GRASP: ("nearest training grasp under the true camera: a model that only recognises training "
                            "grasps cannot do better than this"),
    NEAREST_TRAIN_VIEW: ("nearest training view of the same grasp and distance under the true camera: a model "
                           "that only recalls training views cannot do better than this"),
    NEAREST_TRAIN_FRAME: ("nearest training frame of any grasp and view, by its camera-frame keypoints: a model "
                          "that only recalls training images' labels cannot do better than this"),
}

_TOP_KEYS_V2 = ("schema_version", "kind", "run_name", "model", "dataset", "metrics", "breakdowns",
                "latency_ms_per_image", "device", "training", "git_commit", "created_utc", "source")
_TOP_KEYS_V3 = _TOP_KEYS_V2 + ("track", "split_floor")
_TOP_KEYS = _TOP_KEYS_V3 + ("intervals",)
_MODEL_KEYS = ("name", "label", "config", "parameters", "flops", "input_size", "format")
_DATASET_KEYS_V2 = ("path", "manifest_sha256", "split", "frames", "name")
_DATASET_KEYS_V3 = _DATASET_KEYS_V2 + ("grasp_theta_vol_deg",)
_DATASET_KEYS = ("name", "manifest_sha256", "grasps_sha256", "split", "frames", "grasp_theta_vol_deg")
_METRIC_KEYS_V1 = ("mpjpe_mm", "root_relative_hand_mpjpe_mm", "pa_mpjpe_hand_mm", "pck_auc_0_50mm", "pixel_error_px")
_METRIC_KEYS = _METRIC_KEYS_V1 + ("probe_symmetric_mpjpe_mm", "spread_ratio")
#: metrics added within version 3: eval writes them, files written before lack them (readers: ``.get``)
_OPTIONAL_METRIC_KEYS = ("middle_mcp_relative_hand_mpjpe_mm", "probe_pose", "split_floor_probe_pose")
#: a probe pose block (``metrics.bop_scores`` and the symmetry group's name and the mesh's vertex count)
_POSE_MM_KEYS = ("add_mm", "add_s_mm", "mssd_mm")
_POSE_FRACTION_KEYS = ("add_accuracy", "add_s_accuracy", "ar_mssd", "ar_mspd")
_POSE_KEYS = _POSE_MM_KEYS + ("mspd_px",) + _POSE_FRACTION_KEYS + ("diameter_mm", "image_width_px", "symmetry",
                                                                   "model_points")
_SPREAD_KEYS = ("x", "y", "z")
# the symmetric probe error is a minimum that includes the identity: it may exceed the plain one only by rounding
_SYMMETRIC_SLACK_MM = 1e-6
_MPJPE_KEYS = ("all", "hand", "probe", "all_averaging")
_LATENCY_RUNTIMES = ("pytorch", "onnxruntime")
_LATENCY_BATCHES = ("batch1", "batch32")
_TRAINING_KEYS = ("wall_s", "hardware", "samples_seen", "epochs", "command", "log")
_BUCKET_KEYS = ("frames", "mpjpe_mm")
_BUCKET_MPJPE_KEYS = ("all", "hand", "probe")
_FLOOR_KEYS = ("floor_kind", "floor_mm", "per_grasp")
_GRASP_FLOOR_KEYS = ("floor_mm", "frames")
#: a floor's further figures: one per floor kind (mm triplets, null where undefined) and the mean training grasp's;
#: per grasp also the id of what replaced it
_FLOOR_FIGURES = tuple(f"{kind}_mm" for kind in FLOOR_KINDS) + ("train_mean_mm",)
_GRASP_FLOOR_IDS = tuple(f"{kind}_id" for kind in FLOOR_KINDS)
_INTERVAL_KEYS = ("method", "confidence", "resamples", "seed", "grasps", "mpjpe_mm", "split_floor_mm")
#: a grasp id as a key (JSON keys are strings): the decimal form of an integer
GRASP_ID_PATTERN = re.compile(r"^-?(0|[1-9][0-9]*)$")
SHA256_PATTERN = re.compile(r"^[0-9a-f]{64}$")
UTC_FORMAT = "%Y-%m-%dT%H:%M:%SZ"
#: per unit, the largest hand-typed number (a reported row's; beyond: a unit slip) and eval's (a diverged fit reaches
#: metres, millions of px: docs/clinic.md; beyond 1000 km and its px at the fits' 1 mm projection clamp: damage)
LIMITS = {"mm": 1e4, "ms": 1e6, "px": 1e5}
MEASURED_LIMITS = {"mm": 1e9, "ms": 1e6, "px": 1e12}
_LIMITS = contextvars.ContextVar("results_limits", default=LIMITS)  # the row's being validated
#: how far a measured row's ``all`` may lie from the keypoint-weighted mean of its ``hand`` and ``probe``: the
#: two-decimal rounding of hand-typed numbers
WEIGHTED_MEAN_TOLERANCE_MM = 0.01


class _Root(str):
    """The start of a field's path when the block is not read from the results (e.g. the manifest it is copied
    from), so that an error names the file the user has to fix."""


def _path(parts: tuple) -> str:
    if parts and isinstance(parts[0], _Root):
        return str(parts[0]) + "".join(f"[{p!r}]" for p in parts[1:])
    return "results" + "".join(f"[{p!r}]" for p in parts)


def _show(value) -> str:
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


def _fail(parts: tuple, expected: str, value) -> None:
    raise BadValueError(f"{_path(parts)} must be {expected}, got {_show(value)}")


def _keys(d, parts: tuple, keys: tuple, optional: tuple = ()) -> None:
    """``d`` is a dict with exactly ``keys``, and any of ``optional`` (with no ``keys``: a subset of ``optional``)."""
    if not isinstance(d, dict):
        _fail(parts, "a dict", d)
    missing = [k for k in keys if k not in d]
    if not keys:
        expected = f"expected a subset of {list(optional)}"
    else:
        expected = f"expected keys {list(keys)}" + (f" (and optionally {list(optional)})" if optional else "")
    if missing:
        raise BadValueError(f"{_path(parts)} is missing key(s) {missing}; {expected}")
    unknown = sorted(str(k) for k in d if k not in keys and k not in optional)
    if unknown:
        raise BadValueError(f"{_path(parts)} has unknown key(s) {unknown}; {expected}")


def _check(d: dict, parts: tuple, ok: Callable[[Any], bool], expected: str, nullable: bool) -> None:
    """``d[parts[-1]]`` passes ``ok`` (or is None where ``nullable``), else an error saying ``expected``."""
    value = d[parts[-1]]
    if not (value is None and nullable) and not ok(value):
        _fail(parts, expected + (" or null" if nullable else ""), value)


def _number(d: dict, parts: tuple, *, nullable: bool, high: float = math.inf, unit: str | None = None) -> None:
    """A finite number in [0, high], at most the row's limit of ``unit`` (:data:`LIMITS`, :data:`MEASURED_LIMITS`)."""
    bounds = " >= 0" if high == math.inf else f" in [0, {high:g}]"
    _check(d, parts, lambda v: is_number(v) and 0.0 <= v <= high, f"a finite number{bounds}",
           nullable)
    value = d[parts[-1]]
    if unit is not None and value is not None and value > _LIMITS.get()[unit]:
        _fail(parts, f"at most {_LIMITS.get()[unit]:g} {unit} (a larger value is a unit slip or a damaged file)", value)


def _integer(d: dict, parts: tuple, *, nullable: bool, low: int = 0) -> None:
    _check(d, parts, lambda v: is_whole(v) and v >= low, f"an integer >= {low}", nullable)


def _string(d: dict, parts: tuple, *, nullable: bool) -> None:
    _check(d, parts, lambda v: isinstance(v, str) and bool(v.strip()), "a non-empty string", nullable)


def _sha256(d: dict, parts: tuple) -> None:
    _check(d, parts, lambda v: isinstance(v, str) and bool(SHA256_PATTERN.match(v)),
           "a sha256: 64 lowercase hexadecimal digits", True)


def _is_utc_time(v) -> bool:
    try:
        time.strptime(v, UTC_FORMAT)
    except (TypeError, ValueError):
        return False
    return True


def _choice(d: dict, parts: tuple, choices: tuple, *, nullable: bool) -> None:
    _check(d, parts, lambda v: isinstance(v, str) and v in choices, "one of " + ", ".join(repr(c) for c in choices),
           nullable)


def _validate_mpjpe_triplet(m: dict, parts: tuple, keys: tuple, *, all_nullable: bool) -> None:
    _keys(m, parts, keys)
    _number(m, parts + ("all",), nullable=all_nullable, unit="mm")
    _number(m, parts + ("hand",), nullable=True, unit="mm")
    _number(m, parts + ("probe",), nullable=True, unit="mm")


def keypoint_weighted_all_mm(mpjpe: dict) -> float | None:
    """(21 x hand + 8 x probe) / 29 of an ``mpjpe_mm`` block: the mean over all 29 keypoints that its hand and
    probe MPJPE imply (mm), or None where either is unknown."""
    if mpjpe["hand"] is None or mpjpe["probe"] is None:
        return None
    return (NUM_HAND * mpjpe["hand"] + NUM_CORNERS * mpjpe["probe"]) / (NUM_HAND + NUM_CORNERS)


def _validate_all_mpjpe(d: dict) -> None:
    """A measured row's ``all`` is the keypoint-weighted mean of its hand and probe; any row's lies between them."""
    mpjpe = d["metrics"]["mpjpe_mm"]
    weighted = keypoint_weighted_all_mm(mpjpe)
    if weighted is None:
        return
    parts = ("metrics", "mpjpe_mm", "all")
    low, high = sorted((mpjpe["hand"], mpjpe["probe"]))
    if d["kind"] == "measured" and abs(mpjpe["all"] - weighted) > WEIGHTED_MEAN_TOLERANCE_MM:
        _fail(parts, f"the keypoint-weighted mean of hand and probe, ({NUM_HAND} x {mpjpe['hand']:g} + {NUM_CORNERS} x "
                     f"{mpjpe['probe']:g}) / {NUM_HAND + NUM_CORNERS} = {weighted:.2f} mm (within "
                     f"{WEIGHTED_MEAN_TOLERANCE_MM:g} mm), in a measured row", mpjpe["all"])
    if not low - WEIGHTED_MEAN_TOLERANCE_MM <= mpjpe["all"] <= high + WEIGHTED_MEAN_TOLERANCE_MM:
        _fail(parts, f"between the hand and probe MPJPE ({low:g} and {high:g} mm), as every mean over the 29 "
                     "keypoints is", mpjpe["all"])


def _validate_metrics(metrics, version: int) -> None:
    """``results['metrics']``: MPJPE by part, the other errors, and (version 2) the probe-symmetric MPJPE
    and the spread ratios."""
    if version >= GRASP_FIELDS_VERSION:
        _keys(metrics, ("metrics",), _METRIC_KEYS, _OPTIONAL_METRIC_KEYS)
    else:
        _keys(metrics, ("metrics",), _METRIC_KEYS if version >= 2 else _METRIC_KEYS_V1)
    _validate_mpjpe_triplet(metrics["mpjpe_mm"], ("metrics", "mpjpe_mm"), _MPJPE_KEYS, all_nullable=False)
    _string(metrics["mpjpe_mm"], ("metrics", "mpjpe_mm", "all_averaging"), nullable=False)
    _number(metrics, ("metrics", "root_relative_hand_mpjpe_mm"), nullable=True, unit="mm")
    if "middle_mcp_relative_hand_mpjpe_mm" in metrics:
        _number(metrics, ("metrics", "middle_mcp_relative_hand_mpjpe_mm"), nullable=True, unit="mm")
    for key in ("probe_pose", "split_floor_probe_pose"):
        if metrics.get(key) is not None:
            _validate_probe_pose(metrics[key], ("metrics", key))
    _number(metrics, ("metrics", "pa_mpjpe_hand_mm"), nullable=True, unit="mm")
    _number(metrics, ("metrics", "pck_auc_0_50mm"), nullable=True, high=1.0)
    _number(metrics, ("metrics", "pixel_error_px"), nullable=True, unit="px")
    if version >= 2:
        _number(metrics, ("metrics", "probe_symmetric_mpjpe_mm"), nullable=True, unit="mm")
        symmetric, probe = metrics["probe_symmetric_mpjpe_mm"], metrics["mpjpe_mm"]["probe"]
        if symmetric is not None and probe is not None and symmetric > probe + _SYMMETRIC_SLACK_MM:
            _fail(("metrics", "probe_symmetric_mpjpe_mm"),
                  f"at most the plain probe MPJPE ({probe!r}: a minimum over a group that holds the identity)",
                  symmetric)
        _keys(metrics["spread_ratio"], ("metrics", "spread_ratio"), _SPREAD_KEYS)
        for axis in _SPREAD_KEYS:
            _number(metrics["spread_ratio"], ("metrics", "spread_ratio", axis), nullable=True)


def _validate_probe_pose(pose, parts: tuple) -> None:
    """A probe pose block: mean ADD, ADD-S (at most ADD), MSSD (mm) and MSPD (px, null when undefined), the
    fractions, the diameter (mm > 0), the image width and vertex count (integers >= 1) and the symmetry
    group's name."""
    _keys(pose, parts, _POSE_KEYS)
    for key in _POSE_MM_KEYS:
        _number(pose, parts + (key,), nullable=False, unit="mm")
    _number(pose, parts + ("mspd_px",), nullable=True, unit="px")
    for key in _POSE_FRACTION_KEYS:
        _number(pose, parts + (key,), nullable=False, high=1.0)
    _check(pose, parts + ("diameter_mm",), lambda v: is_number(v) and v > 0.0, "a finite number > 0", False)
    _integer(pose, parts + ("image_width_px",), nullable=False, low=1)
    _integer(pose, parts + ("model_points",), nullable=False, low=1)
    _string(pose, parts + ("symmetry",), nullable=False)
    if pose["add_s_mm"] > pose["add_mm"] + _SYMMETRIC_SLACK_MM:  # the nearest point is never further than its own
        _fail(parts + ("add_s_mm",), f"at most add_mm ({pose['add_mm']!r})", pose["add_s_mm"])


def _validate_breakdowns(breakdowns, version: int) -> None:
    """``results['breakdowns']``: axis -> bucket label -> {"frames", "mpjpe_mm"}; "grasp" buckets are grasp ids."""
    if not isinstance(breakdowns, dict):
        _fail(("breakdowns",), "a dict (empty when none were computed)", breakdowns)
    _keys(breakdowns, ("breakdowns",), (), BREAKDOWNS if version >= GRASP_FIELDS_VERSION else _BREAKDOWNS_V2)
    for label in breakdowns.get("grasp", {}) if isinstance(breakdowns.get("grasp"), dict) else ():
        if not isinstance(label, str) or not GRASP_ID_PATTERN.match(label):
            _fail(("breakdowns", "grasp"), "keyed by grasp ids written as decimal integers", label)
    for axis, buckets in breakdowns.items():
        if not isinstance(buckets, dict):
            _fail(("breakdowns", axis), "a dict of bucket label -> {'frames', 'mpjpe_mm'}", buckets)
        for label, bucket in buckets.items():
            if not isinstance(label, str) or not label:
                _fail(("breakdowns", axis), "keyed by non-empty bucket labels", label)
            parts = ("breakdowns", axis, label)
            _keys(bucket, parts, _BUCKET_KEYS)
            _integer(bucket, parts + ("frames",), nullable=False)
            _validate_mpjpe_triplet(bucket["mpjpe_mm"], parts + ("mpjpe_mm",), _BUCKET_MPJPE_KEYS,
                                    all_nullable=True)


def _floor_mm(d: dict, parts: tuple, *, nullable: bool) -> None:
    """``d[parts[-1]]`` is {"hand", "probe", "all"} finite mm >= 0 (or null where ``nullable``)."""
    if d[parts[-1]] is None and nullable:
        return
    _keys(d[parts[-1]], parts, _BUCKET_MPJPE_KEYS)
    for part in _BUCKET_MPJPE_KEYS:
        _number(d[parts[-1]], parts + (part,), nullable=False, unit="mm")


def validate_split_floor(floor, where: str | None = None) -> dict:
    """Check one split's floor, what a model that only recalls training labels scores on it: a split's entry
    of a manifest's ``split_floors["splits"]`` (datagen/dataset/floors.py) as eval copies it into
    ``results['split_floor']``::

        {"floor_kind": one of FLOOR_KINDS, e.g. "nearest_train_grasp",
         "floor_mm": T,                  # the split's headline floor, the one floor_kind names
         "per_grasp": {"<grasp id>": {"floor_mm": T, "frames": int | null, ...}},
         ...}

    and optionally, in the block and in each grasp's entry, each kind's figure ``"<kind>_mm": T | null``
    (e.g. ``"nearest_train_grasp_mm"``: each evaluated grasp replaced by the nearest training grasp) and
    ``"train_mean_mm": T | null`` (every frame predicted as the mean training grasp), and per grasp
    ``"<kind>_id": int | null`` (e.g. ``"nearest_train_grasp_id"``), where T is {"hand", "probe", "all"}: mean
    distance per keypoint in mm (the 21 hand keypoints, the 8 probe corners, all 29), seen from the true
    camera, and ``frames`` the grasp's frames in the split (the weight of its floor in the split's). ``where``
    names the block in errors (default ``results['split_floor']``). Returns ``floor``.
    """
    parts = ("split_floor",) if where is None else (_Root(where),)
    _keys(floor, parts, _FLOOR_KEYS, _FLOOR_FIGURES)
    _choice(floor, parts + ("floor_kind",), FLOOR_KINDS, nullable=False)
    _floor_mm(floor, parts + ("floor_mm",), nullable=False)
    for key in (k for k in _FLOOR_FIGURES if k in floor):
        _floor_mm(floor, parts + (key,), nullable=True)
    per_grasp = floor["per_grasp"]
    if not isinstance(per_grasp, dict):
        _fail(parts + ("per_grasp",), "a dict of grasp id -> that grasp's floors", per_grasp)
    for grasp, entry in per_grasp.items():
        if not isinstance(grasp, str) or not GRASP_ID_PATTERN.match(grasp):
            _fail(parts + ("per_grasp",), "keyed by grasp ids written as decimal integers", grasp)
        entry_parts = parts + ("per_grasp", grasp)
        _keys(entry, entry_parts, _GRASP_FLOOR_KEYS, _FLOOR_FIGURES + _GRASP_FLOOR_IDS)
        _floor_mm(entry, entry_parts + ("floor_mm",), nullable=False)
        for key in (k for k in _FLOOR_FIGURES if k in entry):
            _floor_mm(entry, entry_parts + (key,), nullable=True)
        for key in (k for k in _GRASP_FLOOR_IDS if k in entry):
            _check(entry, entry_parts + (key,), is_whole, "an integer id", True)
        _integer(entry, entry_parts + ("frames",), nullable=True)
    return floor


def validate_grasp_theta_vol(theta_vol, where: str | None = None) -> dict | None:
    """Check and return a {decimal grasp id: [x, y, z] degrees or null} map of probe orientations Theta_Vol,
    or null; ``where`` names it in errors (default ``results['dataset']['grasp_theta_vol_deg']``)."""
    parts = ("dataset", "grasp_theta_vol_deg") if where is None else (_Root(where),)
    if theta_vol is None:
        return None
    if not isinstance(theta_vol, dict):
        _fail(parts, "a dict of grasp id -> [x, y, z] degrees or null, or null", theta_vol)
    for grasp, angles in theta_vol.items():
        if not isinstance(grasp, str) or not GRASP_ID_PATTERN.match(grasp):
            _fail(parts, "keyed by grasp ids written as decimal integers", grasp)
        if angles is not None and not (isinstance(angles, list) and len(angles) == 3
                                       and all(is_number(a) for a in angles)):
            _fail(parts + (grasp,), "[x, y, z]: three finite numbers (degrees), or null", angles)
    return theta_vol


def _validate_grasp_fields(d: dict) -> None:
    """Version 3: the track, the split's floor and the grasps' orientations, and that they name the same grasps."""
    _choice(d, ("track",), TRACKS, nullable=True)
    if d["split_floor"] is not None:
        if d["track"] is None:
            _fail(("track",), "one of " + ", ".join(repr(t) for t in TRACKS) + " where split_floor is given", None)
        if d["dataset"]["split"] == "train":
            _fail(("split_floor",), "null for the train split (a floor compares a split with training)",
                  d["split_floor"])
        validate_split_floor(d["split_floor"])
    validate_grasp_theta_vol(d["dataset"]["grasp_theta_vol_deg"])
    grasps = d["breakdowns"].get("grasp")
    if grasps is None:
        return
    per_grasp = (d["split_floor"] or {}).get("per_grasp")
    for parts, keyed in ((("split_floor", "per_grasp"), per_grasp),
                         (("dataset", "grasp_theta_vol_deg"), d["dataset"]["grasp_theta_vol_deg"])):
        if keyed is not None and set(keyed) != set(grasps):
            _fail(parts, f"keyed by the evaluated grasps {sorted(grasps, key=int)} (results['breakdowns']['grasp'])",
                  sorted(keyed, key=int))
    for grasp, entry in (per_grasp or {}).items():
        if entry["frames"] is not None and entry["frames"] != grasps[grasp]["frames"]:
            _fail(("split_floor", "per_grasp", grasp, "frames"),
                  f"the grasp's frames in results['breakdowns']['grasp'] ({grasps[grasp]['frames']})", entry["frames"])


def _interval_triplet(block: dict, parts: tuple, *, nullable: bool) -> None:
    """``block[parts[-1]]`` is {"hand", "probe", "all"} -> [low, high], finite mm, 0 <= low <= high."""
    if block[parts[-1]] is None and nullable:
        return
    _keys(block[parts[-1]], parts, _BUCKET_MPJPE_KEYS)
    high = _LIMITS.get()["mm"]
    for part in _BUCKET_MPJPE_KEYS:
        bounds = block[parts[-1]][part]
        if not (isinstance(bounds, list) and len(bounds) == 2 and all(is_number(b) for b in bounds)
                and 0.0 <= bounds[0] <= bounds[1] <= high):
            _fail(parts + (part,), f"[low, high]: two finite numbers, 0 <= low <= high <= {high:g} mm", bounds)


def _validate_intervals(d: dict) -> None:
    """Version 5: ``results['intervals']``, null or the bootstrap intervals over the test grasps
    (:mod:`hupbench.evaluation.intervals`)::

        {"method": str, "confidence": 0.95, "resamples": int >= 1, "seed": int >= 0, "grasps": int >= 1,
         "mpjpe_mm": I, "split_floor_mm": I | null}

    where I is {"hand", "probe", "all"} -> [low, high] mm; ``grasps`` is the number of evaluated grasps (those
    of ``breakdowns['grasp']`` where recorded), ``split_floor_mm`` null where the row has no split floor."""
    block = d["intervals"]
    if block is None:
        return
    parts = ("intervals",)
    _keys(block, parts, _INTERVAL_KEYS)
    _string(block, parts + ("method",), nullable=False)
    _check(block, parts + ("confidence",), lambda v: is_number(v) and 0.0 < v < 1.0, "a number in (0, 1)", False)
    _integer(block, parts + ("resamples",), nullable=False, low=1)
    _integer(block, parts + ("seed",), nullable=False)
    _integer(block, parts + ("grasps",), nullable=False, low=1)
    _interval_triplet(block, parts + ("mpjpe_mm",), nullable=False)
    _interval_triplet(block, parts + ("split_floor_mm",), nullable=True)
    if block["split_floor_mm"] is not None and d["split_floor"] is None:
        _fail(parts + ("split_floor_mm",), "null where results['split_floor'] is null", block["split_floor_mm"])
    grasps = d["breakdowns"].get("grasp")
    if grasps is not None and block["grasps"] != len(grasps):
        _fail(parts + ("grasps",), f"the number of evaluated grasps in results['breakdowns']['grasp'] ({len(grasps)})",
              block["grasps"])


def validate_results(d: dict) -> dict:
    """Check and return a results dict against its schema version (5, or 1 to 4 for older files); an error
    names the first bad, missing or unknown field by its path, e.g.
    ``results['metrics']['mpjpe_mm']['hand'] must be a finite number >= 0 or null, got 'x'``."""
    if not isinstance(d, dict) or "schema_version" not in d:
        _keys(d, (), _TOP_KEYS)
    version = d["schema_version"]
    if not is_whole(version) or version not in READABLE_VERSIONS:
        _fail(("schema_version",), f"{SCHEMA_VERSION} (the version this hupbench writes) or one of "
                                   f"{list(READABLE_VERSIONS[:-1])} (read and upgraded)", version)
    _keys(d, (), _TOP_KEYS if version >= INTERVALS_VERSION else
          _TOP_KEYS_V3 if version >= GRASP_FIELDS_VERSION else _TOP_KEYS_V2,
          optional=("sequence",) if version >= INTERVALS_VERSION else ())
    _choice(d, ("kind",), KINDS, nullable=False)
    token = _LIMITS.set(MEASURED_LIMITS if d["kind"] == "measured" else LIMITS)
    try:
        return _validate_row(d, version)
    finally:
        _LIMITS.reset(token)


def _validate_row(d: dict, version: int) -> dict:
    run_name = d["run_name"]
    if not isinstance(run_name, str) or not RUN_NAME_PATTERN.match(run_name):
        _fail(("run_name",), f"a file stem matching {RUN_NAME_PATTERN.pattern}", run_name)
    model = d["model"]
    _keys(model, ("model",), _MODEL_KEYS)
    _string(model, ("model", "name"), nullable=False)
    _string(model, ("model", "label"), nullable=False)
    if model["config"] is not None and not isinstance(model["config"], dict):
        _fail(("model", "config"), "a dict or null", model["config"])
    _integer(model, ("model", "parameters"), nullable=True)
    _integer(model, ("model", "flops"), nullable=True)
    _integer(model, ("model", "input_size"), nullable=True, low=1)
    _choice(model, ("model", "format"), FORMATS, nullable=True)

    dataset = d["dataset"]
    _keys(dataset, ("dataset",), _DATASET_KEYS if version >= DATASET_SHA_VERSION else
          {3: _DATASET_KEYS_V3}.get(version, _DATASET_KEYS_V2), optional=("depth_sensor",))
    if "depth_sensor" in dataset:
        _choice(dataset, ("dataset", "depth_sensor"), (NONE, *PRESETS), nullable=False)
    if version < DATASET_SHA_VERSION:
        _string(dataset, ("dataset", "path"), nullable=True)
    else:
        _sha256(dataset, ("dataset", "grasps_sha256"))
    _sha256(dataset, ("dataset", "manifest_sha256"))
    _choice(dataset, ("dataset", "split"), SPLITS, nullable=False)
    _integer(dataset, ("dataset", "frames"), nullable=True)
    _string(dataset, ("dataset", "name"), nullable=False)
    _validate_metrics(d["metrics"], version)
    _validate_all_mpjpe(d)
    _validate_breakdowns(d["breakdowns"], version)

    latency = d["latency_ms_per_image"]
    _keys(latency, ("latency_ms_per_image",), _LATENCY_RUNTIMES)
    for runtime in _LATENCY_RUNTIMES:
        parts = ("latency_ms_per_image", runtime)
        _keys(latency[runtime], parts, _LATENCY_BATCHES)
        for batch in _LATENCY_BATCHES:
            _number(latency[runtime], parts + (batch,), nullable=True, unit="ms")

    _string(d, ("device",), nullable=True)

    training = d["training"]
    _keys(training, ("training",), _TRAINING_KEYS)
    _number(training, ("training", "wall_s"), nullable=True)
    _string(training, ("training", "hardware"), nullable=True)
    _integer(training, ("training", "samples_seen"), nullable=True)
    _number(training, ("training", "epochs"), nullable=True)
    _string(training, ("training", "command"), nullable=True)
    _string(training, ("training", "log"), nullable=True)
    log = training["log"]
    if log is not None and (Path(log).is_absolute() or ".." in Path(log).parts):
        _fail(("training", "log"), "a path relative to leaderboard/ inside it (e.g. 'logs/<run_name>.jsonl')", log)

    _string(d, ("git_commit",), nullable=True)
    _check(d, ("created_utc",), _is_utc_time, f"a UTC time {UTC_FORMAT!r}", True)
    _string(d, ("source",), nullable=d["kind"] != "reported")
    if version >= GRASP_FIELDS_VERSION:
        _validate_grasp_fields(d)
    if version >= INTERVALS_VERSION:
        _validate_intervals(d)
    if "sequence" in d:
        from hupbench.evaluation.sequence_metrics import sequence_block_problem

        problem = sequence_block_problem(d["sequence"])
        if problem is not None:
            raise BadValueError(f"results['sequence']{problem}")
    return d


def blank_results(kind: str, run_name: str) -> dict:
    """A fresh results dict with every field present and ``null``; it validates once ``model.name``,
    ``model.label``, ``dataset.name``, ``metrics.mpjpe_mm.all`` and ``.all_averaging`` (and ``source`` for
    a reported row) are filled."""
    assert kind in KINDS, kind
    blank = {
        "schema_version": SCHEMA_VERSION, "kind": kind, "run_name": run_name,
        "model": dict.fromkeys(_MODEL_KEYS),
        "dataset": dict.fromkeys(_DATASET_KEYS) | {"split": "test"},
        "metrics": dict.fromkeys(_METRIC_KEYS + _OPTIONAL_METRIC_KEYS) | {"mpjpe_mm": dict.fromkeys(_MPJPE_KEYS),
                                                   "spread_ratio": dict.fromkeys(_SPREAD_KEYS)},
        "breakdowns": {},
        "latency_ms_per_image": {r: dict.fromkeys(_LATENCY_BATCHES) for r in _LATENCY_RUNTIMES},
        "device": None,
        "training": dict.fromkeys(_TRAINING_KEYS),
        "git_commit": None, "created_utc": None, "source": None, "track": None, "split_floor": None,
        "intervals": None,
    }
    return copy.deepcopy(blank)


def upgrade_results(d: dict) -> dict:
    """``d`` validated, as is in version 5, else upgraded into a new dict (``d`` is left as it was): version 1
    gains ``metrics.probe_symmetric_mpjpe_mm`` and ``metrics.spread_ratio``, versions 1 and 2 ``track``,
    ``split_floor`` and ``dataset.grasp_theta_vol_deg``, versions 1 to 4 ``intervals``, all ``None`` (never
    measured); versions 1 to 3's dataset record loses its ``path`` and gains ``grasps_sha256`` = ``None``. A metric of
    ``_OPTIONAL_METRIC_KEYS`` stays absent where a file lacks it."""
    validate_results(d)
    version = d["schema_version"]
    if version == SCHEMA_VERSION:
        return d
    # new dicts where keys change, the rest shared: a copy of the whole would recurse as deep as a file nests
    out = d | {"schema_version": SCHEMA_VERSION, "metrics": dict(d["metrics"])}
    if version == 1:
        out["metrics"] |= {"probe_symmetric_mpjpe_mm": None, "spread_ratio": dict.fromkeys(_SPREAD_KEYS)}
    if version < GRASP_FIELDS_VERSION:
        out |= {"track": None, "split_floor": None}
    out["intervals"] = None
    out["dataset"] = {key: d["dataset"].get(key) for key in _DATASET_KEYS}
    return validate_results(out)


def load_results(path: str | Path) -> dict:
    """A results JSON file, validated and upgraded (:func:`upgrade_results`); errors start with its path."""
    path = Path(path)
    data = read_bytes(path, "results file")
    if not data.strip():
        raise BadValueError(f"{path}: empty file, not valid JSON (a results file is one JSON object)")
    value = parse_json(data, str(path))
    try:
        return upgrade_results(value)
    except ValueError as exc:
        raise BadValueError(f"{path}: {exc}") from exc


def write_results(path: str | Path, d: dict) -> Path:
    """Validate a results dict, then write it atomically to ``path`` (folders made) as indented JSON with
    sorted keys; returns the path."""
    validate_results(d)
    assert d["schema_version"] == SCHEMA_VERSION, "upgrade_results() first"
    return write_json(path, d)
