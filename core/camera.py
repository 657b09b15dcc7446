"""Pinhole cameras: intrinsics, look-at extrinsics, projection, axis conventions.

Convention:
    Annotations use the OpenCV camera frame: x right, y down, z forward
    (into the scene). pyrender uses OpenGL camera axes: x right, y up,
    z backward. :func:`swap_gl_cv_axes` is the one function that converts
    between them. ``T_cam_world`` maps world points into the (OpenCV)
    camera frame; ``T_world_cam`` is the camera pose.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hupbench.core import tolerances as tol
from hupbench.core.geometry import check_last_axes, invert_transform, make_transform
from hupbench.core.input_checks import check_int, check_number
from hupbench.core.errors import BadValueError

#: diag(1, -1, -1): flips y and z, mapping OpenCV camera axes to OpenGL ones and back
_FLIP_YZ = np.diag([1.0, -1.0, -1.0, 1.0])


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics in pixels; the image is ``width`` x ``height``.

    Pixel centres sit at integer coordinates: pixel (u, v) covers
    [u - 0.5, u + 0.5] x [v - 0.5, v + 0.5] (OpenCV's convention).
    """

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    def __post_init__(self) -> None:
        for name in ("width", "height"):
            check_int(getattr(self, name), f"image {name}", low=1)
        for name in ("fx", "fy"):
            v = getattr(self, name)
            if not np.isfinite(v) or v <= 0:
                raise BadValueError(f"focal length {name} must be positive and finite, got {v!r}")
        for name in ("cx", "cy"):
            if not np.isfinite(getattr(self, name)):
                raise BadValueError(f"principal point {name} must be finite, got {getattr(self, name)!r}")

    @property
    def K(self) -> np.ndarray:
        """(3, 3) float64 camera matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @classmethod
    def from_lens(cls, focal_mm: float, sensor_mm: float, width: int, height: int) -> "Intrinsics":
        """Blender-style lens on a sensor fitted to the larger image side.

        HUP-3D: 60 mm on 32 mm at 256 x 256 gives fx = fy = 480, cx = cy = 128.
        """
        check_number(focal_mm, "focal_mm", 0.0, low_open=True)
        check_number(sensor_mm, "sensor_mm", 0.0, low_open=True)
        f = focal_mm / sensor_mm * max(width, height)
        return cls(f, f, width / 2.0, height / 2.0, width, height)


def swap_gl_cv_axes(T_world_cam: np.ndarray) -> np.ndarray:
    """Convert a camera pose between OpenCV and OpenGL camera axes.

    The change of axes flips y and z; it is its own inverse, so the same call
    converts OpenCV -> OpenGL and OpenGL -> OpenCV.

    Args:
        T_world_cam: (..., 4, 4) float camera-to-world pose in one convention.

    Returns:
        (..., 4, 4) float64 the same pose in the other convention.
    """
    T_world_cam = check_last_axes(T_world_cam, (4, 4), "T_world_cam")
    return T_world_cam @ _FLIP_YZ


def look_at(eye_world: np.ndarray, target_world: np.ndarray, up_world=(0.0, 0.0, 1.0)) -> np.ndarray:
    """OpenCV camera pose looking from ``eye`` at ``target``.

    The image's "up" (-y of the camera) is the projection of ``up_world`` on
    the image plane. When the view is parallel to ``up_world`` (a camera at a
    pole of the viewpoint sphere) the up vector is replaced by the world axis
    least aligned with the view direction (ties go to x, then y), so that
    every viewpoint has a defined, finite pose.

    Args:
        eye_world: (3,) float, metres, camera centre in the world frame.
        target_world: (3,) float, metres, point on the optical axis.
        up_world: (3,) float, direction that should point up in the image.

    Returns:
        (4, 4) float64 ``T_cam_world`` (OpenCV axes).
    """
    eye = check_last_axes(eye_world, (3,), "eye_world").reshape(3)
    target = check_last_axes(target_world, (3,), "target_world").reshape(3)
    up = check_last_axes(up_world, (3,), "up_world").reshape(3)
    forward = target - eye
    dist = np.linalg.norm(forward)
    # the camera distances (DatasetSpec.z_ego_m, PreviewView.distance_m) are checked positive
    assert dist >= tol.MIN_PROJECTION_DEPTH_M and np.linalg.norm(up) > 0, (eye, target, up)
    z = forward / dist
    up = up / np.linalg.norm(up)
    if np.linalg.norm(np.cross(z, up)) < tol.LOOK_AT_PARALLEL:
        up = np.eye(3)[int(np.argmin(np.abs(z)))]
    x = np.cross(z, up)  # OpenCV: y points down, so y = z x x comes out as -up
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R_world_cam = np.stack([x, y, z], axis=1)
    return invert_transform(make_transform(R_world_cam, eye))


def project_points(points_cam: np.ndarray, K: np.ndarray, behind: str = "raise") -> np.ndarray:
    """Pinhole projection of camera-frame points (no distortion).

    Args:
        points_cam: (..., N, 3) float, metres, OpenCV camera frame.
        K: (3, 3) or (..., 3, 3) float camera matrix.
        behind: what to do with points at or behind the camera plane
            (z < MIN_PROJECTION_DEPTH_M): "raise" a ValueError naming them, or
            return "nan" for them.

    Returns:
        (..., N, 2) float64 pixel coordinates (u, v).
    """
    assert behind in ("raise", "nan"), behind
    points_cam = check_last_axes(points_cam, (3,), "points_cam")
    K = check_last_axes(K, (3, 3), "K")
    z = points_cam[..., 2]
    bad = z < tol.MIN_PROJECTION_DEPTH_M
    if np.any(bad) and behind == "raise":
        idx = np.argwhere(bad)[:5].tolist()
        raise BadValueError(
            f"{int(bad.sum())} point(s) at or behind the camera plane (z <= 0), first indices {idx}"
        )
    safe_z = np.where(bad, 1.0, z)[..., None]
    xy1 = np.concatenate([points_cam[..., :2] / safe_z, np.ones_like(safe_z)], axis=-1)
    uv = np.einsum("...ij,...nj->...ni", K, xy1)[..., :2]
    return np.where(bad[..., None], np.nan, uv)


def resize_intrinsics(K: np.ndarray, scale: float, offset=(0.0, 0.0)) -> np.ndarray:
    """Intrinsics after padding the image by ``offset`` pixels (left, top), then resizing it by ``scale``.

    Convention: pixel centres at integers, so a pixel u maps to u' = (u + offset + 0.5) * scale - 0.5;
    fx' = fx * scale and cx' = (cx + offset_x + 0.5) * scale - 0.5 (likewise y).

    Args:
        K: (..., 3, 3) intrinsics, pixels. scale: new pixels per old pixel. offset: (2,) pixels added
            on the left and top before resizing.

    Returns:
        (..., 3, 3) float64 intrinsics of the resized image.
    """
    out = np.array(K, dtype=np.float64, copy=True)
    out[..., :2, :2] *= scale
    out[..., :2, 2] = (out[..., :2, 2] + np.asarray(offset, dtype=np.float64) + 0.5) * scale - 0.5
    return out


def resize_points(uv: np.ndarray, scale: float, offset=(0.0, 0.0)) -> np.ndarray:
    """(..., 2) pixel coordinates after padding by ``offset`` and resizing by ``scale`` (see resize_intrinsics)."""
    return (np.asarray(uv, dtype=np.float64) + np.asarray(offset, dtype=np.float64) + 0.5) * scale - 0.5
