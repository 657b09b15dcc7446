"""Reading a user's video for ``hupbench predict`` and writing its overlay video (numpy and OpenCV only).

A video file (:data:`hupbench.inference.images.VIDEO_SUFFIXES`, by name) is read frame by frame with OpenCV's
``VideoCapture``, never whole (an hour at 1080p is hundreds of gigabytes of pixels): :class:`VideoFrames` yields each
frame's index, time and RGB image in [0, 1], as :func:`hupbench.inference.images.read_image` gives a still. Checked
before the first frame: OpenCV opens it, it declares a frame rate, its frames are within the still images' size
limits. A file that ends before the frame count its header declares is truncated: the frames that decode are yielded
and :attr:`VideoFrames.truncated` says so afterwards. :class:`OverlayVideo` writes the overlays at the video's rate,
to a temporary name renamed into place when the last frame is in.

Convention:
    Frame ``i`` is at ``i / fps`` seconds from the first; images are (H, W, 3) float32 RGB in [0, 1] in, BGR
    uint8 out to the writer.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import cv2
import numpy as np

from hupbench.core.errors import BadValueError, MissingFileError, RunFailedError
from hupbench.inference.images import MAX_IMAGE_SIDE, MIN_IMAGE_SIDE, VIDEO_SUFFIXES

__all__ = ["OVERLAY_FOURCC", "OverlayVideo", "VideoFrames", "is_video"]
#: the overlay video's codec (MPEG-4 part 2 in an .mp4: OpenCV's pip wheels write it without extra libraries)
OVERLAY_FOURCC = "mp4v"


def is_video(path: Path) -> bool:
    return Path(path).suffix.lower() in VIDEO_SUFFIXES


class VideoFrames:
    """The frames of one video file, checked when opened (the module docstring).

    Args:
        path: the video file.

    Raises:
        MissingFileError: no such file. BadValueError: OpenCV cannot open it as a video, it declares no frame
            rate, or its frames are smaller or larger than predict's image limits (the message names the file).
    """

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        if not self.path.is_file():
            raise MissingFileError(f"{self.path}: no such video file")
        self._capture = cv2.VideoCapture(str(self.path))
        if not self._capture.isOpened():
            self._capture.release()
            raise BadValueError(f"{self.path}: not a readable video (OpenCV cannot open it: a damaged file, or a "
                                "codec it lacks)")
        self.fps = float(self._capture.get(cv2.CAP_PROP_FPS))
        self.declared_frames = int(self._capture.get(cv2.CAP_PROP_FRAME_COUNT))
        self.width = int(self._capture.get(cv2.CAP_PROP_FRAME_WIDTH))
        self.height = int(self._capture.get(cv2.CAP_PROP_FRAME_HEIGHT))
        problem = None
        if not (math.isfinite(self.fps) and self.fps > 0):
            problem = "declares no frame rate (its frames have no times)"
        elif min(self.width, self.height) < MIN_IMAGE_SIDE or max(self.width, self.height) > MAX_IMAGE_SIDE:
            problem = (f"frames of {self.width} x {self.height} px, outside {MIN_IMAGE_SIDE} px on the shorter side "
                       f"to {MAX_IMAGE_SIDE} px on the longer")
        if problem is not None:
            self._capture.release()
            raise BadValueError(f"{self.path}: {problem}")
        #: frames yielded so far
        self.decoded = 0

    def __iter__(self):
        """(index, time_s, (H, W, 3) float32 RGB in [0, 1]) per frame, in order; releases the file at the end."""
        try:
            while True:
                ok, bgr = self._capture.read()
                if not ok:
                    return
                yield self.decoded, self.decoded / self.fps, bgr[..., ::-1].astype(np.float32) / 255.0
                self.decoded += 1
        finally:
            self._capture.release()

    @property
    def truncated(self) -> str | None:
        """After iterating: what is missing when fewer frames decoded than the header declares, else None."""
        if self.decoded == 0:
            return "no frame decodes"
        if self.declared_frames > 0 and self.decoded < self.declared_frames:
            return f"truncated: {self.decoded} of the {self.declared_frames} frames its header declares decode"
        return None


class OverlayVideo:
    """The overlay video of one input video, written at its rate to a temporary name until :meth:`close`.

    Args:
        path: where the finished video goes (``.mp4``).
        fps: frames per second. size: (width, height) pixels of every frame.
    """

    def __init__(self, path: Path, fps: float, size: tuple[int, int]) -> None:
        self.path = Path(path)
        self.tmp = self.path.with_name(f".{self.path.stem}.tmp{os.getpid()}{self.path.suffix}")
        self._writer = cv2.VideoWriter(str(self.tmp), cv2.VideoWriter_fourcc(*OVERLAY_FOURCC), fps, size)
        if not self._writer.isOpened():
            self.tmp.unlink(missing_ok=True)
            raise BadValueError(f"{self.path}: OpenCV cannot write an {OVERLAY_FOURCC} video here")

    def write(self, rgb_uint8: np.ndarray) -> None:
        self._writer.write(np.ascontiguousarray(rgb_uint8[..., ::-1]))

    def close(self) -> Path:
        """Finish the file and move it into place; its path."""
        self._writer.release()
        if not self.tmp.is_file() or self.tmp.stat().st_size == 0:
            raise RunFailedError(f"{self.path}: OpenCV wrote no overlay video (a full disk, or a lost folder)")
        os.replace(self.tmp, self.path)
        return self.path

    def discard(self) -> None:
        """Drop an unfinished file (a failed run leaves no overlay that looks complete)."""
        self._writer.release()
        self.tmp.unlink(missing_ok=True)
