"""The user's camera in ``hupbench predict``: ``--K`` checked where it enters, and a prediction's keypoints mapped to the
original image's pixels and to the chosen camera (the training camera scaled to the image, or the user's).

Convention:
    Intrinsics (3, 3) in pixels of the original image unless named ``_in`` / ``K_model_input`` (model-input pixels);
    3D points in metres, OpenCV camera frame.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from hupbench.core.errors import BadValueError
from hupbench.inference.model_file import check_intrinsics
from hupbench.input_geometry import InputGeometry

__all__ = ["CAMERA_ASSUMED", "CAMERA_USER", "MAX_FOCAL_PX", "check_user_K", "keypoints_for_image", "parse_intrinsics",
           "user_camera_points"]

# a focal length or principal point beyond a million pixels is a typo (1e6 px on a 4000 px photo is a 0.2
# degree field of view) and 1e308 overflows the 3D points to infinity
MAX_FOCAL_PX = 1e6
CAMERA_ASSUMED = "assumed training camera"
CAMERA_USER = "user K"


def parse_intrinsics(text: str) -> np.ndarray:
    """Parse ``--K fx,fy,cx,cy`` (pixels of the original image) into a checked (3, 3) float64 matrix."""
    try:
        fx, fy, cx, cy = (float(p) for p in text.split(","))
    except ValueError:
        raise BadValueError(f"--K must be four numbers 'fx,fy,cx,cy' (pixels), got {text!r}") from None
    return check_user_K([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]], "--K")


def check_user_K(K: Any, name: str = "K") -> np.ndarray:
    """A user's (3, 3) intrinsics, pixels of the original image: finite, 0 < fx, fy <= MAX_FOCAL_PX,
    |cx|, |cy| <= MAX_FOCAL_PX (beyond that a value is a typo; see the constant)."""
    K = check_intrinsics(K, name)
    if max(K[0, 0], K[1, 1], abs(K[0, 2]), abs(K[1, 2])) > MAX_FOCAL_PX:
        raise BadValueError(f"{name}: fx and fy must be in (0, {MAX_FOCAL_PX:g}] and cx and cy in "
                            f"[-{MAX_FOCAL_PX:g}, {MAX_FOCAL_PX:g}] pixels, got fx={K[0, 0]:g}, fy={K[1, 1]:g}, "
                            f"cx={K[0, 2]:g}, cy={K[1, 2]:g}")
    return K


def user_camera_points(uv_in: np.ndarray, points3d_train: np.ndarray, K_train: np.ndarray,
                       K_user_in: np.ndarray, metric_depth: bool = False) -> np.ndarray:
    """3D keypoints for the user's camera from a network trained with another camera.

    The network judges depth from the object's size in pixels, so a point it sees at an input pixel with
    focal f_train lies, through the user's lens of focal f_user_in, at z_user = z * f_user_in / f_train
    (the geometric mean of the x and y ratios when fx != fy); x and y are back-projected from the 2D
    prediction at that depth, so the points project through K_user_in exactly onto it. A network that reads
    a depth map (``metric_depth``) measures z itself: it is kept.

    Args:
        uv_in: (N, 2) float, predicted 2D keypoints, model-input pixels.
        points3d_train: (N, 3) float, metres, the network's 3D output (camera K_train).
        K_train: (3, 3) intrinsics the network was trained with (K_input), model-input pixels.
        K_user_in: (3, 3) the user's intrinsics mapped to the model input.

    Returns:
        (N, 3) float64, metres, OpenCV camera frame of the user's camera.
    """
    uv_in, points3d_train = np.asarray(uv_in, dtype=np.float64), np.asarray(points3d_train, dtype=np.float64)
    focal_ratio = 1.0 if metric_depth else np.sqrt((K_user_in[0, 0] / K_train[0, 0]) * (K_user_in[1, 1] / K_train[1, 1]))
    z = points3d_train[:, 2] * focal_ratio
    x = (uv_in[:, 0] - K_user_in[0, 2]) * z / K_user_in[0, 0]
    y = (uv_in[:, 1] - K_user_in[1, 2]) * z / K_user_in[1, 1]
    return np.stack([x, y, z], axis=1)


def keypoints_for_image(points2d_norm: np.ndarray, points3d: np.ndarray, geometry: InputGeometry,
                        K_input: np.ndarray, K_user: np.ndarray | None = None,
                        metric_depth: bool = False) -> dict[str, Any]:
    """Map one image's network outputs to its original pixels and to the chosen camera.

    Args:
        points2d_norm: (N, 2) normalised input coordinates. points3d: (N, 3) metres, camera frame of K_input.
        geometry: how the image became the input. K_input: (3, 3) the training camera at the model input.
        K_user: (3, 3) the user's intrinsics of the original image, or None to assume the training camera.
        metric_depth: the network read a depth map (:func:`user_camera_points`).

    Returns:
        ``{"camera": str, "K": (3, 3) original pixels, "K_model_input": (3, 3), "keypoints_2d_px": (N, 2)
        original pixels, "keypoints_3d_m": (N, 3) metres, camera frame of "K"}``.
    """
    uv_px = geometry.normalized_to_image_px(points2d_norm)
    if K_user is None:
        return {"camera": CAMERA_ASSUMED, "K": geometry.intrinsics_to_image(K_input), "K_model_input": K_input,
                "keypoints_2d_px": uv_px, "keypoints_3d_m": np.asarray(points3d, dtype=np.float64)}
    K_user_in = geometry.intrinsics_to_input(K_user)
    xyz = user_camera_points(geometry.normalized_to_input_px(points2d_norm), points3d, K_input, K_user_in, metric_depth)
    return {"camera": CAMERA_USER, "K": np.asarray(K_user, dtype=np.float64), "K_model_input": K_user_in,
            "keypoints_2d_px": uv_px, "keypoints_3d_m": xyz}
