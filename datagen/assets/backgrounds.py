"""Background images behind the rendered hand and probe, and alpha compositing.

HUP-3D composites every frame over one of 8 photographs: plain white, a
consultation room, 3 x an ultrasound fetal phantom scene and 3 x real
pregnant abdomens (light, brown, dark skin). The photographs are not
redistributable, so :meth:`BackgroundSet.builtin` paints procedural stand-ins
of the same 8 categories with numpy and OpenCV (:mod:`hupbench.datagen.assets.background_scenes`); :class:`BackgroundSet` also
reads a folder of the user's own photographs.

Convention:
    Images are RGB (never BGR), uint8, shaped (H, W, 3); foregrounds are
    RGBA (H, W, 4) with straight (not premultiplied) alpha, 0 = transparent,
    255 = opaque. Built-ins are painted once on a square canvas of
    ``BASE_PX`` pixels; any other size is the centre crop of that canvas
    to the requested aspect ratio, resized (``cv2.INTER_AREA`` when
    shrinking, ``cv2.INTER_LINEAR`` when enlarging). User photographs get
    the same centre crop and resize.

Determinism:
    Every random field comes from ``np.random.default_rng`` with a fixed
    seed per background; nothing reads the global RNG, the clock or the
    machine. Two calls, and two processes, give the same bytes.
    :meth:`BackgroundSet.fingerprint` lets a dataset manifest record the
    exact pixels it used.

Returned arrays are cached and therefore read-only; copy one before
drawing on it.
"""

from __future__ import annotations

import functools
import hashlib
from pathlib import Path
from typing import Callable, Sequence

import cv2
import numpy as np

from hupbench.datagen.assets.background_scenes import SCENES
from hupbench.core.errors import BadValueError

#: the built-in backgrounds; the position in this tuple is the background_id
BUILTIN_NAMES: tuple[str, ...] = (
    "plain_white",
    "consultation_room",
    "phantom_1",
    "phantom_2",
    "phantom_3",
    "abdomen_light",
    "abdomen_brown",
    "abdomen_dark",
)
#: smallest width or height an image may be asked for, pixels
MIN_SIZE_PX = 16
#: file suffixes (lower case) that BackgroundSet.from_dir reads
IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png")

# --------------------------------------------------------------------------- public API


class BackgroundSet:
    """An ordered set of background images: the built-ins or a folder of photographs.

    Use :meth:`builtin` or :meth:`from_dir` rather than the constructor.

    Attributes:
        names: one name per image; built-in names or file names (with suffix).
    """

    def __init__(self, names: Sequence[str], loader: Callable[[int, int, int], np.ndarray],
                 originals: Callable[[int], np.ndarray], kind: str):
        self.names: tuple[str, ...] = tuple(names)
        self._loader = loader
        self._originals = originals
        self._kind = kind
        self._cache: dict[tuple[int, int, int], np.ndarray] = {}

    @classmethod
    def builtin(cls) -> "BackgroundSet":
        """The 8 procedural backgrounds of ``BUILTIN_NAMES``, in that order."""
        return cls(BUILTIN_NAMES, _builtin_cached, _base_image, kind="builtin")

    @classmethod
    def from_dir(cls, path: str | Path) -> "BackgroundSet":
        """Every .jpg / .jpeg / .png file directly inside a folder, sorted by file name.

        All files are decoded here, so a broken one fails now rather than
        in the middle of dataset generation. Other files and sub-folders
        are ignored; suffixes match case-insensitively.

        Args:
            path: folder of photographs.

        Returns:
            A BackgroundSet whose names are the file names.

        Raises:
            ValueError: the folder does not exist, holds no image file, or a
                file cannot be decoded as an image (the message names it).
        """
        folder = Path(path)
        if not folder.is_dir():
            raise BadValueError(f"background folder {str(folder)!r} does not exist or is not a folder")
        files = sorted((f for f in folder.iterdir() if f.is_file() and f.suffix.lower() in IMAGE_SUFFIXES),
                       key=lambda f: f.name)
        if not files:
            raise BadValueError(f"no images found in {str(folder)!r} (looked for {', '.join(IMAGE_SUFFIXES)})")
        photos = [_read_rgb(f) for f in files]
        for photo in photos:
            photo.flags.writeable = False

        def load(index: int, width: int, height: int) -> np.ndarray:
            return _center_crop_resize(photos[index], width, height)

        return cls([f.name for f in files], load, photos.__getitem__, kind="dir")

    def __len__(self) -> int:
        return len(self.names)

    def __repr__(self) -> str:
        return f"BackgroundSet({self._kind}, {len(self)} images: {', '.join(self.names)})"

    def image(self, index: int, width: int, height: int) -> np.ndarray:
        """Background ``index`` at the given size, centre-cropped to its aspect ratio.

        Args:
            index: position in ``names``.
            width: pixels, >= ``MIN_SIZE_PX``.
            height: pixels, >= ``MIN_SIZE_PX``.

        Returns:
            (height, width, 3) uint8 RGB, read-only (cached per index and size).
        """
        assert 0 <= index < len(self), index  # the writer bounds n_backgrounds by the set's length
        assert min(width, height) >= MIN_SIZE_PX, (width, height)  # DatasetSpec's image size
        key = (int(index), int(width), int(height))
        if key not in self._cache:
            image = self._loader(index, width, height)
            image.flags.writeable = False
            self._cache[key] = image
        return self._cache[key]

    def fingerprint(self) -> str:
        """SHA-256 hex digest over the names and full-resolution pixels, in order.

        Two sets with the same fingerprint give the same image for every
        index and size, so a dataset manifest can record it to say which
        backgrounds were used.

        Returns:
            64 lower-case hexadecimal characters.
        """
        digest = hashlib.sha256()
        digest.update(f"hupbench-backgrounds-v1:{len(self)}\n".encode())
        for index, name in enumerate(self.names):
            pixels = np.ascontiguousarray(self._originals(index))
            digest.update(f"{name}\n{pixels.shape}\n".encode())
            digest.update(pixels.tobytes())
        return digest.hexdigest()


def composite(foreground_rgba: np.ndarray, background_rgb: np.ndarray) -> np.ndarray:
    """Lay a straight-alpha RGBA render over an RGB background ("over" operator).

    out = (alpha * fg + (255 - alpha) * bg) / 255, rounded to the nearest
    integer in exact integer arithmetic, so alpha 0 gives the background
    and alpha 255 the foreground bit for bit, and anti-aliased edges blend.

    Args:
        foreground_rgba: (H, W, 4) uint8, RGB plus alpha (0 transparent, 255 opaque).
        background_rgb: (H, W, 3) uint8 RGB, same H and W.

    Returns:
        (H, W, 3) uint8 RGB, a new array.
    """
    assert foreground_rgba.dtype == background_rgb.dtype == np.uint8
    assert foreground_rgba.shape == background_rgb.shape[:2] + (4,), (foreground_rgba.shape, background_rgb.shape)
    alpha = foreground_rgba[..., 3:].astype(np.uint32)
    mixed = alpha * foreground_rgba[..., :3] + (255 - alpha) * background_rgb  # (H, W, 3) uint32, <= 255^2
    return ((mixed + 127) // 255).astype(np.uint8)


# --------------------------------------------------------------------------- I/O


def _read_rgb(path: Path) -> np.ndarray:
    """Decode an image file to (H, W, 3) uint8 RGB; grey and alpha are converted."""
    # imdecode rather than imread: imread cannot open non-ASCII paths on Windows
    data = np.fromfile(str(path), dtype=np.uint8)
    image = cv2.imdecode(data, cv2.IMREAD_COLOR) if data.size else None
    if image is None:
        raise BadValueError(f"cannot read background image {str(path)!r}: not a decodable JPEG/PNG file")
    return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)


def _center_crop_resize(image: np.ndarray, width: int, height: int) -> np.ndarray:
    """Largest centred crop with the aspect ratio width:height, resized to (height, width, 3)."""
    src_h, src_w = image.shape[:2]
    # compare src_w / src_h with width / height without rounding
    if src_w * height > width * src_h:
        crop_w, crop_h = max(1, round(src_h * width / height)), src_h
    else:
        crop_w, crop_h = src_w, max(1, round(src_w * height / width))
    x0, y0 = (src_w - crop_w) // 2, (src_h - crop_h) // 2
    crop = image[y0:y0 + crop_h, x0:x0 + crop_w]
    if (crop_w, crop_h) == (width, height):
        return crop.copy()
    # INTER_AREA averages when shrinking; when enlarging it degrades towards nearest neighbour
    shrinking = width <= crop_w and height <= crop_h
    return cv2.resize(crop, (width, height), interpolation=cv2.INTER_AREA if shrinking else cv2.INTER_LINEAR)


@functools.lru_cache(maxsize=64)
def _builtin_cached(index: int, width: int, height: int) -> np.ndarray:
    image = _center_crop_resize(_base_image(index), width, height)
    image.flags.writeable = False
    return image


@functools.lru_cache(maxsize=None)
def _base_image(index: int) -> np.ndarray:
    """Built-in ``index`` on the BASE_PX x BASE_PX canvas, (BASE_PX, BASE_PX, 3) uint8 RGB, read-only."""
    canvas = SCENES[index]()  # (BASE_PX, BASE_PX, 3) float32 RGB in [0, 1]
    image = np.clip(np.rint(canvas * 255.0), 0, 255).astype(np.uint8)
    image.flags.writeable = False
    return image
