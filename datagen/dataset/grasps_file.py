"""The grasps file a dataset is rendered from (``grasps.npz``, written by ``hupbench grasps``): read and checked."""

from __future__ import annotations

import io
import zipfile
import zlib
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from hupbench.core import keypoints as kp
from hupbench.core.contract import SEQUENCE, read_manifest
from hupbench.core.errors import BadValueError, MissingFileError
from hupbench.core.geometry import axis_angle_to_matrix
from hupbench.datagen.assets.hand_anatomy import FACTOR_RANGE, PROPORTION_FIELDS, HandSpec
from hupbench.datagen.assets.subjects import ADULT_HAND_BREADTH_MM, ADULT_HAND_LENGTH_MM
from hupbench.datagen.assets.probe_mesh import MAX_LENGTH_M, PROBE_MESH_FIELDS
from hupbench.datagen.dataset.spec import BOX_CENTRE

if TYPE_CHECKING:
    from hupbench.datagen.assets.probe import Probe


#: what a dataset needs of a grasps.npz: array -> (dtype kind: "f" float / "i" integer, row shape)
GRASP_FIELDS = {"hand_pose": ("f", (48,)), "hand_trans": ("f", (3,)), "grasp_id": ("i", ())}
#: what a dataset records of a grasps.npz when it is there: the probe orientation Theta_Vol (Euler
#: angles, degrees) each grasp was made for (``hupbench grasps`` writes it)
OPTIONAL_GRASP_FIELDS = {"probe_euler_deg": ("f", (3,))}
#: each grasp's subject (``hupbench grasps +subjects=clinic`` writes them, all or none): sex (0 woman, 1 man), the
#: hand's :data:`hupbench.datagen.assets.hand_anatomy.PROPORTION_FIELDS`, and its measured length and breadth, mm
SUBJECT_FIELDS = {"subject_sex": ("i", ()), "subject_hand": ("f", (len(PROPORTION_FIELDS),)),
                  "hand_length_mm": ("f", ()), "hand_breadth_mm": ("f", ())}
#: the patient placed under each grasp (``hupbench grasps +subjects=clinic`` writes them, all or none:
#: :data:`hupbench.datagen.assets.patient.PLACEMENT_FIELDS`): metres, world (probe) frame
PATIENT_FIELDS = {"patient_T_world_body": ("f", (4, 4)), "patient_radius_m": ("f", ()),
                  "patient_vertical_world": ("f", (3,)), "patient_normal_world": ("f", (3,)),
                  "patient_lens_skin_m": ("f", ()), "patient_penetration_m": ("f", ())}
#: the field groups a grasps file holds all of or none of
_ALL_OR_NONE = {"subject": SUBJECT_FIELDS, "patient": PATIENT_FIELDS}
#: the default dataset's grasps, shipped with hupbench (the benchmark's grasps: ``hupbench generate`` renders
#: them unless given a grasps file, so that every machine makes the same dataset); ``hupbench grasps`` with
#: the default config made them, on a 2-core AMD EPYC
DEFAULT_GRASPS = Path(__file__).with_name("default_grasps.npz")
#: the clinic track's grasps, one per subject, shipped with hupbench (like the default grasps, so that every machine
#: renders the same clinic dataset): ``hupbench grasps +subjects=clinic`` made them, on a 2-core AMD EPYC
CLINIC_GRASPS = Path(__file__).with_name("clinic_grasps.npz")
#: the longest rotation vector of a joint (and of the hand as a whole), radians: half a turn, the most a
#: rotation vector written by a hand model (e.g. MANO, Romero et al. 2017) takes; no finger joint turns
#: more than about 105 degrees (:func:`hupbench.datagen.assets.hand_anatomy.joint_limits_rad`)
MAX_JOINT_ROTATION_RAD = np.pi
#: the farthest a grasp's wrist lies from the probe frame's origin, metres: a hand's length beyond the
#: longest probe (:data:`hupbench.datagen.assets.probe_mesh.MAX_LENGTH_M`) and the longest adult hand
MAX_WRIST_DISTANCE_M = MAX_LENGTH_M + ADULT_HAND_LENGTH_MM[1] * 1e-3
_EXPECTED = "expected a grasps.npz written by `hupbench grasps`"


def first_grasps(source: str | Path, n: int, out: str | Path) -> Path:
    """Write the first ``n`` grasps of the grasps file ``source`` (every per-grasp array cut, per-file arrays such
    as a probe mesh kept whole) to ``out``, for small datasets and benchmarks; returns ``out``."""
    from hupbench.core.io import save_npz

    with np.load(source, allow_pickle=False) as data:
        count = len(data["grasp_id"])
        arrays = {k: (data[k][:n] if data[k].ndim and len(data[k]) == count else data[k]) for k in data.files}
    return save_npz(out, arrays)


def read_grasps_probe_record(path: str | Path) -> dict:
    """The record of the probe a grasps file (checked by :func:`read_grasps`) was made for
    (:attr:`hupbench.datagen.assets.probe.Probe.record`) without building the probe: the JSON it carries, or
    ``{"kind": "procedural"}`` when it carries no mesh."""
    import json

    with np.load(path, allow_pickle=False) as data:
        if "probe_mesh_record" not in data.files:
            return {"kind": "procedural"}
        return json.loads(str(data["probe_mesh_record"]))


def read_grasps_probe(path: str | Path | bytes):
    """The probe a grasps file (or its bytes, checked by :func:`read_grasps`) was made for: a
    :class:`hupbench.datagen.assets.probe.Probe` built from the mesh it carries, or None when it carries none (the
    procedural probe's grasps).

    Raises:
        BadValueError: its probe arrays are incomplete or do not match their record.
    """
    import json

    from hupbench.datagen.assets.probe import probe_from_geometry
    from hupbench.datagen.assets.probe_mesh import ProbeMeshSpec, probe_geometry_sha256

    name = "grasps (bytes)" if isinstance(path, bytes) else str(path)
    with np.load(io.BytesIO(path) if isinstance(path, bytes) else path, allow_pickle=False) as data:
        present = [k for k in PROBE_MESH_FIELDS if k in data.files]
        if not present:
            return None
        arrays = {k: data[k] for k in present}
    record = json.loads(str(arrays["probe_mesh_record"])) if "probe_mesh_record" in arrays else {}
    vertices, faces = arrays.get("probe_mesh_vertices"), arrays.get("probe_mesh_faces")
    if len(present) != len(PROBE_MESH_FIELDS) or vertices.ndim != 2 or vertices.shape[1:] != (3,) \
            or faces.ndim != 2 or faces.shape[1:] != (3,) or faces.dtype.kind not in "iu" \
            or probe_geometry_sha256(vertices, faces) != record.get("geometry_sha256"):
        raise BadValueError(f"grasps file {name}: its probe mesh ({', '.join(present)}) is incomplete or does not "
                            "match its record (damaged); write it again with `hupbench grasps`")
    spec = ProbeMeshSpec(record["path"], record["unit"], record["align"], record["sha256"])
    return probe_from_geometry(vertices, faces, spec)


def read_grasps(path: str | Path | bytes) -> dict[str, np.ndarray]:
    """Read and check the arrays a dataset is rendered from, out of a grasps.npz (``hupbench grasps``).

    Every array of :data:`GRASP_FIELDS` is read in full (the zip's CRC is checked on the way) and
    checked: a float (pose, translation) or integer (ids) dtype, the row shape, one row per grasp
    in each, at least one grasp, finite values, unique ids, and poses a hand can take: every joint's
    rotation vector at most :data:`MAX_JOINT_ROTATION_RAD` long, the wrist within
    :data:`MAX_WRIST_DISTANCE_M` of the probe.

    Args:
        path: the file, or its bytes (what a Ray actor on another machine is sent).

    Returns:
        {"hand_pose": (G, 48) float64 axis-angle radians, "hand_trans": (G, 3) float64 metres (the wrist in
        the probe frame), "grasp_id": (G,) int64}, "probe_euler_deg" (G, 3) float64 degrees when the file
        holds it, and its subjects when it holds them (:data:`SUBJECT_FIELDS`, checked: sex 0 or 1, proportions
        within :data:`hupbench.datagen.assets.hand_anatomy.FACTOR_RANGE`, length and breadth within adult
        sizes): "subject_sex" (G,) int8, "subject_hand" (G, 5) float64, "hand_length_mm" and "hand_breadth_mm"
        (G,) float64; and its patients' placements when it holds them (:data:`PATIENT_FIELDS`, float64).

    Raises:
        MissingFileError: no such file. BadValueError: anything else wrong; the message names the file and
        what was expected.
    """
    if isinstance(path, bytes):
        name, source = "grasps (bytes)", io.BytesIO(path)
    else:
        path = Path(path)
        name, source = str(path), path
        if not path.exists():
            raise MissingFileError(f"grasps file {path} not found (run `hupbench grasps` or set grasps_path=null)")
    arrays, problem = _read_arrays(source)
    problem = problem or _arrays_problem(arrays)
    if problem:
        raise BadValueError(f"grasps file {name}{problem}")
    out = {"hand_pose": arrays["hand_pose"].astype(np.float64), "hand_trans": arrays["hand_trans"].astype(np.float64),
           "grasp_id": arrays["grasp_id"].astype(np.int64)}
    if "probe_euler_deg" in arrays:
        out["probe_euler_deg"] = arrays["probe_euler_deg"].astype(np.float64)
    if "subject_sex" in arrays:
        out["subject_sex"] = arrays["subject_sex"].astype(np.int8)
        out |= {k: arrays[k].astype(np.float64) for k in SUBJECT_FIELDS if k != "subject_sex"}
    out |= {k: arrays[k].astype(np.float64) for k in PATIENT_FIELDS if k in arrays}
    return out


def _read_arrays(source: Path | io.BytesIO) -> tuple[dict[str, np.ndarray], str | None]:
    """The arrays of :data:`GRASP_FIELDS` (and those of :data:`OPTIONAL_GRASP_FIELDS` present), read in full,
    or what keeps the file from being read, as the rest of its error line."""
    if isinstance(source, Path):
        if source.is_dir():
            return {}, f" is a folder; {_EXPECTED}"
        if source.stat().st_size == 0:
            return {}, f" is empty (0 bytes); {_EXPECTED}"
    if not zipfile.is_zipfile(source):
        size = source.getbuffer().nbytes if isinstance(source, io.BytesIO) else source.stat().st_size
        return {}, f" is not an .npz archive ({size} bytes, no zip directory); {_EXPECTED}"
    if isinstance(source, io.BytesIO):
        source.seek(0)  # is_zipfile read the end of the buffer
    arrays = {}
    try:
        with np.load(source, allow_pickle=False) as data:
            if not hasattr(data, "files"):
                return {}, f" holds a single array, not an .npz archive of the arrays {list(GRASP_FIELDS)}"
            absent = [k for k in GRASP_FIELDS if k not in data.files]
            if absent:
                return {}, f" lacks the arrays {absent} (it holds {sorted(data.files)}); {_EXPECTED}"
            grouped = []
            for group, fields in _ALL_OR_NONE.items():
                held = [k for k in fields if k in data.files]
                if held and len(held) != len(fields):
                    return {}, (f" holds the {group} arrays {held} but not {sorted(set(fields) - set(held))}; "
                                "expected all of them or none")
                grouped += held
            for key in [*GRASP_FIELDS, *(k for k in OPTIONAL_GRASP_FIELDS if k in data.files), *grouped]:
                try:
                    arrays[key] = data[key]
                except ValueError as exc:  # object arrays: numpy refuses to unpickle them
                    return {}, f": {key} cannot be read as a numeric array ({exc})"
    except ValueError as exc:
        return {}, f" is not an .npz archive ({exc})"
    except (zipfile.BadZipFile, zipfile.LargeZipFile, EOFError, KeyError, zlib.error, OSError) as exc:
        return {}, (f" is damaged or not an .npz archive ({type(exc).__name__}: {exc}); write it again with "
                    "`hupbench grasps`")
    return arrays, None


def _arrays_problem(arrays: dict[str, np.ndarray]) -> str | None:
    """What is wrong with a grasps file's arrays (:func:`read_grasps` lists the checks), as the rest of its error
    line, or None."""
    for key, (kind, row_shape) in (GRASP_FIELDS | OPTIONAL_GRASP_FIELDS | SUBJECT_FIELDS | PATIENT_FIELDS).items():
        array = arrays.get(key)
        if array is None:
            continue
        if array.dtype.kind not in (("f", "i", "u") if kind == "f" else ("i", "u")):
            return f": {key} is {array.dtype}, expected " + ("float numbers" if kind == "f" else "integer ids")
        if array.ndim != 1 + len(row_shape) or array.shape[1:] != row_shape:
            return f": {key} has shape {array.shape}, expected (G, " + ", ".join(str(v) for v in row_shape) + ")" \
                if row_shape else f": {key} has shape {array.shape}, expected (G,)"
    rows = {k: len(a) for k, a in arrays.items()}
    if len(set(rows.values())) != 1:
        return f": the arrays have different numbers of rows {rows}; expected one row per grasp in each"
    if rows["hand_pose"] == 0:
        return " holds no grasps (0 rows)"
    for key in [k for k in arrays if k != "grasp_id"]:
        bad = ~np.isfinite(arrays[key].astype(np.float64).reshape(len(arrays[key]), -1)).all(axis=1)
        if bad.any():
            return f": {key} must be finite; rows {np.flatnonzero(bad)[:10].tolist()} hold NaN or inf"
    ids, counts = np.unique(arrays["grasp_id"], return_counts=True)
    if (counts > 1).any():
        return f": grasp_id must be unique, {ids[counts > 1][:10].tolist()} repeat"
    turn = np.linalg.norm(arrays["hand_pose"].astype(np.float64).reshape(-1, 16, 3), axis=-1).max(axis=1)
    wrist = np.linalg.norm(arrays["hand_trans"].astype(np.float64), axis=1)
    for values, limit, what in ((turn, MAX_JOINT_ROTATION_RAD, "hand_pose turns a joint by more than half a turn "
                                 f"(rotation vectors longer than {MAX_JOINT_ROTATION_RAD:.4f} rad"),
                                (wrist, MAX_WRIST_DISTANCE_M, "hand_trans puts the wrist farther from the probe than a "
                                 f"hand can reach it ({MAX_WRIST_DISTANCE_M:g} m")):
        bad = np.flatnonzero(values > limit)
        if len(bad):
            return (f": {what}, up to {values[bad].max():.4g}) in rows {bad[:10].tolist()}; expected a pose a hand "
                    "can take, in radians and metres")
    return _subjects_problem(arrays) if "subject_sex" in arrays else None


def _subjects_problem(arrays: dict[str, np.ndarray]) -> str | None:
    """What is wrong with a grasps file's :data:`SUBJECT_FIELDS` (shapes and finiteness checked), or None."""
    low, high = FACTOR_RANGE
    for values, bad_rows, what in (
            (arrays["subject_sex"], ~np.isin(arrays["subject_sex"], (0, 1)), "subject_sex must be 0 (woman) or 1 (man)"),
            (arrays["subject_hand"], ((arrays["subject_hand"] < low) | (arrays["subject_hand"] > high)).any(axis=1),
             f"subject_hand's {list(PROPORTION_FIELDS)} must be within {low:g}..{high:g}"),
            (arrays["hand_length_mm"], (arrays["hand_length_mm"] < ADULT_HAND_LENGTH_MM[0])
             | (arrays["hand_length_mm"] > ADULT_HAND_LENGTH_MM[1]),
             f"hand_length_mm must be within {ADULT_HAND_LENGTH_MM[0]:g}..{ADULT_HAND_LENGTH_MM[1]:g} (adult sizes)"),
            (arrays["hand_breadth_mm"], (arrays["hand_breadth_mm"] < ADULT_HAND_BREADTH_MM[0])
             | (arrays["hand_breadth_mm"] > ADULT_HAND_BREADTH_MM[1]),
             f"hand_breadth_mm must be within {ADULT_HAND_BREADTH_MM[0]:g}..{ADULT_HAND_BREADTH_MM[1]:g} (adult sizes)")):
        rows = np.flatnonzero(bad_rows)
        if len(rows):
            return f": {what}; rows {rows[:10].tolist()} are not"
    return None


def rendered_with(grasps: dict[str, np.ndarray], ann: dict[str, np.ndarray], manifest: dict) -> np.ndarray:
    """(N,) bool: each annotation row holds the grasp (id, hand pose, translation) that its ``grasp_index``
    names in ``grasps`` (:func:`read_grasps`' arrays), as the writer copied them: the frames were rendered
    from these grasps. On a dataset of clips (``manifest`` with a "sequence" record; ``ann`` with ``clip_id`` and
    ``time_s``) the pose is the grasp's with its clip's finger adjustments
    (:func:`hupbench.datagen.dataset.finger_motion.expected_hand_poses`)."""
    index = ann["grasp_index"]
    inside = (index >= 0) & (index < len(grasps["grasp_id"]))
    at = np.where(inside, index, 0)
    expected = grasps["hand_pose"][at]
    if SEQUENCE in manifest:
        from hupbench.datagen.dataset.finger_motion import expected_hand_poses

        expected = expected_hand_poses(grasps["hand_pose"], ann, manifest)
    return (inside & (grasps["grasp_id"][at] == ann["grasp_id"])
            & (expected == ann["hand_pose"]).all(axis=1)
            & (grasps["hand_trans"][at] == ann["hand_trans"]).all(axis=1))


class GraspSet:
    """The grasps a dataset is rendered from (``grasps.npz``), with derived geometry.

    Args:
        path: a grasps.npz, or its bytes (what a Ray actor on another machine is sent).
    """

    def __init__(self, path: str | Path | bytes) -> None:
        from hupbench.datagen.assets.hand import build_hand, hand_keypoints as hand_keypoints_of
        from hupbench.datagen.assets.probe import build_probe

        arrays = read_grasps(path)
        self.hand_pose, self.hand_trans, self.grasp_id = arrays["hand_pose"], arrays["hand_trans"], arrays["grasp_id"]
        #: (G, 3) degrees, the probe orientation each grasp was made for, or None per grasp when not recorded
        self.probe_euler_deg = arrays.get("probe_euler_deg", [None] * len(self.hand_pose))
        self.path = None if isinstance(path, bytes) else Path(path)
        #: the probe the grasps were made for (:func:`read_grasps_probe`, else the procedural one)
        self.probe = read_grasps_probe(path) or build_probe()
        #: each grasp's subject (:data:`SUBJECT_FIELDS` arrays, (G,) or (G, 5)), or None when the file has none
        self.subjects = {k: arrays[k] for k in SUBJECT_FIELDS} if "subject_sex" in arrays else None
        if self.subjects is None:
            hand_keypoints = build_hand().keypoints(self.hand_pose, self.hand_trans, clamp=False)
        else:  # each grasp on its own hand, from its skeleton (its mesh is built where it is rendered)
            hand_keypoints = np.stack([hand_keypoints_of(self.hand_spec(g), self.hand_pose[g], self.hand_trans[g],
                                                         clamp=False) for g in range(len(self))])
        #: each grasp's patient (:class:`hupbench.datagen.assets.patient.PatientPlacement`), or None when the
        #: file has none
        self.placements = None
        if "patient_radius_m" in arrays:
            from hupbench.datagen.assets.patient import placement_from_arrays

            self.placements = [placement_from_arrays(arrays, g) for g in range(len(self.hand_pose))]
        self.keypoints_world = np.concatenate(
            [hand_keypoints, np.broadcast_to(self.probe.corners_probe, (len(self), kp.NUM_CORNERS, 3))], axis=1)
        R = axis_angle_to_matrix(self.hand_pose[:, :3])
        self.forearm_axis = -R[:, :, 0]
        self.dorsal = R[:, :, 1]
        self.box_centre = 0.5 * (self.keypoints_world.min(axis=1) + self.keypoints_world.max(axis=1))

    def __len__(self) -> int:
        return len(self.hand_pose)

    def hand_spec(self, g: int) -> HandSpec:
        """Grasp ``g``'s hand: its subject's (``subject_hand``), or the tables' hand ``HandSpec()`` for a file
        without subjects."""
        if self.subjects is None:
            return HandSpec()
        return HandSpec(*(float(v) for v in self.subjects["subject_hand"][g]))

    def look_at_points(self, look_at: str) -> np.ndarray:
        """(G, 3) float64, metres, world frame: each grasp's camera target (see ``DatasetSpec.look_at``)."""
        if look_at == BOX_CENTRE:
            return self.box_centre
        assert look_at in kp.KEYPOINT_NAMES, look_at  # DatasetSpec checked it
        return self.keypoints_world[:, kp.KEYPOINT_NAMES.index(look_at)]


def subjects_record(grasps: GraspSet) -> dict:
    """The manifest's record of a grasps file's subjects: per grasp (file order) the sex (0 woman, 1 man) and
    the hand's measured length and breadth, mm, and its proportions; empty lists for a file without subjects."""
    if grasps.subjects is None:
        return {"subject_sex": [], "hand_length_mm": [], "hand_breadth_mm": [], "subject_hand": []}
    return {"subject_sex": grasps.subjects["subject_sex"].tolist(),
            "hand_length_mm": np.round(grasps.subjects["hand_length_mm"], 3).tolist(),
            "hand_breadth_mm": np.round(grasps.subjects["hand_breadth_mm"], 3).tolist(),
            "subject_hand": grasps.subjects["subject_hand"].tolist(), "subject_hand_fields": list(PROPORTION_FIELDS)}


def probe_of_dataset(root_or_manifest, manifest: dict | None = None) -> "Probe":
    """The probe a dataset was rendered with, from its manifest's ``probe`` record.

    Given the dataset folder, a mesh probe is rebuilt from the geometry its ``grasps.npz`` carries (the
    dataset needs nothing outside its folder); given the manifest (a dict), from the mesh file the record
    names, whose sha256 must still match. A manifest without a record (older datasets) means the
    procedural probe.

    Args:
        root_or_manifest: the dataset folder (str or Path) or its parsed ``manifest.json``.
        manifest: with a dataset folder, its manifest as the caller read it (verify reads one whose counts
            disagree with its layout, to report that); default: the folder's, read and checked.

    Returns:
        :class:`Probe` (shared and cached: do not modify it).

    Raises:
        MissingFileError, BadValueError: the manifest, the grasps file or the mesh is missing or does not
            match the record.
    """
    from hupbench.datagen.assets.probe import ProbeSpec, build_mesh_probe, build_probe
    from hupbench.datagen.assets.probe_mesh import ProbeMeshSpec
    from hupbench.core.io import file_sha256

    if isinstance(root_or_manifest, dict):
        manifest, root = root_or_manifest, None
    else:
        root = Path(root_or_manifest)
        manifest = read_manifest(root) if manifest is None else manifest
    record = manifest.get("probe", {"kind": "procedural"})
    if record.get("kind") == "procedural":
        return build_probe(ProbeSpec(**record["spec"]) if "spec" in record else ProbeSpec())
    spec = ProbeMeshSpec(record["path"], record["unit"], record["align"], record["sha256"])
    if root is not None:
        read_grasps(root / "grasps.npz")  # a missing or damaged file: its one-line error
        probe = read_grasps_probe(root / "grasps.npz")
        if probe is None or probe.record["geometry_sha256"] != record["geometry_sha256"]:
            raise BadValueError(f"{root / 'grasps.npz'} does not hold the probe mesh the manifest records "
                                f"({record['path']}); the dataset's grasps file was changed")
        return probe
    if not Path(spec.path).is_file():
        raise MissingFileError(f"the dataset's probe mesh {spec.path} not found; pass the dataset folder instead of "
                               "its manifest (its grasps.npz carries the mesh)")
    if file_sha256(spec.path) != spec.sha256:
        raise BadValueError(f"the dataset's probe mesh {spec.path} has changed since the dataset was made (sha256 "
                            "differs); pass the dataset folder instead (its grasps.npz carries the mesh)")
    return build_mesh_probe(spec)
