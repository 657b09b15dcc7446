"""Benchmark metrics as pure functions: numpy in -> numpy/float out, torch in -> torch out, same numbers.

Convention:
    Inputs are metres (3D, OpenCV camera frame of the model-input camera) or pixels (2D); every
    reported number is millimetres (``_mm``), pixels (``_px``) or a fraction in [0, 1]. Keypoint
    order is :mod:`datagen.keypoints`: 0..20 the hand (0 = wrist, the root), 21..28 the probe box
    corners.

Averaging:
    MPJPE (paper Sec. 4; REFERENCE.md) is the absolute camera-frame Euclidean error, no root or
    Procrustes alignment, averaged over keypoints and frames. ``mpjpe_split_mm`` reports "hand"
    (21 keypoints), "probe" (8 corners) and "all" (the mean over all 29 keypoints and all frames,
    i.e. keypoint-weighted: all = (21 hand + 8 probe) / 29). The paper's HOPE-Net row (all 8.65,
    hand 5.33, probe 17.05 mm) is not keypoint-weighted: (21 x 5.33 + 8 x 17.05) / 29 = 8.56, not
    8.65. Rounding of the published numbers cannot explain the gap (with every number moved by
    the 0.005 mm of rounding the keypoint-weighted mean is at most 8.57); 8.65 corresponds to the
    probe weighing 28.3 % of "all" instead of 8/29 = 27.6 %. The three numbers cannot all be
    means over the same frames and keypoints (e.g. they come from different checkpoints, or "all"
    was averaged over a different keypoint subset); the paper does not say. We therefore always
    report all three numbers and state ``ALL_AVERAGING`` beside them.

Symmetry:
    The probe's 8 box corners are only defined up to the box's symmetries that also map the probe
    onto itself. Without its orientation marker (datagen/assets/probe.py) the probe is unchanged by the half
    turn about its long axis z, (x, y, z) -> (-x, -y, z), which maps corner (ix, iy, iz) to
    (1 - ix, 1 - iy, iz) of its axis-centred box; the BOP benchmark (Hodan et al.) scores such objects
    by minimising the error over the symmetry group (MSSD, MSPD). :func:`probe_symmetric_mpjpe_mm`
    does the same for the corners, per frame, beside the plain probe MPJPE: the mean corner error
    under the identity or the half turn, whichever is smaller. The gap between the two numbers is
    how much of a model's probe error is the swapped labelling of a half-turned box. Probes built
    now carry the marker, so the half turn can be read from the image and the plain probe MPJPE is
    the benchmark number; the symmetric one shows whether a model reads the marker (and is the
    fair score on data rendered before the marker existed).
    ``hupbench.training.losses.hopenet_loss`` can take the same minimum in training (``loss.probe_symmetry``).

Spread (collapse guard):
    :func:`spread_ratios` compares how much the predicted 3D keypoints vary across frames with how
    much the truth does, per camera axis; a model that outputs one layout for every image has
    ratios near 0 on the axes it ignores (HOPE-Net's x and y in issue 14: 0.02).

Degenerate sets:
    Procrustes alignment (:func:`procrustes_align`) solves the similarity (scale, rotation,
    translation) by the SVD of the cross-covariance with the determinant correction (Umeyama
    1991), so reflections never enter; collinear and coplanar sets give one of the equally good
    rotations; a prediction whose points all coincide (zero spread, no scale defined) is mapped to
    the target centroid (scale 0). No input of finite numbers gives NaN or inf.
"""

from __future__ import annotations

import numpy as np
import torch

from datagen.keypoints import (
    CORNER_BITS,
    CORNER_SLICE,
    HAND_SLICE,
    NUM_CORNERS,
    NUM_HAND,
    NUM_KEYPOINTS,
)
from datagen.errors import BadTypeError, BadValueError

__all__ = [
    "ALL_AVERAGING",
    "HALF_TURN_Z",
    "PCK_THRESHOLDS_MM",
    "PROBE_SYMMETRIES",
    "ROOT_INDEX",
    "SPREAD_AXES",
    "SPREAD_RATIO_WARN",
    "breakdown_mpjpe_mm",
    "collapsed_axes",
    "keypoint_errors_mm",
    "mpjpe_mm",
    "mpjpe_split_mm",
    "normalized_to_pixels",
    "pa_mpjpe_mm",
    "pck_auc",
    "pck_auc_from_errors",
    "pck_mm",
    "permute_keypoints",
    "pixel_error_px",
    "pixel_errors_px",
    "probe_symmetric_errors_mm",
    "probe_symmetric_mpjpe_mm",
    "procrustes_align",
    "root_relative_mpjpe_mm",
    "split_from_errors_mm",
    "spread_ratios",
    "symmetry_costs",
    "symmetry_permutation",
]

#: how "all" in :func:`mpjpe_split_mm` is averaged (written into the results JSON)
ALL_AVERAGING = "mean over all 29 keypoints and all frames (keypoint-weighted: (21 hand + 8 probe) / 29)"
#: the hand root for root-relative errors: the wrist (OpenPose keypoint 0)
ROOT_INDEX = 0
#: thresholds of the 3D PCK curve whose area is :func:`pck_auc`: 0 to 50 mm in 0.5 mm steps (101)
PCK_THRESHOLDS_MM = np.linspace(0.0, 50.0, 101)
#: a set whose mean squared distance from its centroid is below this (m^2, i.e. 1e-12 m RMS) has
#: no defined scale: Procrustes maps it to the target centroid instead of dividing by ~0
PROCRUSTES_MIN_VARIANCE_M2 = 1e-24
HAND = tuple(range(NUM_HAND))
PROBE = tuple(range(NUM_HAND, NUM_KEYPOINTS))
#: the half turn about the probe frame's long axis z: (x, y, z) -> (-x, -y, z)
HALF_TURN_Z = np.diag([-1.0, -1.0, 1.0])
#: a point set maps onto itself under a symmetry when every mapped point lies within this of a point
#: of the set, relative to the set's size (largest distance from its centroid)
SYMMETRY_REL_TOL = 1e-6
#: the camera axes of :func:`spread_ratios`, in order
SPREAD_AXES = ("x", "y", "z")
#: ``hupbench eval`` warns when a spread ratio is below this (the collapse guard of issue 14)
SPREAD_RATIO_WARN = 0.5
#: a truth whose spread along an axis is below this (metres) does not vary there: its ratio is None
SPREAD_MIN_M = 1e-9

_MM_PER_M = 1000.0


def _is_torch(x) -> bool:
    return isinstance(x, torch.Tensor)


def _check_points(pred, gt, dim: int, names=("pred_m", "gt_m")) -> None:
    for name, x in zip(names, (pred, gt)):
        if not isinstance(x, (np.ndarray, torch.Tensor)):
            raise BadTypeError(f"{name} must be a numpy array or torch tensor, got {type(x).__name__}")
        if x.ndim != 3 or x.shape[-1] != dim:
            raise BadValueError(f"{name} must be (N, K, {dim}), got {tuple(x.shape)}")
    if _is_torch(pred) != _is_torch(gt):
        raise BadTypeError(f"{names[0]} and {names[1]} must both be numpy or both torch, got "
                        f"{type(pred).__name__} and {type(gt).__name__}")
    if tuple(pred.shape) != tuple(gt.shape):
        raise BadValueError(f"{names[0]} {tuple(pred.shape)} and {names[1]} {tuple(gt.shape)} must have the same shape")


def _index(keypoints, k: int) -> list[int]:
    """Keypoint selection (None, slice or sequence of ints) -> validated list of indices into range(k)."""
    if keypoints is None:
        return list(range(k))
    if isinstance(keypoints, slice):
        idx = list(range(k))[keypoints]
    else:
        idx = [int(i) for i in np.asarray(keypoints).reshape(-1)]
    if not idx:
        raise BadValueError("keypoints selects no keypoint")
    bad = [i for i in idx if not 0 <= i < k]
    if bad:
        raise BadValueError(f"keypoint indices {bad} are out of range for {k} keypoints")
    return idx


def _mean(x):
    return x.mean() if _is_torch(x) else float(np.mean(x))


def keypoint_errors_mm(pred_m, gt_m):
    """Euclidean 3D error per frame and keypoint.

    Args:
        pred_m: (N, K, 3) float, metres, predicted keypoints.
        gt_m: (N, K, 3) float, metres, ground truth in the same frame.

    Returns:
        (N, K) errors in millimetres (numpy float64 for numpy input; a tensor of the input dtype
        for torch input).
    """
    _check_points(pred_m, gt_m, 3)
    if _is_torch(pred_m):
        return torch.linalg.vector_norm(pred_m - gt_m, dim=-1) * _MM_PER_M
    return np.linalg.norm(np.asarray(pred_m, np.float64) - np.asarray(gt_m, np.float64), axis=-1) * _MM_PER_M


def mpjpe_mm(pred_m, gt_m, keypoints=None):
    """Mean per-joint position error (absolute, no alignment) over frames and the chosen keypoints.

    Args:
        pred_m, gt_m: (N, K, 3) float, metres, same frame.
        keypoints: None (all K), a slice or a sequence of keypoint indices.

    Returns:
        millimetres: a python float for numpy input, a 0-dim tensor for torch input.
    """
    errors = keypoint_errors_mm(pred_m, gt_m)
    return _mean(errors[:, _index(keypoints, errors.shape[1])])


def split_from_errors_mm(errors_mm) -> dict[str, float]:
    """{"all", "hand", "probe"} MPJPE (python floats, mm) from (N, 29) per-keypoint errors in mm.

    "all" is the mean over all 29 keypoints and all frames (see ``ALL_AVERAGING``).
    """
    if tuple(errors_mm.shape[1:]) != (NUM_KEYPOINTS,) or errors_mm.ndim != 2:
        raise BadValueError(f"errors_mm must be (N, {NUM_KEYPOINTS}), got {tuple(errors_mm.shape)}")
    if errors_mm.shape[0] == 0:
        raise BadValueError("errors_mm holds no frame")
    return {"all": float(errors_mm.mean()), "hand": float(errors_mm[:, HAND_SLICE].mean()),
            "probe": float(errors_mm[:, CORNER_SLICE].mean())}


def mpjpe_split_mm(pred_m, gt_m) -> dict[str, float]:
    """MPJPE of the hand (keypoints 0..20), the probe corners (21..28) and all 29.

    Args:
        pred_m, gt_m: (N, 29, 3) float, metres, same frame (numpy or torch).

    Returns:
        {"all": float, "hand": float, "probe": float}, millimetres, python floats for either input.
        "all" is keypoint-weighted (mean over all 29 keypoints and frames), so
        all = (21 hand + 8 probe) / 29; the paper's 8.65 is not (see the module docstring).
    """
    _check_points(pred_m, gt_m, 3)
    if pred_m.shape[1] != NUM_KEYPOINTS:
        raise BadValueError(f"mpjpe_split_mm needs {NUM_KEYPOINTS} keypoints ({NUM_HAND} hand + {NUM_CORNERS} probe), "
                         f"got {pred_m.shape[1]}")
    with torch.no_grad():
        return split_from_errors_mm(keypoint_errors_mm(pred_m, gt_m))


def root_relative_mpjpe_mm(pred_m, gt_m, root: int = ROOT_INDEX, keypoints=HAND):
    """MPJPE after moving each hand so that its root (the wrist) sits at the origin.

    Both prediction and ground truth are translated by their own root; the error is then averaged
    over ``keypoints`` (default: the 21 hand joints, the root included with its zero error, as in
    the FreiHAND / HO-3D evaluation).

    Args:
        pred_m, gt_m: (N, K, 3) float, metres.
        root: index of the root keypoint (default 0, the wrist).
        keypoints: the keypoints averaged (default 0..20).

    Returns:
        millimetres: python float (numpy) or 0-dim tensor (torch).
    """
    _check_points(pred_m, gt_m, 3)
    (root,) = _index([root], pred_m.shape[1])
    return mpjpe_mm(pred_m - pred_m[:, root:root + 1], gt_m - gt_m[:, root:root + 1], keypoints)


def procrustes_align(pred_m, gt_m):
    """Similarity transform (scale, rotation, translation) that best maps each prediction onto its ground truth.

    Minimises sum_k ||s R p_k + t - g_k||^2 per frame (Umeyama 1991): R = U D V^T from the SVD
    U S V^T of the cross-covariance of the centred sets, D = diag(1, 1, sign(det U det V)) so that
    R is a proper rotation (never a reflection), s = tr(S D) / var(p), t = mean(g) - s R mean(p).
    Computed in float64. Degenerate sets stay finite: collinear or coplanar sets give one of the
    equally optimal rotations; a prediction with (near) zero spread gets s = 0, i.e. every point is
    mapped to the ground-truth centroid.

    Args:
        pred_m: (N, K, 3) float, metres, predicted points.
        gt_m: (N, K, 3) float, metres, target points (K >= 1).

    Returns:
        (N, K, 3) the aligned prediction, same type and dtype as ``pred_m``.
    """
    _check_points(pred_m, gt_m, 3)
    if pred_m.shape[1] < 1:
        raise BadValueError("procrustes_align needs at least one keypoint")
    if _is_torch(pred_m):
        out = _procrustes_np(pred_m.detach().cpu().double().numpy(), gt_m.detach().cpu().double().numpy())
        return torch.from_numpy(out).to(dtype=pred_m.dtype, device=pred_m.device)
    return _procrustes_np(np.asarray(pred_m, np.float64), np.asarray(gt_m, np.float64)).astype(
        np.result_type(pred_m.dtype, np.float32), copy=False)


def _procrustes_np(p: np.ndarray, g: np.ndarray) -> np.ndarray:
    # one float64 numpy path for both backends, so numpy and torch give the same numbers bit for bit
    mu_p, mu_g = p.mean(axis=1, keepdims=True), g.mean(axis=1, keepdims=True)  # (N, 1, 3)
    x, y = p - mu_p, g - mu_g                                                   # (N, K, 3) centred
    var_p = (x ** 2).sum(axis=(1, 2)) / p.shape[1]                               # (N,)
    cov = np.einsum("nki,nkj->nij", y, x) / p.shape[1]                           # (N, 3, 3) = Y^T X / K
    u, s, vt = np.linalg.svd(cov)
    d = np.where(np.linalg.det(u) * np.linalg.det(vt) < 0.0, -1.0, 1.0)         # (N,) reflection fix
    u[:, :, 2] *= d[:, None]                                                     # U D
    rot = u @ vt                                                                 # (N, 3, 3)
    trace = s[:, 0] + s[:, 1] + d * s[:, 2]                                      # tr(S D)
    has_scale = var_p > PROCRUSTES_MIN_VARIANCE_M2
    scale = np.where(has_scale, trace / np.where(has_scale, var_p, 1.0), 0.0)   # (N,)
    return scale[:, None, None] * np.einsum("nij,nkj->nki", rot, x) + mu_g


def pa_mpjpe_mm(pred_m, gt_m, keypoints=HAND):
    """MPJPE after Procrustes alignment of the chosen keypoints (default: the 21 hand joints).

    The alignment is fitted on ``keypoints`` only and the error averaged over the same keypoints.

    Args:
        pred_m, gt_m: (N, K, 3) float, metres.
        keypoints: the keypoints aligned and averaged (default 0..20, the hand).

    Returns:
        millimetres: python float (numpy) or 0-dim tensor (torch).
    """
    _check_points(pred_m, gt_m, 3)
    idx = _index(keypoints, pred_m.shape[1])
    pred_sel, gt_sel = pred_m[:, idx], gt_m[:, idx]
    return mpjpe_mm(procrustes_align(pred_sel, gt_sel), gt_sel)


def pck_mm(errors_mm, thresholds_mm=PCK_THRESHOLDS_MM):
    """Percentage of correct keypoints: the fraction of errors at or below each threshold.

    Args:
        errors_mm: (N, K) (or any shape) errors in millimetres.
        thresholds_mm: (T,) thresholds, millimetres.

    Returns:
        (T,) fractions in [0, 1] (numpy float64, or a tensor for tensor input).
    """
    if _is_torch(errors_mm):
        t = torch.as_tensor(np.asarray(thresholds_mm), dtype=errors_mm.dtype, device=errors_mm.device)
        return (errors_mm.reshape(-1, 1) <= t).to(errors_mm.dtype).mean(dim=0)
    e = np.asarray(errors_mm, np.float64).reshape(-1, 1)
    return (e <= np.asarray(thresholds_mm, np.float64)).mean(axis=0)


def pck_auc_from_errors(errors_mm, thresholds_mm=PCK_THRESHOLDS_MM):
    """Area under the 3D PCK curve, normalised to [0, 1] by the threshold range.

    The curve is sampled at ``thresholds_mm`` (default 0, 0.5, ..., 50 mm: 101 thresholds) and
    integrated with the trapezoidal rule, then divided by (max - min threshold): 1 means every
    error is 0, 0 means every error is above 50 mm.

    Args:
        errors_mm: (N, K) errors, millimetres.
        thresholds_mm: (T,) increasing thresholds, T >= 2, millimetres.

    Returns:
        python float (numpy) or 0-dim tensor (torch).
    """
    th = np.asarray(thresholds_mm, np.float64)
    if th.ndim != 1 or len(th) < 2 or not np.all(np.diff(th) > 0):
        raise BadValueError(f"thresholds_mm must be at least 2 increasing values, got {th.tolist()}")
    curve = pck_mm(errors_mm, th)
    widths = np.diff(th) / (th[-1] - th[0])
    if _is_torch(curve):
        w = torch.as_tensor(widths, dtype=curve.dtype, device=curve.device)
        return (0.5 * (curve[1:] + curve[:-1]) * w).sum()
    return float((0.5 * (curve[1:] + curve[:-1]) * widths).sum())


def pck_auc(pred_m, gt_m, keypoints=None, thresholds_mm=PCK_THRESHOLDS_MM):
    """AUC of the absolute 3D PCK over 0-50 mm (see :func:`pck_auc_from_errors`) of the chosen keypoints.

    Args:
        pred_m, gt_m: (N, K, 3) float, metres.
        keypoints: None (all), a slice or indices.

    Returns:
        fraction in [0, 1]: python float (numpy) or 0-dim tensor (torch).
    """
    errors = keypoint_errors_mm(pred_m, gt_m)
    return pck_auc_from_errors(errors[:, _index(keypoints, errors.shape[1])], thresholds_mm)


def normalized_to_pixels(points_norm, width: int, height: int):
    """Normalised [-1, 1] image coordinates -> pixels (models/coords.py convention, any backend).

    u = ((x + 1) W - 1) / 2, pixel centres at integers.

    Args:
        points_norm: (..., 2) float, normalised coordinates.
        width, height: image size in pixels.

    Returns:
        (..., 2) pixels, same backend.
    """
    if _is_torch(points_norm):
        from models.coords import normalized_to_pixels as _to_px

        return _to_px(points_norm, width, height)
    size = np.array([width, height], dtype=np.float64)
    return ((np.asarray(points_norm, np.float64) + 1.0) * size - 1.0) / 2.0


def pixel_errors_px(pred_px, gt_px):
    """(N, K) Euclidean 2D errors in pixels from (N, K, 2) predicted and true pixel coordinates."""
    _check_points(pred_px, gt_px, 2, names=("pred_px", "gt_px"))
    if _is_torch(pred_px):
        return torch.linalg.vector_norm(pred_px - gt_px, dim=-1)
    return np.linalg.norm(np.asarray(pred_px, np.float64) - np.asarray(gt_px, np.float64), axis=-1)


def pixel_error_px(pred_px, gt_px, mask=None):
    """Mean 2D keypoint error in pixels.

    Args:
        pred_px, gt_px: (N, K, 2) float, pixels of the same image.
        mask: optional (N, K) bool, the keypoints counted (e.g. ``visible``); default all.

    Returns:
        pixels: python float (numpy) or 0-dim tensor (torch); NaN-free (raises if the mask is empty).
    """
    errors = pixel_errors_px(pred_px, gt_px)
    if mask is None:
        return _mean(errors)
    if tuple(mask.shape) != tuple(errors.shape):
        raise BadValueError(f"mask must be {tuple(errors.shape)}, got {tuple(mask.shape)}")
    if not bool(mask.any()):
        raise BadValueError("mask selects no keypoint")
    return _mean(errors[mask])


def breakdown_mpjpe_mm(errors_mm, labels) -> dict[str, dict]:
    """MPJPE split by a per-frame label.

    Args:
        errors_mm: (N, 29) per-keypoint absolute errors, millimetres (numpy or torch).
        labels: (N,) one bucket label per frame (str or anything with a str()).

    Returns:
        {label: {"frames": int, "mpjpe_mm": {"all", "hand", "probe"}}}, labels sorted.
    """
    errors = errors_mm.detach().cpu().numpy() if _is_torch(errors_mm) else np.asarray(errors_mm, np.float64)
    labels = np.asarray(labels).reshape(-1).astype(str)
    if errors.ndim != 2 or len(labels) != errors.shape[0]:
        raise BadValueError(f"labels must hold one entry per frame: errors {tuple(errors.shape)}, labels {labels.shape}")
    out = {}
    for label in sorted(set(labels.tolist())):
        rows = errors[labels == label]
        out[label] = {"frames": int(rows.shape[0]), "mpjpe_mm": split_from_errors_mm(rows)}
    return out


# ----------------------------------------------------------------------------- symmetric probe error


def symmetry_permutation(points_m, rotation, rel_tol: float = SYMMETRY_REL_TOL) -> tuple[int, ...]:
    """The permutation by which a rotation maps a point set onto itself.

    Args:
        points_m: (K, 3) float, metres, the points in the object's own frame (e.g. the probe's box
            corners in the probe frame, ``datagen.assets.probe.Probe.corners_probe``).
        rotation: (3, 3) a proper rotation about that frame's origin (e.g. :data:`HALF_TURN_Z`).
        rel_tol: largest allowed distance between a rotated point and its match, relative to the
            set's size (its largest distance from its centroid).

    Returns:
        ``perm`` with ``rotation @ points[k] == points[perm[k]]`` (within the tolerance), a
        permutation of range(K) as python ints.

    Raises:
        ValueError: wrong shapes, not a rotation, or the set is not symmetric under it (the message
            gives the largest mismatch in mm).
    """
    p = np.asarray(points_m, np.float64)
    r = np.asarray(rotation, np.float64)
    if p.ndim != 2 or p.shape[-1] != 3 or len(p) < 1:
        raise BadValueError(f"points_m must be (K, 3) with K >= 1, got {p.shape}")
    if r.shape != (3, 3) or not np.allclose(r @ r.T, np.eye(3), atol=1e-9) or np.linalg.det(r) < 0:
        raise BadValueError(f"rotation must be a (3, 3) proper rotation matrix, got {r.tolist()}")
    moved = p @ r.T
    dist = np.linalg.norm(moved[:, None] - p[None], axis=-1)  # (K, K): rotated point k to point j
    perm = dist.argmin(axis=1)
    size = max(float(np.linalg.norm(p - p.mean(axis=0), axis=-1).max()), 1e-12)
    worst = float(dist[np.arange(len(p)), perm].max())
    if worst > rel_tol * size or len(set(perm.tolist())) != len(p):
        raise BadValueError(f"the points are not symmetric under the rotation: a rotated point lies "
                         f"{worst * _MM_PER_M:.3g} mm from the nearest point "
                         f"(allowed {rel_tol * size * _MM_PER_M:.3g} mm)")
    return tuple(int(k) for k in perm)


def _box_symmetries() -> dict[str, tuple[tuple[int, ...], ...]]:
    # an axis-centred box with three different side lengths, corners in the documented order
    # (datagen.keypoints.CORNER_BITS, itertools.product((min, max), repeat=3) over x, y, z):
    # the permutation is read off the coordinates, not written by hand
    box = (2.0 * np.array(CORNER_BITS, np.float64) - 1.0) * np.array([0.036, 0.015, 0.0825]) + [0.0, 0.0, 0.0825]
    identity = tuple(range(NUM_CORNERS))
    return {"none": (identity,), "half_turn": (identity, symmetry_permutation(box, HALF_TURN_Z))}


#: the probe corners' symmetry groups as permutations of the 8 corners (indices into 21..28 minus
#: 21): "none" is the identity only, "half_turn" adds the half turn about the long axis, which maps
#: corner (ix, iy, iz) to (1 - ix, 1 - iy, iz): (6, 7, 4, 5, 2, 3, 0, 1)
PROBE_SYMMETRIES = _box_symmetries()


def _check_permutations(permutations, k: int) -> np.ndarray:
    perms = np.asarray(permutations)
    if perms.ndim != 2 or perms.shape[1] != k or len(perms) < 1 or not np.issubdtype(perms.dtype, np.integer):
        raise BadValueError(f"permutations must be (G, {k}) integer permutations of range({k}), got "
                         f"{np.asarray(permutations).tolist()}")
    if not all(sorted(row.tolist()) == list(range(k)) for row in perms):
        raise BadValueError(f"every row of permutations must be a permutation of range({k}), got {perms.tolist()}")
    return perms.astype(np.int64)


def symmetry_costs(pred, gt, permutations, keypoints=PROBE, squared: bool = False):
    """Error of the chosen keypoints under each element of a symmetry group, per frame.

    ``cost[n, g]`` is the mean over the selected keypoints k of ``|pred[n, sel[k]] - gt[n,
    sel[perm_g[k]]]|`` (or its square): the prediction labelled k is compared with the true point
    the symmetry g relabels as k.

    Args:
        pred, gt: (N, K, D) float, same frame and unit (metres for 3D, any for 2D); numpy or torch.
        permutations: (G, S) permutations of range(S), S = number of selected keypoints
            (e.g. ``PROBE_SYMMETRIES["half_turn"]`` for the 8 corners).
        keypoints: the selected keypoints (default 21..28, the probe corners).
        squared: mean squared distance instead of mean distance.

    Returns:
        (N, G) in the input's unit (squared with ``squared``): float64 numpy, or a tensor of the
        input dtype (differentiable) for torch input.
    """
    if not isinstance(pred, (np.ndarray, torch.Tensor)) or not isinstance(gt, (np.ndarray, torch.Tensor)):
        raise BadTypeError(f"pred and gt must be numpy arrays or torch tensors, got {type(pred).__name__} and "
                        f"{type(gt).__name__}")
    _check_points(pred, gt, pred.shape[-1] if pred.ndim == 3 else 3, names=("pred", "gt"))
    idx = _index(keypoints, pred.shape[1])
    perms = _check_permutations(permutations, len(idx))
    sel = np.asarray(idx)[perms]                                                 # (G, S) keypoint indices
    if _is_torch(pred):
        p = pred[:, idx][:, None]                                                 # (N, 1, S, D)
        g = gt[:, torch.as_tensor(sel, device=gt.device)]                         # (N, G, S, D)
        sq = ((p - g) ** 2).sum(dim=-1)
        per_point = sq if squared else torch.sqrt(sq)
        return per_point.mean(dim=-1)
    p = np.asarray(pred, np.float64)[:, idx][:, None]
    g = np.asarray(gt, np.float64)[:, sel]
    sq = ((p - g) ** 2).sum(axis=-1)
    return (sq if squared else np.sqrt(sq)).mean(axis=-1)


def permute_keypoints(points, permutations, choice, keypoints=PROBE):
    """Relabel the chosen keypoints of each frame by one element of a symmetry group.

    ``out[n, sel[k]] = points[n, sel[perm[k]]]`` with ``perm = permutations[choice[n]]``; the other
    keypoints are copied unchanged. With ``choice`` the argmin of :func:`symmetry_costs`, the truth
    is relabelled to the symmetric copy nearest the prediction.

    Args:
        points: (N, K, D) float, numpy or torch (e.g. 3D or 2D targets).
        permutations: (G, S) permutations of range(S), S = number of selected keypoints.
        choice: (N,) int, the group element per frame, numpy or torch like ``points``.
        keypoints: the selected keypoints (default the probe corners).

    Returns:
        (N, K, D) of the same type, dtype and device (a new array; gradients flow for torch).
    """
    if not isinstance(points, (np.ndarray, torch.Tensor)) or points.ndim != 3:
        raise BadValueError(f"points must be an (N, K, D) numpy array or torch tensor, got "
                         f"{getattr(points, 'shape', type(points).__name__)}")
    idx = _index(keypoints, points.shape[1])
    perms = _check_permutations(permutations, len(idx))
    sel = np.asarray(idx)[perms]                                                  # (G, S)
    n = points.shape[0]
    if tuple(choice.shape) != (n,):
        raise BadValueError(f"choice must be ({n},), got {tuple(choice.shape)}")
    if _is_torch(points):
        choice = torch.as_tensor(choice, dtype=torch.int64, device=points.device)
        if n and (int(choice.min()) < 0 or int(choice.max()) >= len(perms)):
            raise BadValueError(f"choice must index the {len(perms)} permutations, got {choice.tolist()}")
        source = torch.as_tensor(sel, device=points.device)[choice]               # (N, S)
        rows = torch.arange(n, device=points.device)[:, None]
        out = points.clone()
        out[:, idx] = points[rows, source]
        return out
    choice = np.asarray(choice, np.int64)
    if n and (choice.min() < 0 or choice.max() >= len(perms)):
        raise BadValueError(f"choice must index the {len(perms)} permutations, got {choice.tolist()}")
    out = np.array(points, copy=True)
    out[:, idx] = points[np.arange(n)[:, None], sel[choice]]
    return out


def probe_symmetric_errors_mm(pred_m, gt_m, permutations=PROBE_SYMMETRIES["half_turn"]):
    """Per-frame probe corner error, minimised over the probe box's symmetry group.

    Args:
        pred_m, gt_m: (N, 29, 3) float, metres, same frame (numpy or torch).
        permutations: the group as permutations of the 8 corners (default identity and the half
            turn about the long axis, :data:`PROBE_SYMMETRIES`).

    Returns:
        (errors, choice): (N,) mean corner error in mm under the best group element, and (N,) int64
        index of that element (0 = identity when it is listed first); numpy for numpy input, tensors
        for torch input.
    """
    _check_points(pred_m, gt_m, 3)
    if pred_m.shape[1] != NUM_KEYPOINTS:
        raise BadValueError(f"probe symmetric errors need {NUM_KEYPOINTS} keypoints, got {pred_m.shape[1]}")
    costs = symmetry_costs(pred_m, gt_m, permutations) * _MM_PER_M               # (N, G) mm
    if _is_torch(costs):
        best, choice = costs.min(dim=1)
        return best, choice
    return costs.min(axis=1), costs.argmin(axis=1).astype(np.int64)


def probe_symmetric_mpjpe_mm(pred_m, gt_m, permutations=PROBE_SYMMETRIES["half_turn"]):
    """Probe corner MPJPE with each frame's corners matched under the probe box's symmetry group.

    For every frame the 8 predicted corners are compared with the true corners relabelled by each
    group element (default: the identity and the half turn about the long axis, corner (ix, iy, iz)
    -> (1 - ix, 1 - iy, iz)); the smaller mean corner error counts, and the result is its mean over
    frames, as the BOP benchmark scores symmetric objects (an MSSD-style minimum over the group,
    with the mean instead of the maximum over points so that it compares with the plain probe
    MPJPE, which it never exceeds).

    Args:
        pred_m, gt_m: (N, 29, 3) float, metres, same frame.
        permutations: the group as permutations of the 8 corners.

    Returns:
        millimetres: python float (numpy) or 0-dim tensor (torch).
    """
    errors, _ = probe_symmetric_errors_mm(pred_m, gt_m, permutations)
    return _mean(errors)


# ----------------------------------------------------------------------------- spread (collapse guard)


def spread_ratios(pred_m, gt_m) -> dict[str, float | None]:
    """How much the predicted 3D keypoints vary across frames, relative to the truth, per camera axis.

    For each axis a of the camera frame (x right, y down, z forward):
    ``spread_a(P) = mean over keypoints k of std over frames n of P[n, k, a]`` (population standard
    deviation), and the ratio is ``spread_a(pred) / spread_a(gt)``. 1 means the prediction varies as
    much as the truth, 0 that it is the same for every frame along that axis (a collapsed model);
    a prediction scaled by s about its per-keypoint mean gives s. The ratio is None on an axis
    along which the truth does not vary (spread below ``SPREAD_MIN_M``, e.g. a single frame).

    Args:
        pred_m, gt_m: (N, K, 3) float, metres, the same frames and keypoints (numpy or torch).

    Returns:
        {"x": ratio, "y": ratio, "z": ratio}, python floats (or None), for either input.
    """
    _check_points(pred_m, gt_m, 3)
    if _is_torch(pred_m):
        pred_m, gt_m = (x.detach().cpu().double().numpy() for x in (pred_m, gt_m))
    pred, gt = np.asarray(pred_m, np.float64), np.asarray(gt_m, np.float64)
    if pred.shape[0] == 0 or pred.shape[1] == 0:
        raise BadValueError(f"spread_ratios needs at least one frame and one keypoint, got {pred.shape}")
    spread_pred = pred.std(axis=0).mean(axis=0)                                    # (3,) metres
    spread_gt = gt.std(axis=0).mean(axis=0)
    return {axis: (float(sp / sg) if sg >= SPREAD_MIN_M else None)
            for axis, sp, sg in zip(SPREAD_AXES, spread_pred, spread_gt)}


def collapsed_axes(ratios: dict[str, float | None], threshold: float = SPREAD_RATIO_WARN) -> list[str]:
    """The axes whose spread ratio (from :func:`spread_ratios`) is below ``threshold``, in x, y, z order.

    An axis with ratio None (the truth does not vary there) is never reported.
    """
    unknown = sorted(set(ratios) - set(SPREAD_AXES))
    if unknown:
        raise BadValueError(f"ratios has unknown axes {unknown}; expected keys {list(SPREAD_AXES)}")
    return [a for a in SPREAD_AXES if ratios.get(a) is not None and ratios[a] < threshold]
