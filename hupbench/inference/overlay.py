"""Predicted keypoints drawn on the original image: hand skeleton and probe box (numpy + OpenCV only).

Convention:
    Images are RGB uint8 (H, W, 3); pixel coordinates (u, v) follow OpenCV
    (pixel centres at integers). Colours come from the keypoint names (the
    ``hupbench.keypoint_names`` of the ONNX metadata): one colour per finger
    (``thumb_*``, ``index_*``, ...), grey for the wrist, orange for the probe
    box corners (``probe_corner_*``); an edge takes the colour of its second
    keypoint, as in :func:`hupbench.core.draw.draw_keypoints`. Lines scale with the
    image so that an overlay on a phone photo is as readable as on a 64 px frame.
    With a per-keypoint confidence in [0, 1], a marker's disc is filled in proportion
    to it (a full disc at 1, a bare ring at 0), and a warning (the
    out-of-distribution check's) is written on a red band across the top.
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np

from hupbench.core.draw import FINGER_RGB, PROBE_RGB

OTHER_RGB = (200, 200, 200)
HALO_RGB = (0, 0, 0)  # a dark rim under every line keeps it visible on bright and dark photos alike
WARNING_RGB = (200, 30, 30)
_SHIFT = 2  # fixed-point bits for sub-pixel drawing
_PIXELS_PER_LINE_WIDTH = 320  # one more pixel of line width for every 320 px of the longer image side


def keypoint_color(name: str) -> tuple[int, int, int]:
    """(r, g, b) uint8 colour of a keypoint name such as ``"index_pip"``, ``"wrist"`` or ``"probe_corner_-x+y-z"``."""
    if name.startswith("probe"):
        return PROBE_RGB
    return FINGER_RGB.get(name.split("_")[0], OTHER_RGB)


def line_width(height: int, width: int) -> int:
    """Line thickness in pixels for an image of this size (1 px up to 479 px, 2 px from 480 px, ...)."""
    return max(1, round(max(height, width) / _PIXELS_PER_LINE_WIDTH))


def draw_prediction(image_rgb: np.ndarray, uv: np.ndarray, names: Sequence[str], edges: Sequence[Sequence[int]],
                    confidence: np.ndarray | None = None, warning: str | None = None) -> np.ndarray:
    """A drawn (H, W, 3) uint8 copy of the original ``image_rgb``: the keypoints ``uv`` ((N, 2) float, its
    pixels; a non-finite row is not drawn, nor its edges) named by ``names``, joined by ``edges`` (pairs of
    indices). Probe box edges go first, hand edges over them, then the markers: the hand stays on top
    where it covers the probe. ``confidence``: (N,) float in [0, 1] or None (full discs); ``warning``: text
    for a red band across the top, or None."""
    uv = np.asarray(uv, dtype=np.float64)
    assert image_rgb.dtype == np.uint8 and image_rgb.shape[2:] == (3,) and uv.shape == (len(names), 2)
    edge_array = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    colors = [keypoint_color(name) for name in names]
    is_corner = np.array([name.startswith("probe") for name in names], dtype=bool)

    out = np.ascontiguousarray(image_rgb.copy())
    thickness = line_width(*out.shape[:2])
    radius = round((1.2 * thickness + 1.5) * (1 << _SHIFT))
    ok = np.all(np.isfinite(uv), axis=1)
    fixed = np.round(np.where(ok[:, None], uv, 0.0) * (1 << _SHIFT)).astype(np.int64)
    fixed = np.clip(fixed, -(1 << 28), 1 << 28)  # keep far-off predictions in OpenCV's int32 range
    points = [tuple(map(int, p)) for p in fixed]

    box_first = sorted(edge_array.tolist(), key=lambda e: not (is_corner[e[0]] and is_corner[e[1]]))
    for a, b in box_first:
        if ok[a] and ok[b]:
            cv2.line(out, points[a], points[b], HALO_RGB, thickness + 2, cv2.LINE_AA, _SHIFT)
            cv2.line(out, points[a], points[b], colors[b], thickness, cv2.LINE_AA, _SHIFT)
    filled = np.ones(len(names)) if confidence is None else np.clip(np.nan_to_num(confidence), 0.0, 1.0)
    for i in np.flatnonzero(ok):
        cv2.circle(out, points[i], radius + (1 << _SHIFT), HALO_RGB, -1, cv2.LINE_AA, _SHIFT)
        # the disc's area, not its radius, in proportion to the confidence; the ring stays to show where
        cv2.circle(out, points[i], radius, colors[i], max(1, thickness // 2), cv2.LINE_AA, _SHIFT)
        inner = round(radius * np.sqrt(filled[i]))
        if inner >= 1 << _SHIFT:
            cv2.circle(out, points[i], inner, colors[i], -1, cv2.LINE_AA, _SHIFT)
    if warning is not None:
        _draw_banner(out, warning, thickness)
    return out


def _draw_banner(image: np.ndarray, text: str, thickness: int) -> None:
    """``text`` in white on a red band across the top of ``image`` (in place), scaled to fit its width."""
    height, width = image.shape[:2]
    scale = 0.4 * thickness
    (text_w, text_h), base = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, thickness)
    if text_w > width - 4:
        scale *= (width - 4) / text_w
        (text_w, text_h), base = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, thickness)
    band = min(height, text_h + base + 4)
    image[:band] = (0.3 * image[:band] + 0.7 * np.array(WARNING_RGB)).astype(np.uint8)
    cv2.putText(image, text, (2, band - base - 2), cv2.FONT_HERSHEY_SIMPLEX, scale, (255, 255, 255), thickness,
                cv2.LINE_AA)
