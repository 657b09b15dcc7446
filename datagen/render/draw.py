"""Drawing keypoints, skeletons, depth and label maps (numpy + OpenCV only, no torch).

Convention:
    Images are RGB uint8 (H, W, 3); pixel coordinates (u, v) follow OpenCV
    (pixel centres at integers). Drawing uses 4x sub-pixel precision.
"""

from __future__ import annotations

import cv2
import numpy as np

from datagen import keypoints as kp
from datagen.errors import BadValueError, RunFailedError

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
SEG_RGB = np.array([[0, 0, 0], [90, 110, 230], [240, 170, 90], [235, 235, 235]], dtype=np.uint8)
_SHIFT = 2  # fixed-point bits for sub-pixel drawing


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
    r = int(round(radius * (1 << _SHIFT)))
    for i in range(kp.NUM_KEYPOINTS):
        if ok[i]:
            cv2.circle(out, tuple(map(int, fixed[i])), r, _keypoint_color(i), -1 if visible[i] else 1,
                       cv2.LINE_AA, _SHIFT)
    return out


def colorize_depth(depth_m: np.ndarray) -> np.ndarray:
    """Depth map to RGB: near bright, far dark (turbo), background black; checked, since a sample sheet
    reads it from a file.

    Args:
        depth_m: (H, W) float, metres, 0 = background.

    Returns:
        (H, W, 3) uint8.
    """
    depth_m = np.asarray(depth_m, dtype=np.float64)
    if depth_m.ndim != 2:
        raise BadValueError(f"depth_m must be (H, W), got {depth_m.shape}")
    hit = depth_m > 0
    out = np.zeros(depth_m.shape + (3,), dtype=np.uint8)
    if not hit.any():
        return out
    near, far = depth_m[hit].min(), depth_m[hit].max()
    scaled = np.zeros(depth_m.shape, dtype=np.uint8)
    scaled[hit] = np.round(255 * (far - depth_m[hit]) / max(far - near, 1e-9)).astype(np.uint8)
    colored = cv2.applyColorMap(scaled, cv2.COLORMAP_TURBO)[..., ::-1]
    out[hit] = colored[hit]
    return out


def colorize_labels(seg: np.ndarray) -> np.ndarray:
    """Label map (0 background, 1 hand, 2 arm, 3 probe) to RGB; checked, since a sample sheet reads it from a file."""
    seg = np.asarray(seg)
    if seg.ndim != 2 or not np.issubdtype(seg.dtype, np.integer):
        raise BadValueError(f"seg must be an (H, W) integer label map, got {seg.shape} {seg.dtype}")
    if seg.size and seg.max() >= len(SEG_RGB):
        raise BadValueError(f"seg labels must be < {len(SEG_RGB)}, found {int(seg.max())}")
    return SEG_RGB[seg]


def titled(image_rgb: np.ndarray, title: str, bar: int = 22) -> np.ndarray:
    """Put a white title bar above an image."""
    h, w = image_rgb.shape[:2]
    out = np.full((h + bar, w, 3), 255, dtype=np.uint8)
    out[bar:] = image_rgb
    cv2.putText(out, title, (6, bar - 7), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (20, 20, 20), 1, cv2.LINE_AA)
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
    from datagen.io import write_bytes

    ok, buf = cv2.imencode(".png", np.ascontiguousarray(image_rgb[..., ::-1]))
    if not ok:
        raise RunFailedError(f"PNG encoding failed for {path}")
    return write_bytes(path, buf.tobytes())
