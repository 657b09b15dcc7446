"""``hupbench predict``: 2D and 3D keypoints for new images with an exported ONNX model, without torch.

Only onnxruntime, numpy and OpenCV run here (plus the torch-free ``datagen.keypoints``,
``datagen.render.draw`` and ``datagen.io``), so a deployment needs neither PyTorch nor the training code.

Model: an ``.onnx`` file written by ``hupbench export`` (the ONNX contract in the notes): input
``image`` (B, 3, S, S) float32 RGB in [0, 1]; outputs ``points2d`` (B, N, 2) normalised [-1, 1]
coordinates of the input image and ``points3d`` (B, N, 3) metres in the OpenCV camera frame of the
model-input camera ``K_input``; metadata ``hupbench.*`` (input size, K_input, keypoint names,
skeleton edges, run name). A file without that metadata is refused.

Images: PNG or JPEG, recognised by content (not by name), from MIN_IMAGE_SIDE (16) px on the
shorter side to MAX_IMAGE_SIDE (8192) px on the longer side. Smaller images hold too few pixels for 29
keypoints; larger ones are refused from their header, before decoding, because the padded square
would need gigabytes (a 20000 x 20000 PNG decodes into 1.2 GB, 4.8 GB as float32): downscale them
first. 8- and 16-bit samples are scaled to [0, 1]; a grey image becomes three equal channels; an
alpha channel is composited over the padding grey (so transparent areas look like the padding to the
network); JPEG EXIF orientation is applied (OpenCV's ``IMREAD_COLOR``). What libpng and libjpeg
print about a damaged file does not reach the terminal: it becomes part of that file's error, or a
note naming the file when the image still decodes whole (e.g. extraneous bytes in a JPEG); a JPEG
whose data end early ("premature end of data segment", decoded with its lower part grey) is refused.

Geometry (pad to square, then resize):
    An H x W image is padded to a centred L x L square, L = max(H, W), with
    pad_left = (L - W) // 2 columns on the left and pad_top = (L - H) // 2 rows on top, filled
    with mid-grey (0.5), then resized to S x S with ``cv2.INTER_AREA``, scale s = S / L.
    Why pad and not centre-crop: padding keeps every pixel, so a hand or probe near the border of
    a wide photo stays in view and gets keypoints instead of being cut off, and the predictions
    can land anywhere on the original image; the price is fewer input pixels on the subject. The
    padding is a constant grey, not reflected content, so that it holds no mirrored copy of a hand.
    With pixel centres at integers (OpenCV; as ``datagen.camera.resize_intrinsics``):
        u_in = (u + pad_left + 0.5) * s - 0.5        v_in = (v + pad_top + 0.5) * s - 0.5
        u    = (u_in + 0.5) / s - 0.5 - pad_left    v    = (v_in + 0.5) / s - 0.5 - pad_top
    and from the model's normalised output (x_n = (2 u_in + 1) / S - 1):
        u = (x_n + 1) * L / 2 - 0.5 - pad_left      v = (y_n + 1) * L / 2 - 0.5 - pad_top.
    Intrinsics follow the same map: fx_in = fx * s, cx_in = (cx + pad_left + 0.5) * s - 0.5
    (and fy, cy with pad_top).

Camera:
    The network's 3D output is for its training camera K_input at the model input. Without
    ``--K`` the image is assumed to come from that camera scaled to the image: the reported K is
    K_input mapped back to the original pixels (the inverse of the map above) and the 3D points
    are the network's output as it is ("camera": "assumed training camera"); they are what
    ``hupbench eval`` scores. With ``--K fx,fy,cx,cy`` of the original image ("camera": "user K"),
    the user's camera at the model input is K_user_in (the map above). The network judges depth
    from the object's size in pixels, so a point it sees at an input pixel with focal f_train lies,
    through a lens of focal f_user_in, at depth z_user = z * f_user_in / f_train (with
    fx != fy the ratio is the geometric mean sqrt(fx_user_in / fx_train * fy_user_in / fy_train));
    x and y are re-derived by back-projecting the 2D prediction through K_user_in at that depth, so
    the reported 3D points project through the user's K exactly onto the reported 2D points.
    One ``--K`` applies to every image of the call.

Outputs (``OUT/``): ``predictions.json`` (written atomically, and last) with, per image, the path, ok/error,
image size, the camera and its K (original image pixels), the keypoint names, ``keypoints_2d_px``
(N, 2) original image pixels (from ``points2d``), ``keypoints_3d_m`` (N, 3) metres in the camera
frame of that K, and the model's run name; and ``OUT/<stem>_overlay.png`` per image (the hand
skeleton and the probe box on the original image; ``<stem>_<k>_overlay.png`` when two inputs share
a stem). A file that cannot be read as an image gets an error in its record and on stderr; the
others are still processed.

Refused before anything is written (one error line): a model that is missing, empty, not ONNX (a
PyTorch checkpoint is named as one), without hupbench metadata, whose metadata disagree with its
graph (input size, keypoint count) or whose graph fails on the input size its metadata declare;
``--K`` that is not four finite numbers with 0 < fx, fy <= MAX_FOCAL_PX and |cx|, |cy| <= MAX_FOCAL_PX;
a batch size below 1; an ``--out`` that is a file or lies on a read-only file system; inputs with no
image file. Writing: stale temporary files of killed runs are removed, an earlier run's
``predictions.json`` is removed before the first new file is written, and a run that fails while
writing (a full disk: ``no space left on MOUNT writing FILE``) removes the overlays it wrote, so a
folder with a ``predictions.json`` always holds one finished run.
"""
from __future__ import annotations

import contextlib
import hashlib
import json
import os
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any
import onnxruntime as ort
from onnxruntime.capi import onnxruntime_pybind11_state as ort_errors

import cv2
import numpy as np

from datagen.render.draw import write_png
from datagen.input_checks import check_int, check_shape
from datagen.io import clean_stale_tmp, write_bytes
from hupbench.inference.model_file import InputGeometry, check_intrinsics, check_io_shapes, read_metadata
from hupbench.inference.overlay import draw_prediction
from hupbench.inference.images import IMAGE_SUFFIXES, PAD_VALUE, expand_inputs, read_image, to_uint8
from datagen.errors import BadTypeError, BadValueError, MissingFileError, NotWritableError, RunFailedError


SCHEMA_VERSION = 1
DEFAULT_BATCH_SIZE = 16
# a focal length or principal point beyond a million pixels is a typo (1e6 px on a 4000 px photo is a 0.2
# degree field of view) and 1e308 overflows the 3D points to infinity
MAX_FOCAL_PX = 1e6
CAMERA_ASSUMED = "assumed training camera"
CAMERA_USER = "user K"
_DECIMALS_M = 6  # 1 um: far below any model's error, keeps the JSON readable
_DECIMALS_PX = 3
_DECIMALS_K = 6
# onnxruntime raises its own exception types (not RuntimeError) for unreadable or invalid models
_ORT_LOAD_ERRORS = (ort_errors.Fail, ort_errors.InvalidProtobuf, ort_errors.InvalidGraph,
                    ort_errors.InvalidArgument, ort_errors.NoSuchFile, ort_errors.NotImplemented)
_ORT_RUN_ERRORS = (ort_errors.Fail, ort_errors.InvalidArgument, ort_errors.RuntimeException,
                   ort_errors.NotImplemented, ort_errors.EPFail)
_ZIP_MAGIC = b"PK\x03\x04"  # torch.save's format since PyTorch 1.6
_PICKLE_MAGIC = b"\x80\x02"  # torch.save's legacy format

PREPROCESSING = (
    "pad the H x W image to a centred L x L square (L = max(H, W), pad_left = (L - W) // 2, "
    "pad_top = (L - H) // 2, mid-grey 0.5), resize to S x S with cv2.INTER_AREA (s = S / L); "
    "pixel centres at integers: u = (u_in + 0.5) / s - 0.5 - pad_left, v = (v_in + 0.5) / s - 0.5 - pad_top"
)


# ---------------------------------------------------------------- camera


def parse_intrinsics(text: str) -> np.ndarray:
    """Parse ``--K fx,fy,cx,cy`` (pixels of the original image) into a (3, 3) matrix.

    Args:
        text: four comma-separated numbers, e.g. ``"480,480,320,240"``.

    Returns:
        (3, 3) float64 K.
    """
    if not isinstance(text, str):
        raise BadTypeError(f"--K must be a string 'fx,fy,cx,cy', got {type(text).__name__}")
    parts = [p.strip() for p in text.split(",")]
    try:
        fx, fy, cx, cy = (float(p) for p in parts)
    except ValueError:
        raise BadValueError(f"--K must be four numbers 'fx,fy,cx,cy' (pixels), got {text!r}") from None
    return check_user_K([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]], "--K")


def check_user_K(K: Any, name: str = "K") -> np.ndarray:
    """A user's (3, 3) intrinsics, pixels of the original image: finite, 0 < fx, fy <= MAX_FOCAL_PX,
    |cx|, |cy| <= MAX_FOCAL_PX (beyond that a value is a typo; see the constant)."""
    K = check_intrinsics(K, name)
    if K[0, 0] > MAX_FOCAL_PX or K[1, 1] > MAX_FOCAL_PX:
        raise BadValueError(f"{name}: fx and fy must be in (0, {MAX_FOCAL_PX:g}] pixels, got fx={K[0, 0]:g}, "
                         f"fy={K[1, 1]:g}")
    if abs(K[0, 2]) > MAX_FOCAL_PX or abs(K[1, 2]) > MAX_FOCAL_PX:
        raise BadValueError(f"{name}: cx and cy must be in [-{MAX_FOCAL_PX:g}, {MAX_FOCAL_PX:g}] pixels, got "
                         f"cx={K[0, 2]:g}, cy={K[1, 2]:g}")
    return K


def user_camera_points(uv_in: np.ndarray, points3d_train: np.ndarray, K_train: np.ndarray,
                       K_user_in: np.ndarray) -> np.ndarray:
    """3D keypoints for the user's camera from a network trained with another camera.

    The network sees pixels; it infers depth from apparent size, which it learned for focal
    f_train. The same pixels through focal f_user mean depth z * f_user / f_train. The point
    then lies on the ray of its 2D prediction through K_user_in.

    Convention: all cameras share the OpenCV camera frame axes; K's are of the model input image.

    Args:
        uv_in: (N, 2) float, predicted 2D keypoints, model-input pixels.
        points3d_train: (N, 3) float, metres, the network's 3D output (camera K_train).
        K_train: (3, 3) intrinsics the network was trained with (K_input), model-input pixels.
        K_user_in: (3, 3) the user's intrinsics mapped to the model input.

    Returns:
        (N, 3) float64, metres, OpenCV camera frame of the user's camera.
    """
    uv_in = check_shape(np.asarray(uv_in, dtype=np.float64), ("N", 2), "uv_in")
    points3d_train = check_shape(np.asarray(points3d_train, dtype=np.float64), (len(uv_in), 3), "points3d_train")
    K_train = check_intrinsics(K_train, "K_train")
    K_user_in = check_intrinsics(K_user_in, "K_user_in")
    focal_ratio = np.sqrt((K_user_in[0, 0] / K_train[0, 0]) * (K_user_in[1, 1] / K_train[1, 1]))
    z = points3d_train[:, 2] * focal_ratio
    x = (uv_in[:, 0] - K_user_in[0, 2]) * z / K_user_in[0, 0]
    y = (uv_in[:, 1] - K_user_in[1, 2]) * z / K_user_in[1, 1]
    return np.stack([x, y, z], axis=1)


# ---------------------------------------------------------------- images


def preprocess(image_rgb: np.ndarray, input_size: int) -> tuple[np.ndarray, InputGeometry]:
    """Pad an image to a centred square and resize it to the model input (module docstring).

    Args:
        image_rgb: (H, W, 3) float32 RGB in [0, 1].
        input_size: S, pixels.

    Returns:
        (3, S, S) float32 RGB in [0, 1], the model input; and its :class:`InputGeometry`.
    """
    image_rgb = np.asarray(image_rgb)
    if image_rgb.ndim != 3 or image_rgb.shape[2] != 3 or image_rgb.dtype != np.float32:
        raise BadValueError(f"image_rgb must be (H, W, 3) float32, got {image_rgb.shape} {image_rgb.dtype}")
    height, width = image_rgb.shape[:2]
    geometry = InputGeometry(width=width, height=height, input_size=input_size)
    pad_bottom = geometry.side - height - geometry.pad_top
    pad_right = geometry.side - width - geometry.pad_left
    square = cv2.copyMakeBorder(image_rgb, geometry.pad_top, pad_bottom, geometry.pad_left, pad_right,
                                cv2.BORDER_CONSTANT, value=(PAD_VALUE, PAD_VALUE, PAD_VALUE))
    if geometry.side != input_size:
        square = cv2.resize(square, (input_size, input_size), interpolation=cv2.INTER_AREA)
    return np.ascontiguousarray(square.transpose(2, 0, 1), dtype=np.float32), geometry


# ---------------------------------------------------------------- model


@dataclass(frozen=True)
class PredictModel:
    """An ONNX keypoint model with its hupbench metadata.

    Attributes:
        path: the .onnx file.
        session: onnxruntime session (CPUExecutionProvider).
        input_size: S, pixels.
        K_input: (3, 3) intrinsics of the model input image, the camera of the 3D output.
        keypoint_names: N names.
        skeleton_edges: pairs (i, j) of keypoint indices.
        run_name: the training run's name.
        git_commit: commit the model was exported from.
        sha256: hash of the .onnx file.
    """

    path: Path
    session: ort.InferenceSession
    input_size: int
    K_input: np.ndarray
    keypoint_names: tuple[str, ...]
    skeleton_edges: tuple[tuple[int, int], ...]
    run_name: str
    git_commit: str
    sha256: str


def load_onnx_model(path: str | Path) -> PredictModel:
    """Open an exported model with onnxruntime (CPU) and check it against the ONNX contract.

    Args:
        path: ``.onnx`` file from ``hupbench export``.

    Returns:
        The :class:`PredictModel`.
    """
    path = Path(path)
    if path.is_dir():
        raise BadValueError(f"model {path} is a folder, not an .onnx file")
    if not path.is_file():
        raise MissingFileError(f"model {path} does not exist")
    data = path.read_bytes()
    if not data:
        raise BadValueError(f"model {path} is an empty file (0 bytes), not an ONNX model")
    if data.startswith((_ZIP_MAGIC, _PICKLE_MAGIC)):
        raise BadValueError(f"model {path} is a PyTorch checkpoint, not an ONNX model: predict runs without torch; "
                         f"export it first with `hupbench export {path}`")
    try:
        session = ort.InferenceSession(data, providers=["CPUExecutionProvider"])
    except _ORT_LOAD_ERRORS as exc:
        reason = " ".join(str(exc).split())[:200]
        raise BadValueError(f"{path} is not a readable ONNX model: {type(exc).__name__}: {reason}") from None
    meta = read_metadata(dict(session.get_modelmeta().custom_metadata_map), str(path))
    check_io_shapes({i.name: list(i.shape or []) for i in session.get_inputs()},
                    {o.name: list(o.shape or []) for o in session.get_outputs()},
                    meta["input_size"], len(meta["keypoint_names"]), str(path))
    meta.pop("model_config")  # the architecture: predict runs the graph, it never rebuilds the model
    return PredictModel(path=path, session=session, sha256=hashlib.sha256(data).hexdigest(), **meta)


def run_model(model: PredictModel, images: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Run the network on a batch of prepared inputs.

    Args:
        model: from :func:`load_onnx_model`.
        images: (B, 3, S, S) float32 RGB in [0, 1].

    Returns:
        points2d (B, N, 2) float32 normalised [-1, 1] input coordinates; points3d (B, N, 3)
        float32, metres, OpenCV camera frame of K_input.
    """
    S = model.input_size
    images = np.asarray(images)
    if images.ndim != 4 or images.shape[1:] != (3, S, S) or images.dtype != np.float32:
        raise BadValueError(f"images must be (B, 3, {S}, {S}) float32, got {images.shape} {images.dtype}")
    try:
        points2d, points3d = model.session.run(["points2d", "points3d"], {"image": images})
    except _ORT_RUN_ERRORS as exc:
        # the declared input shape and the metadata agree (load_onnx_model), so the graph inside wants
        # something else: a model made for another input size whose header was edited, or a broken graph
        reason = " ".join(str(exc).split())[:240]
        raise RunFailedError(f"{model.path}: onnxruntime could not run the model on a {tuple(images.shape)} batch at "
                           f"the input size its metadata declare ({S} px): {type(exc).__name__}: {reason}") from None
    n, b = len(model.keypoint_names), images.shape[0]
    if points2d.shape != (b, n, 2) or points3d.shape != (b, n, 3):
        raise RunFailedError(f"{model.path}: outputs must be ({b}, {n}, 2) and ({b}, {n}, 3) for {n} keypoint "
                           f"names, got {points2d.shape} and {points3d.shape}")
    return points2d, points3d


# ---------------------------------------------------------------- run


def _plain(values: np.ndarray, decimals: int) -> list:
    """Rounded nested lists; a non-finite value becomes null so that the file stays valid JSON."""
    rounded = np.round(np.asarray(values, dtype=np.float64), decimals) + 0.0  # + 0.0 turns -0.0 into 0.0
    return np.where(np.isfinite(rounded), rounded, None).tolist()


def _compact_json(value: Any, indent: int = 0) -> str:
    """Indented JSON (keys sorted) with every list of numbers on one line: one keypoint per line."""
    pad, inner = " " * indent, " " * (indent + 2)
    if isinstance(value, dict) and value:
        items = [f"{inner}{json.dumps(str(k))}: {_compact_json(v, indent + 2)}" for k, v in sorted(value.items())]
        return "{\n" + ",\n".join(items) + "\n" + pad + "}"
    if isinstance(value, (list, tuple)) and value:
        if all(v is None or isinstance(v, (int, float)) for v in value):
            return "[" + ", ".join(json.dumps(v, allow_nan=False) for v in value) + "]"
        return "[\n" + ",\n".join(inner + _compact_json(v, indent + 2) for v in value) + "\n" + pad + "]"
    return json.dumps(value, allow_nan=False)


def _stderr(message: str) -> None:
    print(message, file=sys.stderr)


def keypoints_for_image(points2d_norm: np.ndarray, points3d: np.ndarray, geometry: InputGeometry,
                        K_input: np.ndarray, K_user: np.ndarray | None = None) -> dict[str, Any]:
    """Map one image's network outputs to its original pixels and to the chosen camera.

    Args:
        points2d_norm: (N, 2) normalised [-1, 1] input coordinates.
        points3d: (N, 3) metres, camera frame of K_input.
        geometry: how the image became the input.
        K_input: (3, 3) the network's training camera at the model input.
        K_user: (3, 3) the user's intrinsics of the original image, or None to assume the training camera.

    Returns:
        ``{"camera": str, "K": (3, 3) original pixels, "K_model_input": (3, 3), "keypoints_2d_px": (N, 2)
        original pixels, "keypoints_3d_m": (N, 3) metres, camera frame of "K"}``.
    """
    uv_px = geometry.normalized_to_image_px(points2d_norm)
    if K_user is None:
        return {"camera": CAMERA_ASSUMED, "K": geometry.intrinsics_to_image(K_input), "K_model_input": K_input,
                "keypoints_2d_px": uv_px, "keypoints_3d_m": np.asarray(points3d, dtype=np.float64)}
    K_user_in = geometry.intrinsics_to_input(K_user)
    xyz = user_camera_points(geometry.normalized_to_input_px(points2d_norm), points3d, K_input, K_user_in)
    return {"camera": CAMERA_USER, "K": np.asarray(K_user, dtype=np.float64), "K_model_input": K_user_in,
            "keypoints_2d_px": uv_px, "keypoints_3d_m": xyz}


def check_out_dir(out_dir: str | Path) -> Path:
    """The output folder (``--out``) must be a folder, or not exist yet, on a writable file system.

    Checked before any inference, so that a run that cannot write its results does not compute them.

    Raises:
        ValueError: ``out_dir`` is a file.
        PermissionError: the folder (or its nearest existing parent) is read-only or not writable.
    """
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise BadValueError(f"output folder (--out) {out_dir} is not a folder: a file of that name exists")
    existing = out_dir
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    if not os.access(existing, os.W_OK | os.X_OK):
        try:
            read_only = bool(os.statvfs(existing).f_flag & os.ST_RDONLY)
        except OSError:
            read_only = False
        why = "it is on a read-only file system" if read_only else "no write permission"
        where = "" if existing == out_dir else f" (its parent {existing})"
        raise NotWritableError(f"cannot write into output folder (--out) {out_dir}{where}: {why}")
    return out_dir


def _progress_bar(total: int, enabled: bool):
    """A tqdm bar over images on stderr that shows itself only when the run lasts more than 2 s."""
    from tqdm import tqdm

    return tqdm(total=total, unit="image", desc="hupbench predict", disable=not enabled, delay=2.0,
                dynamic_ncols=True, file=sys.stderr)


def run_predict(model_path: str | Path, inputs: Sequence[str | Path], out_dir: str | Path = "predictions",
                K: str | np.ndarray | None = None, overlay: bool = True, batch_size: int = DEFAULT_BATCH_SIZE,
                log: Callable[[str], None] = _stderr, progress: bool = False) -> dict[str, Any]:
    """Predict 2D and 3D keypoints for image files; write ``predictions.json`` and overlays.

    Everything that can be checked before inference is (module docstring); a failure while writing
    removes this run's overlays and leaves no ``predictions.json``.

    Args:
        model_path: ``.onnx`` file from ``hupbench export``.
        inputs: image files and/or directories (module docstring, :func:`expand_inputs`).
        out_dir: output folder (created).
        K: the user's intrinsics of the original images, ``"fx,fy,cx,cy"`` or (3, 3); None
            assumes the training camera scaled to each image.
        overlay: write ``<stem>_overlay.png`` per image.
        batch_size: images per onnxruntime call.
        log: receives per-file errors and notes (default: stderr).
        progress: a progress bar with ETA on stderr for runs longer than 2 s.

    Returns:
        ``{"json": Path, "images": int, "ok": int, "failed": int, "overlays": [Path], "skipped": [...],
        "records": [per-image dicts as in the JSON]}``.
    """
    check_int(batch_size, "batch_size (--batch-size)", low=1)
    K_user = parse_intrinsics(K) if isinstance(K, str) else (None if K is None else check_user_K(K, "K"))
    out_dir = check_out_dir(out_dir)
    model = load_onnx_model(model_path)
    files, skipped = expand_inputs(inputs)
    if not files:
        raise BadValueError(f"no image files ({', '.join(IMAGE_SUFFIXES)}) in {', '.join(str(i) for i in inputs)}"
                         + (f" ({len(skipped)} other entries skipped)" if skipped else ""))

    names = list(model.keypoint_names)
    records: list[dict[str, Any]] = []
    overlays: list[Path] = []
    used_stems: set[str] = set()
    finished = False
    bar = _progress_bar(len(files), progress)
    if progress and log is _stderr:
        def log(line: str) -> None:
            # above the bar once it shows; tqdm.write before that would print a stray carriage return
            if bar.last_print_t >= bar.start_t + bar.delay:
                bar.write(line, file=sys.stderr)
            else:
                _stderr(line)
    for item in skipped:
        log(f"hupbench predict: note: {item['path']}: {item['reason']}")
    try:
        if out_dir.is_dir():
            clean_stale_tmp(out_dir, recursive=False)
            # the folder's predictions.json must describe the overlays beside it: an earlier run's goes
            # now, and this run's is written last
            (out_dir / "predictions.json").unlink(missing_ok=True)
        for start in range(0, len(files), batch_size):
            chunk_records = [_empty_record(path, names, model.run_name) for path in files[start : start + batch_size]]
            _predict_batch(model, chunk_records, K_user, out_dir if overlay else None, used_stems, overlays, log)
            records.extend(chunk_records)
            bar.update(len(chunk_records))

        failed = sum(not r["ok"] for r in records)
        document = {
            "schema_version": SCHEMA_VERSION,
            "tool": "hupbench predict",
            "model": {"path": str(model.path), "sha256": model.sha256, "run_name": model.run_name,
                      "git_commit": model.git_commit, "input_size": model.input_size,
                      "K_input": model.K_input.tolist()},
            "keypoint_names": names,
            "skeleton_edges": [list(e) for e in model.skeleton_edges],
            "preprocessing": PREPROCESSING,
            "counts": {"images": len(records), "ok": len(records) - failed, "failed": failed},
            "skipped": skipped,
            "images": records,
        }
        json_path = write_bytes(out_dir / "predictions.json", (_compact_json(document) + "\n").encode())
        finished = True
    finally:
        bar.close()
        if not finished:  # a full disk, a model that fails on a later batch, an interrupt
            for path in overlays:
                with contextlib.suppress(OSError):  # the error that stopped the run is the one to report
                    path.unlink(missing_ok=True)
    return {"json": json_path, "images": len(records), "ok": len(records) - failed, "failed": failed,
            "overlays": overlays, "skipped": skipped, "records": records}


def _predict_batch(model: PredictModel, chunk_records: list[dict[str, Any]], K_user: np.ndarray | None,
                   overlay_dir: Path | None, used_stems: set[str], overlays: list[Path], log) -> None:
    """Read, predict and record one batch of images in place: a bad image's record gets its error (and
    the log a line), a good one its keypoints and, with ``overlay_dir``, its overlay (appended to
    ``overlays``)."""
    names = list(model.keypoint_names)
    loaded: list[tuple[dict[str, Any], np.ndarray, np.ndarray, InputGeometry]] = []
    for record in chunk_records:
        notes: list[str] = []
        try:
            image = read_image(record["path"], notes)
        except (ValueError, FileNotFoundError) as exc:
            record["error"] = str(exc)
            log(f"hupbench predict: error: {exc}")
            continue
        for note in notes:
            log(f"hupbench predict: note: {record['path']}: {note}")
        model_input, geometry = preprocess(image, model.input_size)
        loaded.append((record, image, model_input, geometry))
    if loaded:
        points2d, points3d = run_model(model, np.stack([item[2] for item in loaded]))  # (B, 3, S, S) -> (B, N, *)
        for b, (record, image, _, geometry) in enumerate(loaded):
            if not (np.all(np.isfinite(points2d[b])) and np.all(np.isfinite(points3d[b]))):
                record["error"] = f"{record['path']}: the model's output is not finite (NaN or inf)"
                log(f"hupbench predict: error: {record['error']}")
                continue
            result = keypoints_for_image(points2d[b], points3d[b], geometry, model.K_input, K_user)
            record.update(
                ok=True, image_size={"width": geometry.width, "height": geometry.height},
                camera=result["camera"], K=_plain(result["K"], _DECIMALS_K),
                K_model_input=_plain(result["K_model_input"], _DECIMALS_K), input_geometry=geometry.as_dict(),
                keypoints_2d_px=_plain(result["keypoints_2d_px"], _DECIMALS_PX),
                keypoints_3d_m=_plain(result["keypoints_3d_m"], _DECIMALS_M),
            )
            if overlay_dir is not None:
                stem = _unique_stem(Path(record["path"]).stem, used_stems)
                drawn = draw_prediction(to_uint8(image), result["keypoints_2d_px"], names, model.skeleton_edges)
                overlays.append(write_png(overlay_dir / f"{stem}_overlay.png", drawn))
                record["overlay"] = str(overlays[-1])


def _empty_record(path: Path, names: list[str], run_name: str) -> dict[str, Any]:
    """The JSON record of one input before (or without) a prediction: every key present, values null."""
    return {"path": str(path), "ok": False, "error": None, "image_size": None, "camera": None, "K": None,
            "K_model_input": None, "input_geometry": None, "keypoint_names": names, "keypoints_2d_px": None,
            "keypoints_3d_m": None, "run_name": run_name, "overlay": None}


def _unique_stem(stem: str, used: set[str]) -> str:
    """``stem``, or ``stem_2``, ``stem_3``, ... when an earlier input already had that stem."""
    candidate, k = stem, 1
    while candidate in used:
        k += 1
        candidate = f"{stem}_{k}"
    used.add(candidate)
    return candidate
