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
                        background or view id the manifest does not have, a K that is no camera,
                        a lamp colour outside [0, 1] or a negative lamp power
  ``frame_ids``         frame ids repeated or out of order, or not the layout's ids
  ``manifest_mismatch`` the manifest disagrees with the files: its K with the annotations' K, its
                        image_size with every image, its modalities with the image folders (a
                        modality's images present but not listed)
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
                        with (their hand poses, translations and ids in the annotations), or its
                        sha256 is not the manifest's ``grasps_sha256``
  ``lens_skin``         (clinic track) a grasp whose probe lens is not on its patient's skin (its
                        deepest vertex more than 1 mm above it, or a probe vertex more than 2 mm deep)
                        or whose hand or forearm, as rendered, reaches more than 3 mm into the body or
                        the bed; one problem per grasp, naming its frames
  ``camera_in_patient`` (clinic track) a camera centre inside the patient or below the bed's top
  ``hand_size``         (clinic track) a frame's hand_length_mm / hand_breadth_mm other than its grasp's
                        subject's in grasps.npz
  ``patient_depth``     (clinic track) pixels the mask calls patient, unprojected with their depth, off
                        the body's surface by more than max(3 mm, 1.5 pixel footprints)
  ``clip_continuity``   (a dataset of clips) a clip not whole, in order and in time, or whose labels jump:
                        the probe's centre or the head moves between frames beyond the clip's own
                        kinematic bounds (:mod:`hupbench.datagen.dataset.verify_sequence`)

On the clinic track (manifest ``protocol.track``; :mod:`hupbench.datagen.dataset.verify_clinic`) the room
behind has depth and label 0 and hides the background image, each grasp has its own hand and patient
(grasps.npz) and the head turns keypoint 9 off the optical axis. There ``pose_mismatch`` rebuilds the keypoints
on each grasp's own hand; ``look_at`` checks that the look-at keypoint projects at the frame's ``aim_px``, z_ego
from the camera centre; ``mask_depth`` is a pixel without depth; ``empty_frame`` a mask without hand, forearm
or probe; the RGB image is not compared with a background image; seg labels include ``patient`` (4). On a dataset
of clips (manifest "sequence") the patient moves under the probe: ``lens_skin``, ``camera_in_patient`` and
``patient_depth`` take each frame's body pose (``T_world_body``), ``lens_skin`` checks every frame (the contact kept
throughout, one problem per clip).

The checks that need no image: :mod:`hupbench.datagen.dataset.verify_annotations`; how the per-frame checks
work: :mod:`hupbench.datagen.dataset.verify_frames`.
"""

from __future__ import annotations

import json
import math
import multiprocessing
import sys
import zipfile
from pathlib import Path

import numpy as np

from hupbench.core.contract import (
    ANNOTATIONS,
    CLINIC,
    MANIFEST,
    SPLITS,
    DamagedFileError,
    annotations_path,
    check_manifest,
    is_sequence,
    read_annotations,
    read_manifest,
    seg_labels,
    track_of,
)
from hupbench.core.input_checks import is_whole
from hupbench.core.processes import check_workers, workers_ignore_ctrl_c
from hupbench.datagen.dataset.verify_annotations import (
    check_geometry,
    check_grasps_file,
    check_look_at,
    check_manifest_extras,
    check_modalities,
    check_rows,
    check_split_floors,
    problem_detail,
)
from hupbench.datagen.dataset.verify_frames import _CONTEXT, _problem, check_frame
from hupbench.core.depth_sensor import SensorPreset


KINDS = ("count_mismatch", "missing_file", "damaged_file", "bad_annotations", "frame_ids", "manifest_mismatch",
         "undecodable_file", "image_format", "reprojection", "pose_mismatch", "look_at", "visible_not_on_hand",
         "marked_invisible", "empty_frame", "probe_depth", "image_shift", "mask_depth", "split_floors", "rgb_mismatch",
         "rgb_channels", "grasps_file", "lens_skin", "camera_in_patient", "hand_size", "patient_depth", "sensor_depth",
         "clip_continuity")
#: what verify leaves out on a dataset converted from another format (manifest "imported"), and why
IMPORTED_SKIPS = (
    ("pose_mismatch: the stored hand pose is the source's MANO parameters and the probe its own mesh; hupbench's "
     "hand and probe cannot rebuild the keypoints"),
    ("probe_depth, image_shift: they measure against a closed probe surface; the source's mesh is taken as "
     "published, unrepaired"),
    "look_at, rgb_channels: the source records no protocol and no forearm colour",
)
#: fewer frames than this are checked in this process (starting workers would take longer)
POOL_MIN_FRAMES = 64
#: annotation fields the per-frame checks use
FRAME_KEYS = ("frame_id", "keypoints_3d_cam", "keypoints_2d", "visible", "K", "T_cam_world", "background_id",
              "glove_id", "light_color", "grasp_index")


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
        return manifest, [_problem(None, None, "count_mismatch", problem_detail(exc, root / MANIFEST), MANIFEST)]


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
        return None, [_problem(split, None, "damaged_file", problem_detail(exc, path), rel)]
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
        problems.append(_problem(split, None, "bad_annotations", problem_detail(rejected, path), rel))
    return None, problems


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


def _check_geometry(ann: dict, split: str, manifest: dict, probe, world) -> list[dict]:
    """A split's checks of the labels against the stored pose and the camera's aim, on the manifest's track
    (the clinic track's with ``world``, its :class:`~hupbench.datagen.dataset.verify_clinic.ClinicGrasps` or None)."""
    if track_of(manifest) == CLINIC:
        from hupbench.datagen.dataset.verify_clinic import check_clinic_annotations, hand_spec_of

        problems = check_geometry(ann, split, stored_pose=world is not None, probe=probe,
                                  hand_spec=hand_spec_of(world)) \
            + check_clinic_annotations(ann, split, manifest["protocol"]["look_at"], world, probe)
        if is_sequence(manifest):
            from hupbench.datagen.dataset.verify_sequence import check_clips

            problems += check_clips(ann, split, manifest)
        return problems
    problems = check_geometry(ann, split, stored_pose=manifest.get("imported") is None, probe=probe)
    # datasets made before the manifest recorded a protocol have no look-at to check
    if "protocol" in manifest:
        problems += check_look_at(ann, split, manifest["protocol"]["look_at"])
    return problems


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
        without a training split), "image_shift" ({"median_px": [du, dv], "frames"}: the frames'
        median :func:`image_shift_px`, None when no frame allowed the measurement) and "grasps_sha256" (the
        manifest's, None where it records none).

    Raises:
        FileNotFoundError, ValueError: nothing to verify against (module docstring).
    """
    check_workers(workers)
    root = Path(root)
    manifest, problems = _read_manifest(root)
    check_manifest_extras(manifest, root)
    problems += check_modalities(root, manifest)
    skipped = []
    imported = manifest.get("imported")
    # the probe the frames show (a mesh probe's geometry is in the dataset's grasps.npz)
    from hupbench.datagen.dataset.grasps_file import probe_of_dataset

    probe = probe_of_dataset(root, manifest) if imported is None else None
    if imported is not None:
        skipped += IMPORTED_SKIPS
    track = track_of(manifest)
    world = None  # the clinic track's grasps with their subjects and patients
    if track == CLINIC:
        from hupbench.datagen.dataset.verify_clinic import read_clinic_grasps

        world, why = read_clinic_grasps(root)
        if why:
            skipped.append(f"pose_mismatch, lens_skin, camera_in_patient, hand_size, patient_depth: {why}")
    backgrounds, gloves, quality = None, None, _jpeg_quality(manifest)
    if "rgb" in manifest["modalities"] and "seg" in manifest["modalities"]:
        backgrounds, why = _load_backgrounds(manifest) if track != CLINIC else \
            (None, "the clinic track's room covers the backdrop")
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
        found, usable = check_rows(ann, split, manifest)
        problems += found
        ann = {k: v[usable] for k, v in ann.items()}
        annotations[split] = ann
        problems += _check_geometry(ann, split, manifest, probe, world)
        partners = _glove_partners(ann) if gloves is not None and len(gloves) > 1 else {}
        for i in range(len(ann["frame_id"])):
            row = {k: ann[k][i] for k in FRAME_KEYS + (("T_world_body",) if is_sequence(manifest) else ())}
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
    problems += check_grasps_file(root, annotations, manifest)
    for note in skipped:
        log(f"not checked: {note}")
    if imported is not None:
        log(f"imported ({imported.get('format')}): visibility checked with the depth's precision, "
            f"{1000 * imported['depth']['error_max_m']:.2f} mm")
    log(f"checking {len(jobs)} frames with {workers} worker(s)")
    recorded = manifest.get("depth_sensor")
    sensor = None if not isinstance(recorded, dict) else SensorPreset.from_parameters(recorded.get("parameters", {}))
    _CONTEXT.update(root=root, manifest=manifest, backgrounds=backgrounds, jpeg_quality=quality, probe=probe,
                    track=track, labels=seg_labels(track), clinic=world, sensor=sensor,
                    gloves=None if gloves is None else np.asarray(gloves, dtype=np.float64))
    try:
        frame_problems, shifts = _check_frames(jobs, workers, progress)
    finally:
        _CONTEXT.clear()
    problems += _collapse_image_size(frame_problems, len(jobs), tuple(manifest["image_size"]))
    by_kind = {kind: sum(p["kind"] == kind for p in problems) for kind in KINDS}
    image_shift = {"median_px": np.median(shifts, axis=0).tolist(), "frames": len(shifts)} if shifts else None
    return {"frames": len(jobs), "problems": problems, "by_kind": by_kind, "skipped": skipped, "ok": not problems,
            "split_floors": floors, "image_shift": image_shift, "grasps_sha256": manifest.get("grasps_sha256")}


def report_lines(result: dict, max_report: int) -> list[str]:
    """What ``hupbench verify`` prints of :func:`verify`'s ``result``: the first ``max_report`` problems, the
    images' shift against the labels, the grasps file's sha256, each split's floor and the verdict."""
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
    sha = result["grasps_sha256"]
    lines.append(f"  grasps.npz sha256: {sha}" if sha is not None else
                 "  grasps.npz sha256: not recorded (a manifest written before datasets recorded it)")
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

    names = (("nearest_train_frame_mm", "nearest training frame of any grasp and view"),
             ("nearest_train_grasp_mm", "nearest training grasp under the true camera"),
             ("nearest_train_view_mm", "nearest training view of the same grasp"),
             ("train_mean_mm", "mean training frame" if floor["floor_kind"] == "nearest_train_frame" else
              "mean training grasp"))
    parts = [f"{words} {mm(floor[key])}" for key, words in names if floor.get(key) is not None]
    return "; ".join(parts) + (f" (a model that only recalls training labels scores no better than the "
                               f"{floor['floor_kind']} one)")
