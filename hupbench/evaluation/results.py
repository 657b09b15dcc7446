"""The results JSON: one file per evaluated model, schema version 2.

``hupbench eval`` writes it, ``hupbench leaderboard`` reads it. The schema is
the one in the shared contract (notes/common.md), checked exactly: every key
is present (``null`` where a value is unknown), no key is unknown, types are
exact (an ``int`` field refuses ``True`` and ``1.5``), numbers are finite,
errors and latencies are non-negative, and the PCK AUC lies in [0, 1].

Versions:
    2 adds two entries to ``metrics``: ``probe_symmetric_mpjpe_mm`` (the probe
    corner MPJPE minimised per frame over the probe box's half turn,
    ``hupbench.metrics.probe_symmetric_mpjpe_mm``; never above the plain probe
    MPJPE) and ``spread_ratio`` ({"x", "y", "z"}: the spread of the predicted
    3D keypoints across frames over the truth's, ``hupbench.metrics.spread_ratios``;
    ``hupbench eval`` warns below 0.5). Both may be ``null``.
    1 files (written before) still load: :func:`load_results` validates them
    as version 1 and returns them upgraded to version 2 with those fields
    ``null`` (unknown: they were not measured, and nothing is made up for
    them). Only version 2 is written.

A ``"reported"`` row (numbers quoted from a paper) may leave almost every
field ``null``; it needs ``metrics.mpjpe_mm.all`` and a ``source`` citation.

Convention: errors in millimetres, latencies in milliseconds per image,
times in seconds, FLOPs per image counted as 2 x multiply-adds.
"""

from __future__ import annotations

import copy
import json
import math
import re
from pathlib import Path

from datagen.io import write_json

SCHEMA_VERSION = 2
#: versions :func:`load_results` reads (older ones are upgraded on load)
READABLE_VERSIONS = (1, 2)
KINDS = ("measured", "reported")
FORMATS = ("pytorch", "onnx")
SPLITS = ("train", "val", "test")
BREAKDOWNS = ("latitude", "z_ego", "background")
# A run name is also a file stem: no separators, no leading dot, nothing a shell would need quoted.
RUN_NAME_PATTERN = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,127}$")

_TOP_KEYS = ("schema_version", "kind", "run_name", "model", "dataset", "metrics", "breakdowns",
             "latency_ms_per_image", "device", "training", "git_commit", "created_utc", "source")
_MODEL_KEYS = ("name", "label", "config", "parameters", "flops", "input_size", "format")
_DATASET_KEYS = ("path", "manifest_sha256", "split", "frames", "name")
_METRIC_KEYS_V1 = ("mpjpe_mm", "root_relative_hand_mpjpe_mm", "pa_mpjpe_hand_mm", "pck_auc_0_50mm", "pixel_error_px")
_METRIC_KEYS = _METRIC_KEYS_V1 + ("probe_symmetric_mpjpe_mm", "spread_ratio")
_SPREAD_KEYS = ("x", "y", "z")
# the symmetric probe error is a minimum that includes the identity: it may exceed the plain one only by rounding
_SYMMETRIC_SLACK_MM = 1e-6
_MPJPE_KEYS = ("all", "hand", "probe", "all_averaging")
_LATENCY_RUNTIMES = ("pytorch", "onnxruntime")
_LATENCY_BATCHES = ("batch1", "batch32")
_TRAINING_KEYS = ("wall_s", "hardware", "samples_seen", "epochs", "command", "log")
_BUCKET_KEYS = ("frames", "mpjpe_mm")
_BUCKET_MPJPE_KEYS = ("all", "hand", "probe")


def _path(parts: tuple) -> str:
    return "results" + "".join(f"[{p!r}]" for p in parts)


def _show(value) -> str:
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


def _fail(parts: tuple, expected: str, value) -> None:
    raise ValueError(f"{_path(parts)} must be {expected}, got {_show(value)}")


def _keys(d, parts: tuple, keys: tuple) -> None:
    """``d`` is a dict with exactly ``keys``."""
    if not isinstance(d, dict):
        _fail(parts, "a dict", d)
    missing = [k for k in keys if k not in d]
    if missing:
        raise ValueError(f"{_path(parts)} is missing key(s) {missing}; expected keys {list(keys)}")
    unknown = sorted(str(k) for k in d if k not in keys)
    if unknown:
        raise ValueError(f"{_path(parts)} has unknown key(s) {unknown}; expected keys {list(keys)}")


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _number(d: dict, parts: tuple, *, nullable: bool, low: float | None = 0.0, high: float | None = None):
    value = d[parts[-1]]
    if value is None and nullable:
        return
    bounds = ""
    if low is not None and high is not None:
        bounds = f" in [{low:g}, {high:g}]"
    elif low is not None:
        bounds = f" >= {low:g}"
    expected = f"a finite number{bounds}" + (" or null" if nullable else "")
    if not _is_number(value) or not math.isfinite(value):
        _fail(parts, expected, value)
    if (low is not None and value < low) or (high is not None and value > high):
        _fail(parts, expected, value)


def _integer(d: dict, parts: tuple, *, nullable: bool, low: int = 0) -> None:
    value = d[parts[-1]]
    if value is None and nullable:
        return
    if not isinstance(value, int) or isinstance(value, bool) or value < low:
        _fail(parts, f"an integer >= {low}" + (" or null" if nullable else ""), value)


def _string(d: dict, parts: tuple, *, nullable: bool) -> None:
    value = d[parts[-1]]
    if value is None and nullable:
        return
    if not isinstance(value, str) or not value.strip():
        _fail(parts, "a non-empty string" + (" or null" if nullable else ""), value)


def _choice(d: dict, parts: tuple, choices: tuple, *, nullable: bool) -> None:
    value = d[parts[-1]]
    if value is None and nullable:
        return
    if not isinstance(value, str) or value not in choices:
        _fail(parts, "one of " + ", ".join(repr(c) for c in choices) + (" or null" if nullable else ""), value)


def _validate_mpjpe_triplet(m: dict, parts: tuple, keys: tuple, *, all_nullable: bool) -> None:
    _keys(m, parts, keys)
    _number(m, parts + ("all",), nullable=all_nullable)
    _number(m, parts + ("hand",), nullable=True)
    _number(m, parts + ("probe",), nullable=True)


def _validate_metrics(metrics, version: int) -> None:
    """``results['metrics']``: MPJPE by part, the other errors, and (version 2) the probe-symmetric MPJPE
    and the spread ratios."""
    _keys(metrics, ("metrics",), _METRIC_KEYS if version >= 2 else _METRIC_KEYS_V1)
    _validate_mpjpe_triplet(metrics["mpjpe_mm"], ("metrics", "mpjpe_mm"), _MPJPE_KEYS, all_nullable=False)
    _string(metrics["mpjpe_mm"], ("metrics", "mpjpe_mm", "all_averaging"), nullable=False)
    _number(metrics, ("metrics", "root_relative_hand_mpjpe_mm"), nullable=True)
    _number(metrics, ("metrics", "pa_mpjpe_hand_mm"), nullable=True)
    _number(metrics, ("metrics", "pck_auc_0_50mm"), nullable=True, high=1.0)
    _number(metrics, ("metrics", "pixel_error_px"), nullable=True)
    if version >= 2:
        _number(metrics, ("metrics", "probe_symmetric_mpjpe_mm"), nullable=True)
        symmetric, probe = metrics["probe_symmetric_mpjpe_mm"], metrics["mpjpe_mm"]["probe"]
        if symmetric is not None and probe is not None and symmetric > probe + _SYMMETRIC_SLACK_MM:
            _fail(("metrics", "probe_symmetric_mpjpe_mm"),
                  f"at most the plain probe MPJPE ({probe!r}: a minimum over a group that holds the identity)",
                  symmetric)
        _keys(metrics["spread_ratio"], ("metrics", "spread_ratio"), _SPREAD_KEYS)
        for axis in _SPREAD_KEYS:
            _number(metrics["spread_ratio"], ("metrics", "spread_ratio", axis), nullable=True)


def _validate_breakdowns(breakdowns) -> None:
    """``results['breakdowns']``: axis -> bucket label -> {"frames", "mpjpe_mm"}."""
    if not isinstance(breakdowns, dict):
        _fail(("breakdowns",), "a dict (empty when none were computed)", breakdowns)
    unknown = sorted(str(k) for k in breakdowns if k not in BREAKDOWNS)
    if unknown:
        raise ValueError(f"results['breakdowns'] has unknown key(s) {unknown}; expected a subset of {list(BREAKDOWNS)}")
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


def validate_results(d: dict) -> dict:
    """Check a results dict against its schema version (2, or 1 for files written before).

    Args:
        d: the parsed results JSON.

    Returns:
        ``d`` itself, unchanged, so that calls chain.

    Raises:
        ValueError: naming the first bad, missing or unknown field by its path,
            e.g. ``results['metrics']['mpjpe_mm']['hand'] must be a finite number >= 0 or null, got 'x'``.
    """
    _keys(d, (), _TOP_KEYS)
    version = d["schema_version"]
    if not isinstance(version, int) or isinstance(version, bool) or version not in READABLE_VERSIONS:
        raise ValueError(f"results['schema_version'] must be {SCHEMA_VERSION} (the version this hupbench writes) or "
                         f"one of {list(READABLE_VERSIONS[:-1])} (read and upgraded), got {_show(version)}")
    _choice(d, ("kind",), KINDS, nullable=False)
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
    _keys(dataset, ("dataset",), _DATASET_KEYS)
    _string(dataset, ("dataset", "path"), nullable=True)
    _string(dataset, ("dataset", "manifest_sha256"), nullable=True)
    _choice(dataset, ("dataset", "split"), SPLITS, nullable=False)
    _integer(dataset, ("dataset", "frames"), nullable=True)
    _string(dataset, ("dataset", "name"), nullable=False)

    _validate_metrics(d["metrics"], version)
    _validate_breakdowns(d["breakdowns"])

    latency = d["latency_ms_per_image"]
    _keys(latency, ("latency_ms_per_image",), _LATENCY_RUNTIMES)
    for runtime in _LATENCY_RUNTIMES:
        parts = ("latency_ms_per_image", runtime)
        _keys(latency[runtime], parts, _LATENCY_BATCHES)
        for batch in _LATENCY_BATCHES:
            _number(latency[runtime], parts + (batch,), nullable=True)

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
    _string(d, ("created_utc",), nullable=True)
    _string(d, ("source",), nullable=d["kind"] != "reported")
    return d


def blank_results(kind: str, run_name: str) -> dict:
    """A results dict with every field present and unknown values ``null``.

    Fill at least ``model.name``, ``model.label``, ``dataset.name``,
    ``metrics.mpjpe_mm.all`` and ``metrics.mpjpe_mm.all_averaging`` (and
    ``source`` for a reported row) before it validates.

    Args:
        kind: "measured" or "reported".
        run_name: the run name (also the file stem of its results JSON).

    Returns:
        A fresh dict; nested dicts are not shared between calls.
    """
    if kind not in KINDS:
        raise ValueError(f"kind must be one of {list(KINDS)}, got {kind!r}")
    blank = {
        "schema_version": SCHEMA_VERSION, "kind": kind, "run_name": run_name,
        "model": dict.fromkeys(_MODEL_KEYS),
        "dataset": dict.fromkeys(_DATASET_KEYS) | {"split": "test"},
        "metrics": dict.fromkeys(_METRIC_KEYS) | {"mpjpe_mm": dict.fromkeys(_MPJPE_KEYS),
                                                   "spread_ratio": dict.fromkeys(_SPREAD_KEYS)},
        "breakdowns": {},
        "latency_ms_per_image": {r: dict.fromkeys(_LATENCY_BATCHES) for r in _LATENCY_RUNTIMES},
        "device": None,
        "training": dict.fromkeys(_TRAINING_KEYS),
        "git_commit": None, "created_utc": None, "source": None,
    }
    return copy.deepcopy(blank)


def upgrade_results(d: dict) -> dict:
    """A validated results dict in the current schema version.

    Version 1 gains ``metrics.probe_symmetric_mpjpe_mm = None`` and
    ``metrics.spread_ratio = {"x": None, "y": None, "z": None}`` (not measured
    when the file was written); version 2 is returned as is.

    Args:
        d: a dict that :func:`validate_results` accepts.

    Returns:
        ``d`` itself when it is current, else an upgraded deep copy (``d`` is not changed).
    """
    validate_results(d)
    if d["schema_version"] == SCHEMA_VERSION:
        return d
    out = copy.deepcopy(d)
    out["schema_version"] = SCHEMA_VERSION
    out["metrics"]["probe_symmetric_mpjpe_mm"] = None
    out["metrics"]["spread_ratio"] = dict.fromkeys(_SPREAD_KEYS)
    return validate_results(out)


def load_results(path: str | Path) -> dict:
    """Read a results JSON, validate it and upgrade it to the current schema version.

    Args:
        path: the ``.json`` file.

    Returns:
        The validated dict, in schema version 2 (see :func:`upgrade_results`).

    Raises:
        FileNotFoundError: the file does not exist.
        ValueError: the file is not JSON or breaks the schema; the message starts with the file's path.
    """
    path = Path(path)
    if path.exists() and not path.is_file():
        raise ValueError(f"{path}: not a file (a results file is one JSON file)")
    if not path.is_file():
        raise FileNotFoundError(f"results file not found: {path}")
    data = path.read_bytes()
    if not data.strip():
        raise ValueError(f"{path}: empty file, not valid JSON (a results file is one JSON object)")
    try:
        data = json.loads(data.decode("utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: not valid JSON: {exc}") from None
    try:
        return upgrade_results(data)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from exc


def write_results(path: str | Path, d: dict) -> Path:
    """Validate a results dict, then write it atomically as indented JSON with sorted keys.

    Args:
        path: destination ``.json``; parent folders are created.
        d: the results dict.

    Returns:
        The written path.

    Raises:
        ValueError: ``d`` breaks the schema or is not the current version (nothing is written).
    """
    validate_results(d)
    if d["schema_version"] != SCHEMA_VERSION:
        raise ValueError(f"results['schema_version'] must be {SCHEMA_VERSION} to be written, got "
                         f"{d['schema_version']}: upgrade_results() first")
    return write_json(path, d)
