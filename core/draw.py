"""Drawing keypoints, skeletons, depth and label maps (numpy + OpenCV only, no torch).

Convention:
    Images are RGB uint8 (H, W, 3); pixel coordinates (u, v) follow OpenCV
    (pixel centres at integers). Drawing uses 4x sub-pixel precision.
"""

from __future__ import annotations

import cv2
import numpy as np

from hupbench.core import keypoints as kp
from hupbench.core.errors import BadValueError
from hupbench.core.input_checks import check_shape

# one colour per finger (RGB), the wrist grey, the probe box orange
FINGER_RGB = {
    "wrist": (200, 200, 200),
    "thumb": (230, 60, 60),
    "index": (240, 200, 40),
    "middle": (60, 200, 80),
    "ring": (50, 140, 240),
    "little": (200, 80, 230),
}
PROBE_RGB = (255, 140, 0)
#: mask label -> RGB: 0 background, 1 hand, 2 arm, 3 probe, 4 the patient (the clinic track)
SEG_RGB = np.array([[0, 0, 0], [90, 110, 230], [240, 170, 90], [235, 235, 235], [200, 90, 150]], dtype=np.uint8)
_SHIFT = 2  # fixed-point bits for sub-pixel drawing
_FONT = cv2.FONT_HERSHEY_SIMPLEX
TITLE_SCALE = 0.45
MIN_TEXT_SCALE = 0.3  # below this the font stops being legible; longer text is cut instead


def _keypoint_color(index: int) -> tuple[int, int, int]:
    return PROBE_RGB if index >= kp.NUM_HAND else FINGER_RGB[kp.finger_of(index)]


def draw_keypoints(image_rgb: np.ndarray, uv: np.ndarray, visible: np.ndarray | None = None,
                   radius: float = 2.5, thickness: int = 1) -> np.ndarray:
    """Draw the 29-keypoint skeleton (hand chains and probe box edges).

    Args:
        image_rgb: (H, W, 3) uint8.
        uv: (29, 2) float pixel coordinates; NaN rows are skipped.
        visible: (29,) bool; hidden keypoints are drawn hollow and their
            edges dashed-thin. None means all visible.
        radius: joint marker radius, pixels.
        thickness: line thickness, pixels.

    Returns:
        (H, W, 3) uint8 copy with the drawing.
    """
    assert image_rgb.ndim == 3 and image_rgb.shape[2] == 3 and image_rgb.dtype == np.uint8, image_rgb.shape
    uv = np.asarray(uv, dtype=np.float64)
    visible = np.ones(kp.NUM_KEYPOINTS, dtype=bool) if visible is None else np.asarray(visible, dtype=bool)
    assert uv.shape == (kp.NUM_KEYPOINTS, 2) and visible.shape == (kp.NUM_KEYPOINTS,), (uv.shape, visible.shape)
    out = image_rgb.copy()
    ok = np.all(np.isfinite(uv), axis=1)
    fixed = np.round(np.where(ok[:, None], uv, 0.0) * (1 << _SHIFT)).astype(np.int64)
    # keep coordinates in a range OpenCV's int32 drawing accepts
    fixed = np.clip(fixed, -(1 << 28), 1 << 28)
    for a, b in kp.SKELETON_EDGES:
        if not (ok[a] and ok[b]):
            continue
        color = _keypoint_color(b)
        width = thickness if (visible[a] and visible[b]) else 1
        cv2.line(out, tuple(map(int, fixed[a])), tuple(map(int, fixed[b])), color, width, cv2.LINE_AA, _SHIFT)
    r = int(np.round(radius * (1 << _SHIFT)))
    for i in range(kp.NUM_KEYPOINTS):
        if ok[i]:
            cv2.circle(out, tuple(map(int, fixed[i])), r, _keypoint_color(i), -1 if visible[i] else 1,
                       cv2.LINE_AA, _SHIFT)
    return out


def colorize_depth(depth_m: np.ndarray, near_m: float | None = None, far_m: float | None = None) -> np.ndarray:
    """Depth map to RGB (turbo): near red, far blue, background black; checked, since a sample sheet
    reads it from a file.

    Args:
        depth_m: (H, W) float, metres, 0 = background.
        near_m, far_m: metres mapped to the two ends of the colour scale (depths beyond them are
            clipped); None: the map's own nearest and farthest depth. A fixed range lets one
            :func:`depth_color_bar` describe several maps.

    Returns:
        (H, W, 3) uint8.
    """
    depth_m = check_shape(depth_m, ("H", "W"), "depth_m").astype(np.float64)
    hit = depth_m > 0
    out = np.zeros(depth_m.shape + (3,), dtype=np.uint8)
    if not hit.any():
        return out
    near = depth_m[hit].min() if near_m is None else near_m
    far = depth_m[hit].max() if far_m is None else far_m
    scaled = np.zeros(depth_m.shape, dtype=np.uint8)
    scaled[hit] = np.round(255 * np.clip((far - depth_m[hit]) / max(far - near, 1e-9), 0.0, 1.0)).astype(np.uint8)
    colored = cv2.applyColorMap(scaled, cv2.COLORMAP_TURBO)[..., ::-1]
    out[hit] = colored[hit]
    return out


def colorize_labels(seg: np.ndarray) -> np.ndarray:
    """Label map (0 background, 1 hand, 2 arm, 3 probe, 4 patient) to RGB; checked, since a sample sheet reads it from a file."""
    seg = np.asarray(seg)
    if seg.ndim != 2 or not np.issubdtype(seg.dtype, np.integer):
        raise BadValueError(f"seg must be an (H, W) integer label map, got {seg.shape} {seg.dtype}")
    if seg.size and seg.max() >= len(SEG_RGB):
        raise BadValueError(f"seg labels must be < {len(SEG_RGB)}, found {int(seg.max())}")
    return SEG_RGB[seg]


def _fit_line(text: str, width_px: int, scale: float) -> tuple[str, float]:
    """The text and the largest font scale <= ``scale`` (not below MIN_TEXT_SCALE) at which it fits
    ``width_px``; text that does not fit even then is cut and ends in "..".
    """
    while scale > MIN_TEXT_SCALE and text_width_px(text, scale) > width_px:
        scale = max(MIN_TEXT_SCALE, scale - 0.025)
    while len(text) > 2 and text_width_px(text, scale) > width_px:
        text = text[:-3] + ".."
    return text, scale


def text_width_px(text: str, scale: float) -> int:
    """Width in pixels of one line of text in the sheets' font at ``scale``."""
    return cv2.getTextSize(text, _FONT, scale, 1)[0][0]


def titled(image_rgb: np.ndarray, title: str, bar: int = 22) -> np.ndarray:
    """Put a white title bar above an image.

    Each line of ``title`` ("\n" separates lines) gets ``bar`` pixels, less 6 after the first; a
    line wider than the image is drawn smaller until it fits (then cut), never past the edge.
    """
    h, w = image_rgb.shape[:2]
    lines = title.split("\n")
    step = bar - 6
    height = bar + step * (len(lines) - 1)
    out = np.full((h + height, w, 3), 255, dtype=np.uint8)
    out[height:] = image_rgb
    for k, line in enumerate(lines):
        text, scale = _fit_line(line, w - 8, TITLE_SCALE)
        cv2.putText(out, text, (6 if w > 40 else 1, bar - 7 + k * step), _FONT, scale, (20, 20, 20), 1, cv2.LINE_AA)
    return out


def text_block(paragraphs: list[str], width: int, scale: float = 0.5, line_px: int = 20,
               color=(20, 20, 20)) -> np.ndarray:
    """White block of ``width`` pixels holding the paragraphs, word-wrapped to fit.

    Returns:
        (H, width, 3) uint8.
    """
    lines = []
    for paragraph in paragraphs:
        line = ""
        for word in paragraph.split(" "):
            trial = f"{line} {word}" if line else word
            if line and text_width_px(trial, scale) > width - 12:
                lines.append(line)
                line = word
            else:
                line = trial
        lines.append(line)
    out = np.full((line_px * len(lines) + 8, width, 3), 255, dtype=np.uint8)
    for k, line in enumerate(lines):
        text, fitted = _fit_line(line, width - 12, scale)
        cv2.putText(out, text, (6, line_px * (k + 1) - 3), _FONT, fitted, color, 1, cv2.LINE_AA)
    return out


def _nice_step(span: float, most: int) -> float:
    """The smallest 1-2-5 step giving at most ``most`` intervals over ``span``."""
    for exponent in range(-4, 4):
        for mantissa in (1.0, 2.0, 5.0):
            step = mantissa * 10.0**exponent
            if span / step <= most:
                return step
    return span


def depth_color_bar(near_m: float, far_m: float, width: int, height: int = 16,
                    title: str = "depth, metres (black: background, nothing rendered)") -> np.ndarray:
    """A horizontal colour bar for :func:`colorize_depth` with ``near_m``/``far_m``, ticks in metres.

    Its colours come from colorize_depth itself, so the bar and the maps cannot disagree.

    Args:
        near_m, far_m: the range the maps were coloured with, metres, near_m < far_m.
        width: total width, pixels (the bar leaves a margin for its end labels).

    Returns:
        (H, width, 3) uint8: title, bar, ticks and labels.
    """
    assert 0 < near_m < far_m, (near_m, far_m)
    margin = 24
    length = width - 2 * margin
    assert length > 20, width
    top = 22
    out = np.full((top + height + 26, width, 3), 255, dtype=np.uint8)
    cv2.putText(out, _fit_line(title, width - 12, 0.45)[0], (6, 15), _FONT, 0.45, (20, 20, 20), 1, cv2.LINE_AA)
    ramp_m = np.linspace(near_m, far_m, length)[None, :].repeat(height, axis=0)
    out[top : top + height, margin : margin + length] = colorize_depth(ramp_m, near_m, far_m)
    step = _nice_step(far_m - near_m, max(2, length // 70))
    decimals = max(0, -int(np.floor(np.log10(step) + 1e-9)))
    ticks = np.arange(np.ceil(near_m / step - 1e-9) * step, far_m + 1e-9, step)
    xs = [margin + int(np.round((value - near_m) / (far_m - near_m) * (length - 1))) for value in ticks]
    labels = [(x, f"{value:.{decimals}f}") for x, value in zip(xs, ticks)]
    for x in xs:
        cv2.line(out, (x, top + height), (x, top + height + 4), (20, 20, 20), 1)
    # the range's own ends, in grey, where no tick label is near
    ends = [(margin, near_m), (margin + length - 1, far_m)]
    ends = [(x, f"{value:.{decimals + 1}f}") for x, value in ends if all(abs(x - t) > 34 for t in xs)]
    for (x, label), color in [(item, (20, 20, 20)) for item in labels] + [(item, (110, 110, 110)) for item in ends]:
        cv2.putText(out, label, (x - text_width_px(label, 0.4) // 2, top + height + 18), _FONT, 0.4, color, 1,
                    cv2.LINE_AA)
    return out


def legend(title: str, entries: list[tuple[str, tuple[int, int, int], str]], width: int,
           scale: float = 0.42) -> np.ndarray:
    """A legend block: a title line, then swatches and labels wrapped over as many lines as needed.

    Args:
        title: first line.
        entries: (label, RGB colour, marker) with marker "square" (a filled box with a grey rim, as
            a mask colour), "dot" (a filled circle, a visible keypoint) or "ring" (a hollow circle,
            a hidden keypoint).
        width: pixels.

    Returns:
        (H, width, 3) uint8.
    """
    line_px, swatch = 22, 12
    placed, x, row = [], 6, 1
    for label, color, marker in entries:
        item = swatch + 6 + text_width_px(label, scale) + 16
        if x > 6 and x + item > width:
            x, row = 6, row + 1
        placed.append((x, row, label, color, marker))
        x += item
    out = np.full((line_px * (row + 1) + 4, width, 3), 255, dtype=np.uint8)
    cv2.putText(out, _fit_line(title, width - 12, 0.45)[0], (6, 15), _FONT, 0.45, (20, 20, 20), 1, cv2.LINE_AA)
    for x, row, label, color, marker in placed:
        y = line_px * row + line_px // 2
        color = tuple(int(c) for c in color)
        if marker == "square":
            cv2.rectangle(out, (x, y - swatch // 2), (x + swatch, y + swatch // 2), color, -1)
            cv2.rectangle(out, (x, y - swatch // 2), (x + swatch, y + swatch // 2), (120, 120, 120), 1)
        else:
            assert marker in ("dot", "ring"), marker
            cv2.circle(out, (x + swatch // 2, y), swatch // 2, color, -1 if marker == "dot" else 2, cv2.LINE_AA)
        cv2.putText(out, label, (x + swatch + 6, y + 5), _FONT, scale, (20, 20, 20), 1, cv2.LINE_AA)
    return out


def keypoint_legend_entries() -> list[tuple[str, tuple[int, int, int], str]]:
    """The colours :func:`draw_keypoints` uses, as :func:`legend` entries (hand joints per finger, probe corners)."""
    entries = [(f"{name} joints" if name != "wrist" else "wrist", color, "dot") for name, color in FINGER_RGB.items()]
    return entries + [("probe box corners", PROBE_RGB, "dot"), ("hollow: hidden", (120, 120, 120), "ring")]


def keypoint_radius_px(tile_px: int) -> float:
    """Joint marker radius that reads at a tile side of ``tile_px`` (a pixel of radius per 80 px of tile)."""
    return max(1.5, tile_px / 80.0)


def resize_with_keypoints(image_rgb: np.ndarray, uv: np.ndarray, side_px: int,
                          nearest: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Resize a square image to ``side_px`` and move its keypoints with it (pixel centres at integers).

    Drawing on the resized image, rather than resizing a drawing, keeps dots and lines one size
    whatever the stored resolution.

    Args:
        image_rgb: (H, H, 3) uint8.
        uv: (N, 2) float pixels of ``image_rgb``.
        side_px: output side.
        nearest: nearest-neighbour (label and depth maps) instead of area/linear interpolation.

    Returns:
        ((side_px, side_px, 3) uint8, (N, 2) float64 pixels of the resized image).
    """
    scale = side_px / image_rgb.shape[0]
    mode = cv2.INTER_NEAREST if nearest else (cv2.INTER_AREA if scale < 1 else cv2.INTER_LINEAR)
    resized = cv2.resize(np.ascontiguousarray(image_rgb), (side_px, side_px), interpolation=mode)
    return resized, (np.asarray(uv, dtype=np.float64) + 0.5) * scale - 0.5


def stack(blocks: list[np.ndarray], gap: int = 6) -> np.ndarray:
    """Stack RGB blocks top to bottom, left-aligned on white, as wide as the widest."""
    width = max(b.shape[1] for b in blocks)
    out = np.full((sum(b.shape[0] for b in blocks) + gap * (len(blocks) - 1), width, 3), 255, dtype=np.uint8)
    y = 0
    for b in blocks:
        out[y : y + b.shape[0], : b.shape[1]] = b
        y += b.shape[0] + gap
    return out


def beside(blocks: list[np.ndarray], gap: int = 6) -> np.ndarray:
    """Place RGB blocks left to right, top-aligned on white, as tall as the tallest."""
    height = max(b.shape[0] for b in blocks)
    out = np.full((height, sum(b.shape[1] for b in blocks) + gap * (len(blocks) - 1), 3), 255, dtype=np.uint8)
    x = 0
    for b in blocks:
        out[: b.shape[0], x : x + b.shape[1]] = b
        x += b.shape[1] + gap
    return out


def grid(tiles: list[np.ndarray], columns: int, gap: int = 6) -> np.ndarray:
    """Arrange equally sized RGB tiles in a grid with white gaps."""
    h, w = tiles[0].shape[:2]
    assert all(t.shape[:2] == (h, w) for t in tiles), [t.shape for t in tiles]
    rows = -(-len(tiles) // columns)
    out = np.full((rows * h + (rows + 1) * gap, columns * w + (columns + 1) * gap, 3), 255, dtype=np.uint8)
    for i, tile in enumerate(tiles):
        r, c = divmod(i, columns)
        y, x = gap + r * (h + gap), gap + c * (w + gap)
        out[y : y + h, x : x + w] = tile
    return out


def write_png(path, image_rgb: np.ndarray):
    """Write an RGB image as PNG atomically (temporary name, then rename)."""
    from hupbench.core.io import encode_image, write_bytes

    return write_bytes(path, encode_image(".png", np.ascontiguousarray(image_rgb[..., ::-1]),
                                          [cv2.IMWRITE_PNG_COMPRESSION, 9]))
