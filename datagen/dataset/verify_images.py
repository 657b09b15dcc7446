"""The pixel checks of verify: each image file read whole, depth against the mask, RGB against the frame's
background and glove (the statistics and their measured margins: docs/robustness.md, section verify).

Numpy and OpenCV only; :mod:`hupbench.datagen.dataset.verify` runs them per frame."""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np

from hupbench.core import tolerances as tol
from hupbench.core.contract import SEG_LABELS
from hupbench.core.io import encode_image


#: the renderer's white ambient light (hupbench.datagen.dataset.chunks.ChunkRenderer: RenderSettings(ambient=0.3))
RENDER_AMBIENT = 0.3
#: pyrender's output encoding: stored value = linear ** (1 / 2.2), clamped to [0, 1]
RENDER_GAMMA = 2.2
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
PNG_END = b"\x00\x00\x00\x00IEND\xaeB`\x82"
JPEG_START, JPEG_END = b"\xff\xd8", b"\xff\xd9"


# --- image statistics ------------------------------------------------------------------------


#: stored 8-bit level -> linear light (pyrender's output encoding inverted)
_LINEAR = (np.arange(256) / 255.0) ** RENDER_GAMMA


def _channel_max(image: np.ndarray) -> np.ndarray:
    return np.maximum(np.maximum(image[..., 0], image[..., 1]), image[..., 2])


def _channel_min(image: np.ndarray) -> np.ndarray:
    return np.minimum(np.minimum(image[..., 0], image[..., 1]), image[..., 2])


def grow_mask(mask: np.ndarray, px: int) -> np.ndarray:
    return cv2.dilate(mask.astype(np.uint8), np.ones((2 * px + 1, 2 * px + 1), np.uint8)) > 0


def shrink_mask(mask: np.ndarray, px: int) -> np.ndarray:
    return cv2.erode(mask.astype(np.uint8), np.ones((2 * px + 1, 2 * px + 1), np.uint8)) > 0


def read_image(path: Path, modality: str) -> tuple[np.ndarray | None, str | None]:
    """Read one image file of a frame, refusing damaged files before the decoder sees them.

    A JPEG without its end-of-image marker decodes to a partly grey image (libjpeg only warns on
    stderr), so the end markers are checked first.

    Args:
        path: the file. modality: "rgb" (read as 3-channel BGR, uint8) or "depth"/"seg" (as stored).

    Returns:
        (image, None), or (None, why): "missing" or a description of the damage.
    """
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        return None, "missing"
    except OSError as exc:
        return None, f"unreadable ({exc.strerror or exc})"
    if not data:
        return None, "empty (0 bytes)"
    if path.suffix == ".png":
        if not data.startswith(PNG_SIGNATURE):
            return None, "not a PNG (no PNG signature)"
        if not data.endswith(PNG_END):
            return None, "truncated (no PNG end chunk)"
    elif path.suffix == ".jpg":
        if not data.startswith(JPEG_START):
            return None, "not a JPEG (no JPEG start marker)"
        if not data.endswith(JPEG_END):
            return None, "truncated (no JPEG end-of-image marker)"
    flags = cv2.IMREAD_COLOR if modality == "rgb" else cv2.IMREAD_UNCHANGED
    image = cv2.imdecode(np.frombuffer(data, np.uint8), flags)
    if image is None:
        return None, f"not decodable as {path.suffix[1:].upper()}"
    return image, None


def image_format_problem(image: np.ndarray, modality: str, size: tuple[int, int],
                         labels: dict[str, int] = SEG_LABELS) -> str | None:
    """What is wrong with a decoded image against the contract (None when nothing).

    Args:
        image: as :func:`read_image` returns it. modality: "rgb", "depth" or "seg".
        size: the manifest's image_size (width, height).
        labels: the mask's labels on the dataset's track (:func:`hupbench.core.contract.seg_labels`).
    """
    w, h = size
    if image.shape[:2] != (h, w):
        return f"{image.shape[1]} x {image.shape[0]} pixels, the manifest's image_size is {w} x {h}"
    if modality in ("depth", "sensor_depth") and (image.dtype != np.uint16 or image.ndim != 2):
        return f"{image.dtype} with {1 if image.ndim == 2 else image.shape[2]} channel(s), expected single-channel uint16"
    if modality == "seg":
        if image.dtype != np.uint8 or image.ndim != 2:
            return f"{image.dtype} with {1 if image.ndim == 2 else image.shape[2]} channel(s), expected single-channel uint8"
        present = np.flatnonzero(np.bincount(image.ravel(), minlength=256))
        unknown = sorted(set(present.tolist()) - set(labels.values()))
        if unknown:
            return f"labels {unknown[:8]} outside {labels}"
    return None


def mask_depth_mismatch_px(depth: np.ndarray, seg: np.ndarray) -> int:
    """Pixels where depth and mask disagree on foreground, away from the silhouette's edge.

    The depth and the mask come from two rasterisations that differ on edge pixels only, so a
    1-pixel band around the mask's edge is not counted.

    Args:
        depth: (H, W) stored depth (0 = background). seg: (H, W) labels (0 = background).

    Returns:
        The number of pixels with depth outside the grown mask plus those without depth inside
        the shrunk mask.
    """
    foreground = seg != SEG_LABELS["background"]
    return int(np.count_nonzero((depth > 0) & ~grow_mask(foreground, 1))
               + np.count_nonzero((depth == 0) & shrink_mask(foreground, 1)))


def jpeg_reference(background: np.ndarray, quality: int | None) -> np.ndarray:
    """What the background looks like after the dataset's JPEG encoding (OpenCV, as the generator).

    Far from the rendered object an 8 x 8 block of the stored image holds only background, so it
    decodes like the same block of the background encoded alone (measured: within 2 levels).

    Args:
        background: (H, W, 3) uint8 RGB. quality: the dataset's JPEG quality, None for PNG.

    Returns:
        (H, W, 3) uint8 RGB.
    """
    if quality is None:
        return background
    buf = encode_image(".jpg", np.ascontiguousarray(background[..., ::-1]), [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    return np.ascontiguousarray(cv2.imdecode(np.frombuffer(buf, np.uint8), cv2.IMREAD_COLOR)[..., ::-1])


def _near_blocks(foreground: np.ndarray) -> np.ndarray:
    """(H, W) bool: pixels whose JPEG colour block (16 x 16, half-resolution chroma) or a neighbouring
    one holds foreground (the decoder's chroma upsampling reads across block borders)."""
    h, w = foreground.shape
    bh, bw = -(-h // 16), -(-w // 16)
    padded = np.zeros((bh * 16, bw * 16), dtype=bool)
    padded[:h, :w] = foreground
    blocks = padded.reshape(bh, 16, bw, 16).any(axis=(1, 3))
    blocks = grow_mask(blocks, 1)
    return np.kron(blocks, np.ones((16, 16), dtype=bool))[:h, :w]


def background_mismatch_px(rgb: np.ndarray, seg: np.ndarray, reference: np.ndarray) -> int:
    """Pixels the mask calls background whose colour is not the background's.

    Two zones: in JPEG blocks near the object (:func:`_near_blocks`), but 1 pixel or more from it
    (the renderer's anti-aliased edge), a channel more than ``VERIFY_BACKGROUND_LEVELS`` off counts
    (the object's block is quantised with it); in blocks of background only, a channel more than
    ``VERIFY_BACKGROUND_FAR_LEVELS`` off counts.

    Args:
        rgb: (H, W, 3) uint8, the stored image. seg: (H, W) labels. reference: (H, W, 3) uint8, the
            frame's background as stored (:func:`jpeg_reference`), same channel order as ``rgb``.

    Returns:
        The number of such pixels.
    """
    foreground = seg != SEG_LABELS["background"]
    near = _near_blocks(foreground)
    away = ~grow_mask(foreground, 1)
    diff = _channel_max(cv2.absdiff(rgb, reference))
    return int(np.count_nonzero(away & near & (diff > tol.VERIFY_BACKGROUND_LEVELS))
               + np.count_nonzero(~near & (diff > tol.VERIFY_BACKGROUND_FAR_LEVELS)))


def hand_blocks(rgb: np.ndarray, seg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean linear colours of the usable hand pixel blocks of an image, and their JPEG noise.

    Usable: hand in the mask shrunk by 2 pixels (JPEG's half-resolution chroma bleeds that far),
    not within a pixel of a clipped level (``VERIFY_GLOVE_CLIPPED_LEVEL``), no channel darker than
    ``VERIFY_GLOVE_DARK_LEVEL``. Blocks are ``VERIFY_GLOVE_BLOCK_PX`` square, usable throughout;
    averaging halves JPEG's chroma noise.

    Args:
        rgb: (H, W, 3) uint8 RGB. seg: (H, W) labels.

    Returns:
        (P, 3) float64 block means in linear light, and (P,) their noise in linear light
        (``VERIFY_GLOVE_NOISE_LEVELS`` stored levels per pixel, through the display curve).
    """
    hand = shrink_mask(seg == SEG_LABELS["hand"], 2)
    clipped = grow_mask(_channel_max(rgb) >= tol.VERIFY_GLOVE_CLIPPED_LEVEL, 1)
    use = hand & ~clipped & (_channel_min(rgb) >= tol.VERIFY_GLOVE_DARK_LEVEL)
    b = tol.VERIFY_GLOVE_BLOCK_PX
    h, w = (use.shape[0] // b) * b, (use.shape[1] // b) * b
    whole = use[:h, :w].reshape(h // b, b, w // b, b).all(axis=(1, 3))
    rows, cols = np.nonzero(whole)
    pixels = rgb[(rows[:, None] * b + np.arange(b)).repeat(b, axis=1), np.tile(cols[:, None] * b + np.arange(b), b)]
    linear = _LINEAR[pixels].mean(axis=1)  # (P, 3)
    stored = linear.mean(axis=1) ** (1 / RENDER_GAMMA)
    noise = RENDER_GAMMA * stored ** (RENDER_GAMMA - 1) * (tol.VERIFY_GLOVE_NOISE_LEVELS / 255.0) / b
    return linear, noise


def glove_cost(linear: np.ndarray, noise: np.ndarray, albedo, light_color) -> float:
    """How badly one glove under one lamp explains hand blocks (:func:`hand_blocks`).

    In linear light a glove of albedo ``a`` under the lamp colour ``c`` gives colours on the plane
    through ``RENDER_AMBIENT * a`` spanned by ``a * c`` and ``c`` (module docstring). Each block's
    distance to that plane, in units of its noise, is clipped at ``VERIFY_GLOVE_CLIP`` and squared.

    Args:
        linear: (P, 3) block means. noise: (P,). albedo: (3,) in [0, 1]. light_color: (3,).

    Returns:
        The sum over the blocks (0 for no blocks); NaN when the plane is undefined (an albedo that
        only scales the lamp's colour).
    """
    albedo = np.asarray(albedo, dtype=np.float64)
    light = np.asarray(light_color, dtype=np.float64)
    normal = np.cross(albedo * light, light)
    length = np.linalg.norm(normal)
    if length < 1e-9:
        return math.nan
    distance = np.abs((linear - RENDER_AMBIENT * albedo) @ (normal / length)) / noise
    return float(np.sum(np.minimum(distance, tol.VERIFY_GLOVE_CLIP) ** 2))


def glove_pair_ratio(rgb_a: np.ndarray, rgb_b: np.ndarray, seg: np.ndarray, gloves_rgb, glove_a: int, glove_b: int,
                     light_a, light_b) -> tuple[float | None, float, tuple[float, float]]:
    """Do two frames of one view in the two gloves show their own gloves and lamps?

    The two frames share the geometry (one mask) and differ in glove and lamp. The pair's ratio:
    the cost of each image under its own frame's glove and lamp, summed, over the same with the
    images exchanged; small when each image is its own frame's, 1 when both are one frame's image,
    large when they are swapped. Each frame's own ratio (its image under its own glove and lamp
    over under the other frame's) says which image is the stranger.

    Args:
        rgb_a, rgb_b: (H, W, 3) uint8 RGB of the two frames. seg: (H, W) their mask.
        gloves_rgb: (G, 3) albedos. glove_a, glove_b: the frames' glove ids. light_a, light_b: (3,)
            the frames' lamp colours.

    Returns:
        (ratio, limit, (ratio_a, ratio_b)): ratio None when the hands show too few usable blocks
        (``VERIFY_GLOVE_MIN_PAIR_BLOCKS`` together) or a cost is undefined; limit the ratio above
        which the pair fails (``VERIFY_GLOVE_PAIR_RATIO``, or ``VERIFY_GLOVE_PAIR_RATIO_FEW`` when
        one frame has fewer than ``VERIFY_GLOVE_MIN_BLOCKS`` blocks).
    """
    gloves = np.asarray(gloves_rgb, dtype=np.float64).reshape(-1, 3)
    blocks_a, blocks_b = hand_blocks(rgb_a, seg), hand_blocks(rgb_b, seg)
    n_a, n_b = len(blocks_a[0]), len(blocks_b[0])
    limit = tol.VERIFY_GLOVE_PAIR_RATIO if min(n_a, n_b) >= tol.VERIFY_GLOVE_MIN_BLOCKS else tol.VERIFY_GLOVE_PAIR_RATIO_FEW
    if n_a + n_b < tol.VERIFY_GLOVE_MIN_PAIR_BLOCKS:
        return None, limit, (math.nan, math.nan)
    a_own, a_other = glove_cost(*blocks_a, gloves[glove_a], light_a), glove_cost(*blocks_a, gloves[glove_b], light_b)
    b_own, b_other = glove_cost(*blocks_b, gloves[glove_b], light_b), glove_cost(*blocks_b, gloves[glove_a], light_a)
    if not all(math.isfinite(c) for c in (a_own, a_other, b_own, b_other)):
        return None, limit, (math.nan, math.nan)

    def ratio(own: float, other: float) -> float:
        return own / other if other > 0 else (math.inf if own > 0 else 1.0)

    return ratio(a_own + b_own, a_other + b_other), limit, (ratio(a_own, a_other), ratio(b_own, b_other))


def image_shift_px(signed_m: np.ndarray, normals_cam: np.ndarray, depth_m: np.ndarray, K: np.ndarray
                   ) -> np.ndarray | None:
    """How far the images sit from the labels, from probe pixels unprojected with their depth.

    If the images are shifted by (du, dv) pixels against the labels, a probe pixel at depth z
    unprojects to a point displaced by (du z / fx, dv z / fy, dz) in the camera frame, and its signed
    distance to the probe (placed by the labels) is that displacement along the surface normal.
    Least squares over the pixels gives (du, dv, dz); the probe's curved surface makes it
    well posed (measured: within 0.07 px on correct frames, 0.49-0.55 px for a half-pixel shift).

    Args:
        signed_m: (P,) signed distances of the unprojected pixels to the probe, metres.
        normals_cam: (P, 3) unit surface normals there, camera frame. depth_m: (P,) their depth, metres.
        K: (3, 3) the frame's intrinsics.

    Returns:
        (2,) float64 (du, dv) pixels, or None with fewer than ``VERIFY_SHIFT_MIN_PIXELS`` pixels or
        normals that do not pin both image axes down.
    """
    if len(signed_m) < tol.VERIFY_SHIFT_MIN_PIXELS:
        return None
    design = np.stack([normals_cam[:, 0] * depth_m / K[0, 0], normals_cam[:, 1] * depth_m / K[1, 1],
                       normals_cam[:, 2]], axis=1)  # metres per pixel of shift, and per metre of depth
    scale = np.linalg.norm(design, axis=0)
    if scale[:2].min() <= 0 or np.linalg.cond(design / np.maximum(scale, 1e-12)) > tol.VERIFY_SHIFT_MAX_COND:
        return None
    solution, *_ = np.linalg.lstsq(design, signed_m, rcond=None)
    return solution[:2]


# --- the checks ------------------------------------------------------------------------------
