"""The out-of-distribution check of ``hupbench predict``: is an image like the frames the model was trained on?

Numpy and OpenCV only (the torch-free path). Ten statistics of an image (:data:`STATISTIC_NAMES`), taken on
the image resized so that its longer side is the model's input size S, without the square's padding (a
padded photo and a square one of the same scene score alike):

    mean and standard deviation of R, G and B (in [0, 1]); mean and standard deviation of the HSV saturation;
    log of the mean Sobel gradient magnitude of the grey image; log of the variance of its Laplacian.

``hupbench export`` calibrates them on the model's dataset (:func:`calibrate`): the mean and a shrunk
covariance (:data:`SHRINKAGE` of the way to its average variance, so that few frames still give an
invertible matrix) of up to :data:`TRAIN_FRAMES` training frames; the threshold is the :data:`PERCENTILE`
percentile of the distance of up to :data:`THRESHOLD_FRAMES` validation frames (test frames when a dataset
has no validation split, training frames when it has neither). An image whose Mahalanobis distance to the
training frames exceeds it is flagged: about 1 % of frames like the validation frames are. The statistics need
no graph output and work for every model type (the RGB of a depth model); ``scripts/measure_ood_statistics.py``
compares them with the backbone's features (README, prediction section). They judge how an image looks, not
whether it holds a hand: a rendered frame without any hand passes.

Depth, for a model that reads it: the calibration also keeps the lowest and highest median depth of the training
frames (the median of a map's valid, non-zero values, metres). A depth map whose median lies outside that range
widened by the factor :data:`DEPTH_MARGIN` is refused (:meth:`ImageStatistics.check_depth`): a map in another
unit than ``--depth-scale-m`` says is off by a factor 10 or more (millimetres read as 0.1 mm, a scale ten times
the map's), a camera at another distance by less. The factor is chosen on the quickstart dataset's validation
split (``scripts/measure_depth_range.py``; README, prediction section).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from hupbench.core.errors import BadValueError

__all__ = ["DEPTH_MARGIN", "PERCENTILE", "SHRINKAGE", "STATISTIC_NAMES", "ImageStatistics", "calibrate",
           "depth_median_m", "image_statistics"]

STATISTIC_NAMES = ("mean_r", "mean_g", "mean_b", "std_r", "std_g", "std_b", "saturation_mean", "saturation_std",
                   "log_gradient_mean", "log_laplacian_var")
#: fraction of the way from the training frames' covariance to its mean variance times the identity
SHRINKAGE = 0.1
#: percentile of the calibration frames' distances that becomes the threshold
PERCENTILE = 99.0
#: frames, evenly spaced over the split, for the mean and covariance (train) and for the threshold
TRAIN_FRAMES = 2000
THRESHOLD_FRAMES = 500
#: how far beyond the training frames' median depths a depth map's median may lie: a factor on either side
DEPTH_MARGIN = 1.5
_EPS = 1e-6  # keeps the logs finite on a constant image
STATISTIC = ("Mahalanobis distance of 10 image statistics (mean and std of R, G, B and of HSV saturation, log mean "
             "Sobel gradient, log Laplacian variance; image resized to the model input's scale, no padding) to the "
             "training frames' mean and covariance")


def image_statistics(image_rgb: np.ndarray, input_size: int) -> np.ndarray:
    """The :data:`STATISTIC_NAMES` of one image.

    Args:
        image_rgb: (H, W, 3) float32 RGB in [0, 1], the image as :func:`hupbench.inference.images.read_image`
            returns it.
        input_size: S, the model's input size in pixels: the image is resized (``cv2.INTER_AREA``) so that its
            longer side is S.

    Returns:
        (10,) float64.
    """
    height, width = image_rgb.shape[:2]
    scale = input_size / max(height, width)
    size = (max(1, round(width * scale)), max(1, round(height * scale)))
    image = np.asarray(image_rgb, dtype=np.float32)
    if size != (width, height):
        image = cv2.resize(image, size, interpolation=cv2.INTER_AREA).reshape(size[1], size[0], 3)
    # OpenCV's means and deviations sum in float64 (numpy's float32 sums over the channel-strided axes drifted by
    # up to 4e-4 of the value) and cost a fifth of numpy's (predict's frame rate); the gradient is numpy's hypot:
    # cv2.magnitude's last digits differed between two exports of one model in one test process (the CLI's and the
    # library call's), and so did the exported files' bytes
    mean, std = cv2.meanStdDev(image)
    saturation_mean, saturation_std = cv2.meanStdDev(cv2.cvtColor(image, cv2.COLOR_RGB2HSV)[..., 1].copy())
    grey = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
    gradient = np.hypot(cv2.Sobel(grey, cv2.CV_32F, 1, 0), cv2.Sobel(grey, cv2.CV_32F, 0, 1))
    _, laplacian_std = cv2.meanStdDev(cv2.Laplacian(grey, cv2.CV_32F))
    return np.array([*mean[:, 0], *std[:, 0], saturation_mean[0, 0], saturation_std[0, 0],
                     math.log(float(gradient.mean(dtype=np.float64)) + _EPS), math.log(laplacian_std[0, 0] ** 2 + _EPS)],
                    dtype=np.float64)


def depth_median_m(depth_m: np.ndarray) -> float:
    """The median of a depth map's valid values: (H, W) metres, 0 where nothing was seen -> metres, NaN when no
    value is valid."""
    valid = np.asarray(depth_m)[np.asarray(depth_m) > 0]
    return float(np.median(valid)) if valid.size else math.nan


@dataclass(frozen=True)
class ImageStatistics:
    """A calibration of the check (module docstring), as stored in ``hupbench.image_statistics``.

    Attributes:
        mean: (10,) float64, the training frames' mean statistics.
        precision: (10, 10) float64, the inverse of their shrunk covariance.
        threshold: distances above it are flagged.
        frames: {"train": frames of the mean and covariance, "threshold": frames of the threshold,
            "threshold_split": the split they came from}.
        percentile: the percentile of those frames' distances that ``threshold`` is (:data:`PERCENTILE` when
            calibrated; a file says which it used).
        depth_median_m: (lowest, highest) median depth of the training frames' depth maps, metres
            (:func:`depth_median_m`); None for a model that reads no depth.
    """

    mean: np.ndarray
    precision: np.ndarray
    threshold: float
    frames: dict
    percentile: float = PERCENTILE
    depth_median_m: tuple[float, float] | None = None

    def check_depth(self, depth: np.ndarray, scale_m: float, source: str) -> None:
        """Refuse a depth map whose median valid depth lies outside the training frames' (module docstring).

        Args:
            depth: (H, W) the map as stored, ``scale_m`` metres per unit, 0 where nothing was seen.
            source: the file, which the error names.
        """
        if self.depth_median_m is None:
            return
        median = depth_median_m(np.asarray(depth, dtype=np.float64) * scale_m)
        low, high = self.depth_median_m[0] / DEPTH_MARGIN, self.depth_median_m[1] * DEPTH_MARGIN
        if not low <= median <= high:
            raise BadValueError(f"{source}: its median depth is {median:.3g} m at --depth-scale-m {scale_m:g}, outside "
                                f"the {low:.2f}-{high:.2f} m the model accepts (its training frames' medians "
                                f"{self.depth_median_m[0]:.2f}-{self.depth_median_m[1]:.2f} m, widened by a factor "
                                f"{DEPTH_MARGIN:g}): is the map in another unit? The dataset's PNGs hold 0.1 mm "
                                "(--depth-scale-m 1e-4)")

    def distance(self, statistics: np.ndarray) -> np.ndarray:
        """(B,) float64 Mahalanobis distances of (B, 10) statistics."""
        d = np.asarray(statistics, dtype=np.float64) - self.mean
        return np.sqrt(np.maximum(np.einsum("bi,ij,bj->b", d, self.precision, d), 0.0))

    def to_json(self) -> str:
        depth = {} if self.depth_median_m is None else {"depth_median_m": list(self.depth_median_m)}
        return json.dumps({"statistic": STATISTIC, "names": list(STATISTIC_NAMES), "mean": self.mean.tolist(),
                           "precision": self.precision.tolist(), "threshold": self.threshold,
                           "percentile": self.percentile, "shrinkage": SHRINKAGE, "frames": self.frames} | depth,
                          sort_keys=True)

    @classmethod
    def from_json(cls, text: str, source: str) -> ImageStatistics:
        """Read ``hupbench.image_statistics``; ``source`` names the file in errors."""
        name = f"{source}: metadata hupbench.image_statistics"
        try:
            data = json.loads(text)
            names, frames = data["names"], data["frames"]
            mean = np.asarray(data["mean"], dtype=np.float64)
            precision = np.asarray(data["precision"], dtype=np.float64)
            threshold, percentile = float(data["threshold"]), float(data["percentile"])
            depth = data.get("depth_median_m")
            depth = None if depth is None else tuple(np.asarray(depth, dtype=np.float64).reshape(2).tolist())
        except (json.JSONDecodeError, KeyError, TypeError, ValueError) as exc:
            raise BadValueError(f"{name} is not a calibration of {len(STATISTIC_NAMES)} image statistics "
                                f"({type(exc).__name__}: {exc}): {text[:80]!r}") from None
        n = len(STATISTIC_NAMES)
        if tuple(names) != STATISTIC_NAMES:
            raise BadValueError(f"{name} names the statistics {names!r:.160}; this hupbench computes "
                                f"{list(STATISTIC_NAMES)}")
        if (mean.shape != (n,) or precision.shape != (n, n) or not np.all(np.isfinite(mean))
                or not np.all(np.isfinite(precision)) or not np.isfinite(threshold) or threshold <= 0
                or not (depth is None or 0 < depth[0] <= depth[1] < math.inf)):
            raise BadValueError(f"{name} must hold a finite mean ({n},), precision ({n}, {n}), threshold > 0 and "
                                f"depth_median_m [low, high] with 0 < low <= high or none, got shapes {mean.shape}, "
                                f"{precision.shape}, threshold {threshold!r} and depth_median_m {depth!r}")
        return cls(mean, precision, threshold, dict(frames), percentile, depth)

    def describe(self) -> dict[str, Any]:
        """What ``predictions.json`` says about the check."""
        depth = {} if self.depth_median_m is None else {
            "depth_median_m": [round(v, 4) for v in self.depth_median_m],
            "depth_rule": f"a depth map's median valid depth within the training frames' medians widened by a factor "
                          f"{DEPTH_MARGIN:g}"}
        return {"statistic": STATISTIC, "threshold": round(self.threshold, 4),
                "threshold_rule": f"percentile {self.percentile:g} of the calibration frames' distances",
                "frames": self.frames} | depth


def calibrate(train_statistics: np.ndarray, threshold_statistics: np.ndarray, threshold_split: str,
              train_depth_medians_m: np.ndarray | None = None) -> ImageStatistics:
    """The check's calibration (module docstring) from (T, 10) training-frame statistics (T >= 2) and (V, 10)
    statistics of the frames that set the threshold (V >= 1), taken from ``threshold_split``; for a model that
    reads depth, (F,) the training frames' :func:`depth_median_m` (NaN for a map with no valid value)."""
    train = np.asarray(train_statistics, dtype=np.float64)
    assert train.ndim == 2 and train.shape[0] >= 2, train.shape
    covariance = np.cov(train, rowvar=False)
    n = covariance.shape[0]
    shrunk = (1.0 - SHRINKAGE) * covariance + SHRINKAGE * np.trace(covariance) / n * np.eye(n)
    shrunk += _EPS * np.eye(n)  # identical frames: a zero covariance
    provisional = ImageStatistics(train.mean(axis=0), np.linalg.inv(shrunk), 1.0, {})
    threshold = float(np.percentile(provisional.distance(threshold_statistics), PERCENTILE))
    frames = {"train": int(train.shape[0]), "threshold": len(threshold_statistics),
              "threshold_split": threshold_split}
    depth = None
    if train_depth_medians_m is not None:
        depth = (float(np.nanmin(train_depth_medians_m)), float(np.nanmax(train_depth_medians_m)))
    return ImageStatistics(provisional.mean, provisional.precision, max(threshold, _EPS), frames, PERCENTILE, depth)
