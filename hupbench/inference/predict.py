"""``hupbench predict``: 2D and 3D keypoints for new images with an exported ONNX model, without torch.

Only onnxruntime, numpy and OpenCV run here: a deployment needs neither PyTorch nor the training code.
An image is padded with mid-grey to a centred square and resized to the input (``PREPROCESSING``): padding,
unlike a centre crop, keeps a hand near the border in view, and a constant grey holds no mirrored copy of it.

Camera: without ``--K`` the image is assumed to come from the training camera K_input scaled to the
image ("assumed training camera"): the 3D points are the network's output as it is, which is what
``hupbench eval`` scores. With ``--K fx,fy,cx,cy`` of the original images ("user K") the points are moved
to the user's camera by :func:`hupbench.inference.user_camera.user_camera_points`.

Depth: a model exported from a run with ``data.reader.input_modalities=rgb+depth`` reads a depth map beside
each image, ``--depth DIR``: ``DIR/<image stem>.png``, single-channel 16-bit, of the image's size, metres =
value x ``--depth-scale-m`` (default the dataset's 0.1 mm), 0 where nothing was seen, padded with 0 and
resized to the nearest pixel (a dataset's ``<split>/rgb`` and ``<split>/depth`` folders pair up as they are).
A model that reads depth is refused without ``--depth``, an RGB model with it; an image whose depth map is
missing, of another size, 0 everywhere, or whose median depth lies outside what the model was trained on
(:meth:`hupbench.inference.image_statistics.ImageStatistics.check_depth`: a map in another unit) fails alone,
naming the file. Millimetre PNGs (Azure Kinect, HoloLens 2 research mode): ``--depth-scale-m 0.001``. The model file
names the depth camera its training read (``hupbench.depth_sensor``: ``none``, the renderer's clean z-buffer, or a
preset of :mod:`hupbench.core.depth_sensor`); predict says it, and warns of a depth map that camera would not give
(no invalid pixel at all, the mark of a z-buffer, or depths beyond its range or wrap).

Trust: ``keypoint_confidence`` (N,) in [0, 1] per image for a model with a per-keypoint confidence (HUPNet:
its heatmap's peak mass, :data:`hupbench.inference.model_file.CONFIDENCE`), null for a regression model (HOPE-Net,
ResNet), which has no such score; the document's ``keypoint_confidence`` says which and why. ``ood`` per image:
the out-of-distribution check of :mod:`hupbench.inference.image_statistics` (distance, threshold, flagged),
calibrated at export on the training frames; a flagged image gets one warning line, and its overlay a red
banner. A model file without the calibration has ``ood`` null and the document says so.

Videos: a video file (``.mp4``, ``.avi``, ``.mov``, ``.mkv``, ``.webm``) is read frame by frame
(:mod:`hupbench.inference.video`), each frame a record with its ``frame`` index and ``time_s``, in order, and its
overlays go into ``<stem>_overlay.mp4`` at the video's frame rate. ``predictions.json`` lists each video (path, fps,
frames decoded and declared, ok, error, overlay). A video OpenCV cannot open fails alone in one line; one that ends
before the frames its header declares keeps the frames that decode, and one line says what is missing. A video has no
depth maps: a model that reads depth takes a video's frames as images with ``--depth``. With ``--track
MIN_CUTOFF_HZ,BETA`` a video's frames are tracked: each frame's 3D keypoints go through a 1-euro filter
(:mod:`hupbench.inference.tracking`) carrying its state from the frames before, its 2D are their projection, and the
record keeps the per-frame prediction under ``untracked`` and the settings under ``tracking``; the overlay video
shows the tracked keypoints. ``hupbench eval`` on a split of clips chooses the settings on its validation split.

Ordered frames: with ``--track`` and ``--fps F`` the image files (a folder's in name order; names whose numbers say
another order, ``frame_10`` before ``frame_2``, are refused) are the frames of one sequence at F frames/s, each
record with its ``frame`` index and ``time_s`` = frame / F, tracked as a video's are; a model that fits (and so reads
``--depth``) also starts each frame's fits where they left the frame before (:func:`hupbench.fits.track_fits`: the
probe's pose), which makes them cheaper. Without ``--fps`` images are never tracked.

Outputs in ``OUT/``: ``predictions.json`` (written atomically, and last), with per image the path, ok or
error, the camera and its K, ``keypoints_2d_px`` (N, 2) original image pixels and ``keypoints_3d_m``
(N, 3) metres in the camera frame of that K, ``keypoint_confidence`` and ``ood``; and ``<stem>_overlay.png`` per
image (``<stem>_<k>_overlay.png`` when two inputs share a stem). A file that is no readable image gets an error in
its record and on stderr; the others are still processed. ``OUT`` may not be an input folder (the next run would
read the overlays back as images). Everything checkable is checked before any image is read. The output
folder is locked from the start of the run (before the model is loaded), so that a second run into it is
refused while the first one lasts; a run that fails while writing removes the overlays it wrote, so a folder
with a ``predictions.json`` holds one finished run, and a refused run leaves no folder it made.
"""
from __future__ import annotations

import contextlib
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from hupbench.core.camera import project_points
from hupbench.core.depth_sensor import PRESETS, depth_input_warnings
from hupbench.core.errors import BadTypeError, BadValueError, UserError
from hupbench.core.input_checks import check_int, check_number
from hupbench.core.io import OutputLock, check_writable, clean_stale_tmp, compact_json, write_bytes
from hupbench.core.draw import write_png
from hupbench.inference.image_statistics import image_statistics
from hupbench.inference.images import (
    IMAGE_SUFFIXES,
    PAD_VALUE,
    VIDEO_SUFFIXES,
    check_frame_order,
    expand_inputs,
    read_depth_png,
    read_image,
    to_uint8,
)
from hupbench.fits import after_network, check_fitted_probe, fits, track_fits
from hupbench.inference.model_file import (
    CONFIDENCE,
    NO_CONFIDENCE,
)
from hupbench.inference.overlay import draw_prediction
from hupbench.inference.video import OverlayVideo, VideoFrames, is_video
from hupbench.inference.tracking import OneEuroFilter, parse_track
from hupbench.inference.user_camera import check_user_K, keypoints_for_image, parse_intrinsics
from hupbench.inference.runtime import (
    OnnxModel,
    load_onnx_model,
    run_onnx_outputs,
)
from hupbench.input_geometry import InputGeometry, depth_channel, pad_and_resize

SCHEMA_VERSION = 4  # 2: keypoint_confidence and ood; 3: videos, and each record's frame and time_s; 4: tracking
DEFAULT_BATCH_SIZE = 16
#: metres per unit of a depth PNG unless ``--depth-scale-m`` says otherwise: the dataset's (0.1 mm)
DEFAULT_DEPTH_SCALE_M = 1e-4
_DECIMALS_M = 6  # 1 um: far below any model's error, keeps the JSON readable
_DECIMALS_PX = 3
_DECIMALS_K = 6
_DECIMALS_SCORE = 4
NO_CALIBRATION = ("the model file has no hupbench.image_statistics (exported before the check existed): "
                  "re-export its checkpoint with `hupbench export CKPT`")

PREPROCESSING = (
    "pad the H x W image to a centred L x L square (L = max(H, W), pad_left = (L - W) // 2, "
    "pad_top = (L - H) // 2, mid-grey 0.5), resize to S x S with cv2.INTER_AREA (s = S / L); "
    "pixel centres at integers: u = (u_in + 0.5) / s - 0.5 - pad_left, v = (v_in + 0.5) / s - 0.5 - pad_top"
)


@dataclass(frozen=True)
class PredictOptions:
    """What ``hupbench predict`` is asked to do, checked once where it enters.

    Attributes:
        model: ``.onnx`` file from ``hupbench export``.
        inputs: image files and/or folders (:func:`hupbench.inference.images.expand_inputs`).
        out_dir: output folder (created).
        K: the user's intrinsics of the original images, ``"fx,fy,cx,cy"`` or (3, 3), pixels; None assumes
            the training camera scaled to each image. Held as a (3, 3) float64 array.
        overlay: write ``<stem>_overlay.png`` per image.
        batch_size: images per onnxruntime call.
        progress: a progress bar with ETA on stderr for runs longer than 2 s.
        depth_dir: the depth maps of a model that reads depth, ``<image stem>.png`` each (module docstring).
        depth_scale_m: metres per unit of those PNGs, in (0, 1].
        track: a video's frames tracked with the 1-euro filter of these settings, ``"min_cutoff_hz,beta"`` (what
            ``hupbench eval`` chose on a split of clips) or {"min_cutoff_hz", "beta"}; None: each frame alone.
        fps: with ``track``, the image files are one sequence's frames at this rate, frames/s (module docstring);
            None: images are not tracked.
    """

    model: Path
    inputs: tuple[Path, ...]
    out_dir: Path = Path("predictions")
    K: Any = None
    overlay: bool = True
    batch_size: int = DEFAULT_BATCH_SIZE
    progress: bool = False
    depth_dir: Path | None = None
    depth_scale_m: float = DEFAULT_DEPTH_SCALE_M
    track: Any = None
    fps: float | None = None

    def __post_init__(self) -> None:
        if self.track is not None:
            object.__setattr__(self, "track", parse_track(self.track))
        if self.fps is not None:
            if self.track is None:
                raise BadValueError("--fps is the frame rate of image files tracked as a sequence: give --track too")
            check_number(self.fps, "--fps (frames per second of the image files)", 0.0, 1000.0, low_open=True)
        if isinstance(self.inputs, (str, Path)):
            raise BadTypeError("inputs must be a list of paths, got a single path")
        check_int(self.batch_size, "batch_size (--batch-size)", low=1)
        check_number(self.depth_scale_m, "--depth-scale-m (metres per PNG unit)", 0.0, 1.0, low_open=True)
        if self.depth_dir is not None:
            if not Path(self.depth_dir).is_dir():
                raise BadValueError(f"--depth {self.depth_dir} is not a folder (it holds one <image stem>.png per image)")
            object.__setattr__(self, "depth_dir", Path(self.depth_dir))
        K = self.K
        if K is not None:
            K = parse_intrinsics(K) if isinstance(K, str) else check_user_K(K, "K")
        out_dir = check_writable(self.out_dir, "output folder (--out)")  # '' would name the current folder
        inputs = tuple(Path(i) for i in self.inputs)
        folder = next((i for i in inputs if i.is_dir() and i.resolve() == out_dir.resolve()), None)
        if folder is not None:
            raise BadValueError(f"--out {out_dir} is the input folder {folder}: the next run would read this run's "
                                "overlays back as images; choose another output folder")
        object.__setattr__(self, "model", Path(self.model))
        object.__setattr__(self, "inputs", inputs)
        object.__setattr__(self, "out_dir", out_dir)
        object.__setattr__(self, "K", K)


# ---------------------------------------------------------------- images


def preprocess(image_rgb: np.ndarray, input_size: int) -> tuple[np.ndarray, InputGeometry]:
    """(H, W, 3) float32 RGB in [0, 1] -> the (3, S, S) float32 model input and its :class:`InputGeometry`."""
    square, geometry = pad_and_resize(image_rgb, input_size, PAD_VALUE)
    return np.ascontiguousarray(square.transpose(2, 0, 1), dtype=np.float32), geometry


def preprocess_depth(depth: np.ndarray, scale_m: float, input_size: int) -> np.ndarray:
    """(H, W) uint16 depth PNG values -> the (1, S, S) float32 depth input: metres (``depth * scale_m``, the
    model's depth channel), padded like the image with 0 (no surface) and resized to the nearest pixel."""
    import cv2

    square, _ = pad_and_resize(depth_channel(depth, scale_m), input_size, 0.0, cv2.INTER_NEAREST)
    return np.ascontiguousarray(square[None], dtype=np.float32)


# ---------------------------------------------------------------- run


def _plain(values: np.ndarray, decimals: int) -> list:
    """Rounded nested lists; a non-finite value becomes null so that the file stays valid JSON."""
    rounded = np.round(np.asarray(values, dtype=np.float64), decimals) + 0.0  # + 0.0 turns -0.0 into 0.0
    return np.where(np.isfinite(rounded), rounded, None).tolist()


def _stderr(message: str) -> None:
    print(message, file=sys.stderr)


def run_predict(options: PredictOptions, log: Callable[[str], None] = _stderr) -> dict[str, Any]:
    """Predict 2D and 3D keypoints for image files; write ``predictions.json`` and overlays (module
    docstring). ``log`` receives per-file errors and notes.

    Returns:
        ``{"json": Path, "images": int, "ok": int, "failed": int, "overlays": [Path], "skipped": [...],
        "flagged": [paths of images the out-of-distribution check flagged], "records": [per-image dicts as in
        the JSON]}``.
    """
    made = not options.out_dir.exists()
    try:
        with OutputLock(options.out_dir, "predict"):
            return _run_locked(options, log)
    finally:
        if made:  # a refused or failed run leaves no folder it made; rmdir removes only an empty one
            with contextlib.suppress(OSError):
                options.out_dir.rmdir()


def _open_checked(options: PredictOptions) -> tuple[OnnxModel, list[Path], list[dict[str, str]]]:
    """The model and the image files of a run, and the folder entries left out, checked against each other."""
    model = load_onnx_model(options.model)
    if model.reads_depth != (options.depth_dir is not None):
        raise BadValueError(f"{model.path} reads RGB and depth (hupbench.input_modalities rgb+depth): pass --depth "
                            "DIR with a 16-bit depth PNG per image, named by the image's stem" if model.reads_depth
                            else f"{model.path} reads RGB only; --depth is for a model trained with "
                            "data.reader.input_modalities=rgb+depth")
    if fits(model.model_config):  # such a model reads depth: --depth is given
        dataset = options.depth_dir.resolve().parent.parent  # the dataset, for a dataset's <split>/depth folder
        if (dataset / "manifest.json").is_file():
            from hupbench.core.contract import read_manifest

            check_fitted_probe(model.model_config, read_manifest(dataset).get("probe"), str(dataset / "manifest.json"),
                               model.fit_probe)
    files, skipped = expand_inputs(options.inputs)
    if not files:
        raise BadValueError(f"no image or video files ({', '.join(IMAGE_SUFFIXES + VIDEO_SUFFIXES)}) in "
                            f"{', '.join(str(i) for i in options.inputs)}"
                            + (f" ({len(skipped)} other entries skipped)" if skipped else ""))
    videos = [f for f in files if is_video(f)]
    if options.fps is not None:
        if len(videos) == len(files):
            raise BadValueError("--fps is the frame rate of image files tracked as a sequence, and the inputs hold only "
                                "videos, which carry their own")
        check_frame_order([f for f in files if not is_video(f)])
    if videos and model.reads_depth:
        raise BadValueError(f"{videos[0]} is a video, which holds no depth maps, and {model.path} reads RGB and depth: "
                            "give its frames as images in a folder, with their depth maps in --depth DIR")
    return model, files, skipped


def _run_locked(options: PredictOptions, log: Callable[[str], None]) -> dict[str, Any]:
    """:func:`run_predict` once the output folder is locked."""
    from tqdm import tqdm

    model, files, skipped = _open_checked(options)
    out_dir = options.out_dir
    names = list(model.keypoint_names)
    records: list[dict[str, Any]] = []
    videos: list[dict[str, Any]] = []
    overlays: list[Path] = []
    used_stems: set[str] = set()
    finished = False
    # on stderr, and only once the run has lasted 2 s
    bar = tqdm(total=len(files), unit="image", desc="hupbench predict", disable=not options.progress, delay=2.0,
               dynamic_ncols=True, file=sys.stderr)
    if options.progress and log is _stderr:
        def log(line: str) -> None:
            # above the bar once it shows; tqdm.write before that would print a stray carriage return
            if bar.last_print_t >= bar.start_t + bar.delay:
                bar.write(line, file=sys.stderr)
            else:
                _stderr(line)
    for item in skipped:
        log(f"hupbench predict: note: {item['path']}: {item['reason']}")
    frames = None if options.fps is None else _Track(OneEuroFilter(**options.track))   # the image files, tracked
    if model.reads_depth and model.depth_sensor is not None:
        log(f"hupbench predict: note: {model.path.name} was trained on "
            + ("the renderer's clean depth (no sensor model)" if model.depth_sensor not in PRESETS else
               f"the depth of a {model.depth_sensor} camera (hupbench.core.depth_sensor)"))
    try:
        clean_stale_tmp(out_dir, recursive=False)
        # the folder's predictions.json must describe the overlays beside it: an earlier run's goes
        # now, and this run's is written last
        (out_dir / "predictions.json").unlink(missing_ok=True)
        overlay_dir = out_dir if options.overlay else None
        stills: list[Path] = []
        for path in [*files, None]:  # the image files in runs between videos, in the inputs' order
            if path is not None and not is_video(path):
                stills.append(path)
                continue
            for start in range(0, len(stills), options.batch_size):
                chunk = [_empty_record(p, names, model.run_name) for p in stills[start:start + options.batch_size]]
                if frames is not None:
                    for record in chunk:
                        record.update(frame=frames.count, time_s=round(frames.count / options.fps, _DECIMALS_M))
                        frames.count += 1
                _predict_batch(model, chunk, options, overlay_dir, used_stems, overlays, log, frames)
                records.extend(chunk)
                bar.update(len(chunk))
            stills = []
            if path is not None:
                videos.append(_predict_video(model, path, options, overlay_dir, used_stems, overlays, records, log))
                bar.update(1)
        json_path = write_bytes(out_dir / "predictions.json",
                                (compact_json(_document(model, records, videos, skipped)) + "\n").encode())
        finished = True
    finally:
        bar.close()
        if not finished:  # a full disk, a model that fails on a later batch, an interrupt
            for path in overlays:
                with contextlib.suppress(OSError):  # the error that stopped the run is the one to report
                    path.unlink(missing_ok=True)
    failed = sum(not r["ok"] for r in records)
    flagged = [_where(r) for r in records if r["ood"] is not None and r["ood"]["flagged"]]
    return {"json": json_path, "images": len(records), "ok": len(records) - failed, "failed": failed,
            "overlays": overlays, "skipped": skipped, "flagged": flagged, "records": records, "videos": videos}


def _document(model: OnnxModel, records: list[dict[str, Any]], videos: list[dict[str, Any]],
              skipped: list[dict[str, str]]) -> dict[str, Any]:
    """The content of ``predictions.json``."""
    failed = sum(not r["ok"] for r in records)
    return {
        "schema_version": SCHEMA_VERSION,
        "tool": "hupbench predict",
        "model": {"path": str(model.path), "sha256": model.sha256, "run_name": model.run_name,
                  "git_commit": model.git_commit, "input_size": model.input_size, "K_input": model.K_input.tolist(),
                  "input_modalities": model.input_modalities},
        "keypoint_names": list(model.keypoint_names),
        "skeleton_edges": [list(e) for e in model.skeleton_edges],
        "preprocessing": PREPROCESSING,
        "keypoint_confidence": ({"available": True, "definition": CONFIDENCE.get(model.model_config.get("name"),
                                                                             "the model's own, in [0, 1]")}
                                if model.has_confidence else {"available": False, "reason": NO_CONFIDENCE}),
        "ood_check": ({"available": True, **model.image_statistics.describe(),
                       "flagged": sum(r["ood"] is not None and r["ood"]["flagged"] for r in records)}
                      if model.image_statistics is not None else {"available": False, "reason": NO_CALIBRATION}),
        "counts": {"images": len(records), "ok": len(records) - failed, "failed": failed},
        "skipped": skipped,
        "videos": videos,
        "images": records,
    }


def _predict_batch(model: OnnxModel, chunk_records: list[dict[str, Any]], options: PredictOptions,
                   overlay_dir: Path | None, used_stems: set[str], overlays: list[Path], log,
                   track: _Track | None = None) -> None:
    """Read, predict and record one batch of image files in place: a bad image's record gets its error (and
    the log a line), a good one its keypoints and, with ``overlay_dir``, its overlay (appended to
    ``overlays``); with ``track``, as the next frames of its sequence."""
    loaded = []
    for record in chunk_records:
        notes: list[str] = []
        try:
            image = read_image(record["path"], notes)
            depth = None
            if model.reads_depth:
                record["depth"] = str(options.depth_dir / f"{Path(record['path']).stem}.png")
                depth = read_depth_png(record["depth"], (image.shape[1], image.shape[0]))
                if model.image_statistics is not None:
                    model.image_statistics.check_depth(depth, options.depth_scale_m, record["depth"])
                if model.depth_sensor in PRESETS:
                    for warning in depth_input_warnings(depth * options.depth_scale_m, PRESETS[model.depth_sensor]):
                        log(f"hupbench predict: warning: {record['depth']}: {warning}")
        except UserError as exc:  # a bad image fails alone: its record and the log say why
            record["error"] = str(exc)
            log(f"hupbench predict: error: {exc}")
            continue
        for note in notes:
            log(f"hupbench predict: note: {record['path']}: {note}")
        loaded.append((record, image, depth))

    def overlay(record: dict[str, Any], drawn: np.ndarray) -> None:
        stem = _unique_stem(Path(record["path"]).stem, used_stems)
        overlays.append(write_png(overlay_dir / f"{stem}_overlay.png", drawn))
        record["overlay"] = str(overlays[-1])

    _predict_loaded(model, loaded, options, overlay if overlay_dir is not None else None, log, track)


@dataclass
class _Track:
    """What a tracked sequence (a video, or the ordered image files) carries from frame to frame: the 1-euro
    filter, the probe's pose where the fits left the frame before (:func:`hupbench.fits.track_fits`), and the
    frames counted so far."""

    filter: OneEuroFilter
    probe_start: np.ndarray | None = None
    count: int = 0


def _predict_loaded(model: OnnxModel, loaded: list[tuple[dict[str, Any], np.ndarray, np.ndarray | None]],
                    options: PredictOptions, overlay: Callable[[dict[str, Any], np.ndarray], None] | None,
                    log, track: _Track | None = None) -> None:
    """Predict read images (each (record, (H, W, 3) float RGB in [0, 1], depth map or None)) in one onnxruntime
    call and fill their records; ``overlay(record, drawn RGB uint8)`` takes each drawn prediction (None: none
    drawn); ``track``: the images are the next frames of that sequence, in order."""
    if not loaded:
        return
    names = list(model.keypoint_names)
    prepared = []
    for record, image, depth in loaded:
        model_input, geometry = preprocess(image, model.input_size)
        depth_input = None if depth is None else preprocess_depth(depth, options.depth_scale_m, model.input_size)
        prepared.append((record, image, model_input, geometry, depth_input))
    depth = np.stack([item[4] for item in prepared]) if model.reads_depth else None
    images = np.stack([item[2] for item in prepared])
    outputs = run_onnx_outputs(model, images, depth)  # (B, C, S, S) -> (B, N, *)
    points2d, points3d, confidence = outputs["points2d"], outputs["points3d"], outputs.get("confidence")
    segmentation = outputs.get("segmentation")
    if fits(model.model_config) and track is None:
        points2d, points3d = after_network(model.model_config, points2d, points3d,
                                           np.concatenate([images, depth], axis=1), model.K_input, *model.fit_settings,
                                           fitted=model.fit_probe, segmentation=segmentation)
    elif fits(model.model_config):   # frame by frame, each started where the fits left the frame before
        points2d, points3d = np.array(points2d, np.float64), np.array(points3d, np.float64)
        for b in range(len(images)):
            points2d[b:b + 1], points3d[b:b + 1], track.probe_start = track_fits(
                model.model_config, points2d[b:b + 1], points3d[b:b + 1],
                np.concatenate([images[b:b + 1], depth[b:b + 1]], axis=1), model.K_input, track.probe_start,
                *model.fit_settings, fitted=model.fit_probe,
                segmentation=None if segmentation is None else segmentation[b:b + 1])
    K_user = options.K
    for b, (record, image, _, geometry, _) in enumerate(prepared):
        if not (np.all(np.isfinite(points2d[b])) and np.all(np.isfinite(points3d[b]))):
            record["error"] = f"{_where(record)}: the model's output is not finite (NaN or inf)"
            log(f"hupbench predict: error: {record['error']}")
            continue
        result = keypoints_for_image(points2d[b], points3d[b], geometry, model.K_input, K_user, model.reads_depth)
        ood = None
        if model.image_statistics is not None:
            distance = float(model.image_statistics.distance(image_statistics(image, model.input_size)[None])[0])
            ood = {"distance": round(distance, _DECIMALS_SCORE), "flagged": distance > model.image_statistics.threshold,
                   "threshold": round(model.image_statistics.threshold, _DECIMALS_SCORE)}
            if ood["flagged"]:
                log(f"hupbench predict: warning: {_where(record)} looks unlike the training images (image-statistics "
                    f"distance {distance:.2f} > {model.image_statistics.threshold:.2f}, percentile "
                    f"{model.image_statistics.percentile:g} of "
                    "the calibration frames): its keypoints are likely wrong")
        record.update(
            ok=True, image_size={"width": geometry.width, "height": geometry.height},
            camera=result["camera"], K=_plain(result["K"], _DECIMALS_K),
            K_model_input=_plain(result["K_model_input"], _DECIMALS_K), input_geometry=geometry.as_dict(),
            keypoints_2d_px=_plain(result["keypoints_2d_px"], _DECIMALS_PX),
            keypoints_3d_m=_plain(result["keypoints_3d_m"], _DECIMALS_M),
            keypoint_confidence=None if confidence is None else _plain(confidence[b], _DECIMALS_SCORE), ood=ood,
        )
        if track is not None:
            _track(record, track.filter, options.track)
            if overlay is not None:
                overlay(record, _draw_record(model, record, image))
        elif overlay is not None:
            overlay(record, draw_prediction(to_uint8(image), result["keypoints_2d_px"], names, model.skeleton_edges,
                                            None if confidence is None else confidence[b],
                                            "unlike the training images" if ood is not None and ood["flagged"]
                                            else None))


def _where(record: dict[str, Any]) -> str:
    """An input as the log names it: its path, and a video frame's index."""
    return record["path"] if record["frame"] is None else f"{record['path']} frame {record['frame']}"


def _predict_video(model: OnnxModel, path: Path, options: PredictOptions, overlay_dir: Path | None,
                   used_stems: set[str], overlays: list[Path], records: list[dict[str, Any]], log) -> dict[str, Any]:
    """Predict every frame of one video in order (:mod:`hupbench.inference.video`): a record per frame appended to
    ``records`` (its ``frame`` and ``time_s``), with ``overlay_dir`` the overlay video ``<stem>_overlay.mp4`` at
    the video's rate (a frame whose prediction failed shows without keypoints). A video that cannot be read
    fails alone, one line naming it; a truncated one keeps the frames that decode and says what is missing.

    Returns:
        The video's entry of ``predictions.json``: path, fps, frames (decoded), frames_declared, ok, error,
        overlay.
    """
    names = list(model.keypoint_names)
    summary = {"path": str(path), "fps": None, "frames": 0, "frames_declared": None, "ok": False, "error": None,
               "overlay": None}
    try:
        frames = VideoFrames(path)
    except UserError as exc:
        summary["error"] = str(exc)
        log(f"hupbench predict: error: {exc}")
        return summary
    summary.update(fps=frames.fps, frames_declared=frames.declared_frames or None)
    writer = None
    if overlay_dir is not None:
        stem = _unique_stem(path.stem, used_stems)
        writer = OverlayVideo(overlay_dir / f"{stem}_overlay.mp4", frames.fps, (frames.width, frames.height))
    tracker = None if options.track is None else _Track(OneEuroFilter(**options.track))
    try:
        batch: list[tuple[dict[str, Any], np.ndarray, None]] = []

        def flush() -> None:
            drawn: dict[int, np.ndarray] = {}

            def keep(record: dict[str, Any], image: np.ndarray) -> None:
                drawn[record["frame"]] = image

            _predict_loaded(model, batch, options, keep if writer is not None else None, log, tracker)
            for record, image, _ in batch:
                if writer is not None:
                    writer.write(drawn.get(record["frame"], to_uint8(image)))
                records.append(record)
            batch.clear()

        for index, time_s, image in frames:
            record = _empty_record(path, names, model.run_name)
            record.update(frame=index, time_s=round(time_s, _DECIMALS_M))
            batch.append((record, image, None))
            if len(batch) == options.batch_size:
                flush()
        flush()
        if writer is not None and frames.decoded:
            overlays.append(writer.close())
            summary["overlay"] = str(overlays[-1])
            for record in records[-frames.decoded:]:
                record["overlay"] = summary["overlay"]
        elif writer is not None:
            writer.discard()
    except BaseException:
        if writer is not None:
            writer.discard()
        raise
    summary["frames"] = frames.decoded
    problem = frames.truncated
    if problem is not None:
        summary["error"] = f"{path}: {problem}"
        log(f"hupbench predict: error: {summary['error']}")
    summary["ok"] = problem is None
    return summary


def _track(record: dict[str, Any], tracker: OneEuroFilter, settings: dict[str, float]) -> None:
    """A video frame's record tracked in place: its 3D keypoints through the video's filter (state carried from the
    frames before), its 2D the tracked points' projection with the frame's K; the per-frame prediction kept under
    "untracked", the settings under "tracking"."""
    points = tracker(np.asarray(record["keypoints_3d_m"], np.float64), record["time_s"])
    record["untracked"] = {"keypoints_2d_px": record["keypoints_2d_px"], "keypoints_3d_m": record["keypoints_3d_m"]}
    record["tracking"] = {"filter": "1-euro", **settings}
    record["keypoints_3d_m"] = _plain(points, _DECIMALS_M)
    record["keypoints_2d_px"] = _plain(project_points(points, np.asarray(record["K"], np.float64), behind="nan"),
                                       _DECIMALS_PX)


def _draw_record(model: OnnxModel, record: dict[str, Any], image: np.ndarray) -> np.ndarray:
    """The overlay of a record's keypoints (as recorded) on its image."""
    confidence = record["keypoint_confidence"]
    ood = record["ood"]
    return draw_prediction(to_uint8(image), np.asarray(record["keypoints_2d_px"], np.float64),
                           list(model.keypoint_names), model.skeleton_edges,
                           None if confidence is None else np.asarray(confidence, np.float64),
                           "unlike the training images" if ood is not None and ood["flagged"] else None)


def _empty_record(path: Path, names: list[str], run_name: str) -> dict[str, Any]:
    """The JSON record of one input before (or without) a prediction: every key present, values null."""
    return {"path": str(path), "frame": None, "time_s": None, "depth": None, "ok": False, "error": None,
            "image_size": None, "camera": None, "K": None,
            "K_model_input": None, "input_geometry": None, "keypoint_names": names, "keypoints_2d_px": None,
            "keypoints_3d_m": None, "keypoint_confidence": None, "ood": None, "run_name": run_name, "overlay": None}


def _unique_stem(stem: str, used: set[str]) -> str:
    """``stem``, or ``stem_2``, ``stem_3``, ... when an earlier input already had that stem."""
    candidate, k = stem, 1
    while candidate in used:
        k += 1
        candidate = f"{stem}_{k}"
    used.add(candidate)
    return candidate
