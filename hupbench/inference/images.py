"""Reading the images a user gives ``hupbench predict`` (numpy and OpenCV only: the torch-free path).

PNG or JPEG, recognised by content (not by name), from MIN_IMAGE_SIDE px on the shorter side (fewer hold
too few pixels for 29 keypoints) to MAX_IMAGE_SIDE px on the longer side, refused from the header before
decoding (a 20000 x 20000 PNG would decode into gigabytes). 8- and 16-bit samples are scaled to [0, 1];
grey becomes three equal channels; alpha is composited over the padding grey; JPEG EXIF orientation is
applied. What libpng and libjpeg print about a damaged file becomes that file's error, or a note naming
the file when the image still decodes whole; a JPEG whose data end early is refused. Folders expand to
their image files.
"""

from __future__ import annotations

import contextlib
import os
import re
import struct
import sys
import tempfile
from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np

from hupbench.core.errors import BadValueError, MissingFileError

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")
#: file names ``hupbench predict`` reads as videos, frame by frame (:mod:`hupbench.inference.video`)
VIDEO_SUFFIXES = (".mp4", ".avi", ".mov", ".mkv", ".webm")
PAD_VALUE = 0.5  # mid-grey in [0, 1], for the square padding and under transparent pixels
MIN_IMAGE_SIDE = 16  # pixels, shorter side: below it a hand is a few pixels, its 21 joints indistinguishable
MAX_IMAGE_SIDE = 8192  # pixels, longer side: a 48-megapixel phone photo (8000 x 6000) passes
_PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
_JPEG_MAGIC = b"\xff\xd8\xff"
_JPEG_SOF_MARKERS = frozenset({0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF})


def image_size_from_header(data: bytes) -> tuple[int, int] | None:
    """(width, height) pixels (before any EXIF rotation) that a PNG's IHDR or a JPEG's frame header (SOFn)
    declares, without decoding; None when the header is not found."""
    if data.startswith(_PNG_MAGIC):
        if len(data) >= 24 and data[12:16] == b"IHDR":
            return struct.unpack(">II", data[16:24])
        return None
    if not data.startswith(_JPEG_MAGIC):
        return None
    pos = 2
    while pos + 4 <= len(data):
        if data[pos] != 0xFF:
            return None
        marker = data[pos + 1]
        if marker == 0xFF:  # fill byte before a marker
            pos += 1
        elif marker == 0x01 or 0xD0 <= marker <= 0xD8:  # markers without a length
            pos += 2
        elif marker in (0xD9, 0xDA):  # end of image, or scan data before any frame header
            return None
        elif marker in _JPEG_SOF_MARKERS:
            if pos + 9 > len(data):
                return None
            height, width = struct.unpack(">HH", data[pos + 5:pos + 9])
            return width, height
        else:
            (length,) = struct.unpack(">H", data[pos + 2:pos + 4])
            pos += 2 + length
    return None


def check_image_size(width: int, height: int, source: str = "image") -> None:
    """Refuse images smaller than MIN_IMAGE_SIDE or larger than MAX_IMAGE_SIDE (module docstring)."""
    if min(width, height) < MIN_IMAGE_SIDE:
        raise BadValueError(f"{source}: image is {width} x {height} px; predict needs at least {MIN_IMAGE_SIDE} px "
                            "on each side")
    if max(width, height) > MAX_IMAGE_SIDE:
        raise BadValueError(f"{source}: image is {width} x {height} px; predict reads images of at most "
                            f"{MAX_IMAGE_SIDE} px on the longer side: downscale it first")


_OPENCV_LOG_PREFIX = re.compile(r"^\[\s*[A-Z]+:[^\]]*\]\s*(global\s+\S+\s+\S+\s+)?")


@contextlib.contextmanager
def _c_library_messages():
    """Collect what C libraries (libpng, libjpeg, OpenCV's logger) print to file descriptor 2 meanwhile.

    They print straight to the process's stderr, not through Python, and a line such as
    "libpng error: PNG input buffer is incomplete" names no file: the caller turns the lines into
    its own message, which does. Yields a list filled with the non-empty lines on exit.
    """
    lines: list[str] = []
    try:
        saved = os.dup(2)
    except OSError:  # no file descriptor 2 (a detached process): nothing to collect
        yield lines
        return
    with tempfile.TemporaryFile() as sink:
        sys.stderr.flush()
        os.dup2(sink.fileno(), 2)
        try:
            yield lines
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            sink.seek(0)
            text = sink.read().decode("utf-8", errors="replace")
            for line in text.splitlines():
                line = _OPENCV_LOG_PREFIX.sub("", line.strip())
                if line and line not in lines:
                    lines.append(line)


def _decode(data: bytes, flags: int, kind: str, source: str) -> tuple[np.ndarray, str]:
    """``cv2.imdecode`` of PNG or JPEG (``kind``) bytes, and what the C libraries said meanwhile ("" when
    nothing); data that do not decode are an error naming ``source``."""
    with _c_library_messages() as said:
        image = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), flags)
    detail = "; ".join(said)
    if image is None or image.size == 0:
        raise BadValueError(f"{source}: {kind} data could not be decoded (truncated or corrupt file"
                            + (f": {detail})" if detail else ")"))
    return image, detail


def _file_bytes(path: Path, missing: str) -> bytes:
    """The bytes of an input file; ``missing`` says what a missing file should have been."""
    if not path.exists():
        raise MissingFileError(f"{path}: {missing}")
    if not path.is_file():  # a FIFO would block the read, a device never end it
        raise BadValueError(f"{path}: not a regular file")
    try:
        return path.read_bytes()
    except OSError as exc:
        raise BadValueError(f"{path}: cannot be read: {exc.strerror or exc}") from exc


def decode_image(data: bytes, source: str = "image", notes: list[str] | None = None) -> np.ndarray:
    """PNG or JPEG bytes -> (H, W, 3) float32 RGB in [0, 1] (module docstring).

    Args:
        data: the file's bytes.
        source: the path, for error messages (which start with it).
        notes: receives what the decoder said about a damaged file that still decoded whole.
    """
    if not data:
        raise BadValueError(f"{source}: empty file (0 bytes), not an image")
    if data.startswith(_PNG_MAGIC):
        kind, flags = "PNG", cv2.IMREAD_UNCHANGED  # keep 16-bit samples and alpha
    elif data.startswith(_JPEG_MAGIC):
        kind, flags = "JPEG", cv2.IMREAD_COLOR  # applies the EXIF orientation of photos
    else:
        raise BadValueError(f"{source}: not a PNG or JPEG image (the file starts with {data[:8]!r})")
    declared = image_size_from_header(data)
    if declared is not None:
        check_image_size(*declared, source)  # before decoding: a 20000 x 20000 file would take gigabytes
    image, detail = _decode(data, flags, kind, source)
    if "premature end" in detail:  # libjpeg fills the missing lower part with grey and carries on
        raise BadValueError(f"{source}: {kind} data end early, part of the image is missing ({detail})")
    if detail and notes is not None:
        notes.append(f"{kind} decoder: {detail}")
    check_image_size(image.shape[1], image.shape[0], source)
    if image.dtype == np.uint8:
        image = image.astype(np.float32) / 255.0
    elif image.dtype == np.uint16:
        image = image.astype(np.float32) / 65535.0
    else:
        raise BadValueError(f"{source}: {kind} with {image.dtype} samples is not supported (8 or 16 bit)")
    if image.ndim == 2:
        image = image[:, :, None]
    channels = image.shape[2]
    if channels in (2, 4):  # grey + alpha or BGRA: composite over the padding grey
        alpha = image[:, :, -1:]
        image = image[:, :, :-1] * alpha + PAD_VALUE * (1.0 - alpha)
    if image.shape[2] == 1:
        image = np.repeat(image, 3, axis=2)
    elif image.shape[2] == 3:
        image = image[:, :, ::-1]  # BGR -> RGB
    else:
        raise BadValueError(f"{source}: {kind} with {channels} channels is not supported")
    return np.ascontiguousarray(image, dtype=np.float32)


def read_image(path: str | Path, notes: list[str] | None = None) -> np.ndarray:
    """A PNG or JPEG file (recognised by content) as :func:`decode_image` gives it."""
    path = Path(path)
    return decode_image(_file_bytes(path, "no such file"), str(path), notes)


def read_depth_png(path: str | Path, image_size: tuple[int, int] | None = None) -> np.ndarray:
    """The depth map of an image for a model that reads depth: a single-channel 16-bit PNG of the image's
    ``image_size`` (width, height; None: any size), as (H, W) uint16 in the file's unit (``--depth-scale-m``
    metres), with at least one valid (non-zero) value."""
    path = Path(path)
    data = _file_bytes(path, "no such depth map (--depth holds one <image stem>.png per image)")
    if not data.startswith(_PNG_MAGIC):
        raise BadValueError(f"{path}: a depth map must be a 16-bit PNG; the file starts with {data[:8]!r}")

    def check_size(width: int, height: int) -> None:
        if image_size is not None and (width, height) != tuple(image_size):
            raise BadValueError(f"{path}: the depth map is {width} x {height} px, its image "
                                f"{image_size[0]} x {image_size[1]} px")

    declared = image_size_from_header(data)
    if declared is not None:  # before decoding: a huge file of the wrong size is refused from its header
        check_size(*declared)
    depth, _ = _decode(data, cv2.IMREAD_UNCHANGED, "PNG", str(path))
    if depth.dtype != np.uint16 or depth.ndim != 2:
        raise BadValueError(f"{path}: a depth map must be single-channel 16-bit, got {depth.dtype} with "
                            f"{1 if depth.ndim == 2 else depth.shape[2]} channel(s)")
    check_size(depth.shape[1], depth.shape[0])
    if not depth.any():
        raise BadValueError(f"{path}: the depth map is 0 everywhere (nothing measured): a model that reads depth "
                            "needs the distance of the hand and probe")
    return depth


def to_uint8(image_rgb: np.ndarray) -> np.ndarray:
    """(H, W, 3) float in [0, 1] -> (H, W, 3) uint8."""
    return np.clip(np.round(np.asarray(image_rgb) * 255.0), 0, 255).astype(np.uint8)


def expand_inputs(inputs: Sequence[str | Path]) -> tuple[list[Path], list[dict[str, str]]]:
    """The files to process, and ``{"path", "reason"}`` for the folder entries left out.

    A folder expands to its files with an image or video suffix (any case; sorted by name, not recursive): a
    folder of a video's frames, named in their order, is read in that order. A path named explicitly, missing or
    not, is always processed and fails on its own if it is no image (or, by its suffix, no video).
    """
    files: list[Path] = []
    skipped: list[dict[str, str]] = []
    for item in inputs:
        path = Path(item)
        if not path.is_dir():
            files.append(path)
            continue
        for entry in sorted(path.iterdir(), key=lambda p: p.name):
            if entry.is_file() and entry.suffix.lower() in IMAGE_SUFFIXES + VIDEO_SUFFIXES:
                files.append(entry)
            elif entry.is_dir():
                skipped.append({"path": str(entry), "reason": "a directory (directories are not searched recursively)"})
            else:
                skipped.append({"path": str(entry), "reason": "not an image or video file name "
                                f"({', '.join(IMAGE_SUFFIXES + VIDEO_SUFFIXES)})"})
    return files, skipped


def check_frame_order(files: Sequence[Path]) -> None:
    """Refuse image files read as a video's frames in name order (a folder sorted by name, :func:`expand_inputs`)
    whose numbers say another order: ``frame_10.png`` sorts before ``frame_2.png``.

    Raises:
        BadValueError: naming the first two files of one folder out of their numbers' order.
    """
    def numbers_first(path: Path) -> list:
        return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", path.name)]

    for before, after in zip(files, files[1:]):
        if before.parent == after.parent and numbers_first(before) > numbers_first(after):
            raise BadValueError(f"{before} comes before {after} in name order, but its number is the higher: frames are "
                                "tracked in name order; name them with zero-padded numbers (frame_0002.png)")
