"""Benchmark metrics as pure functions: numpy in -> numpy/float out, torch in -> torch out, same numbers.

Convention:
    Inputs are metres (3D, OpenCV camera frame of the model-input camera) or pixels (2D); every
    reported number is millimetres (``_mm``), pixels (``_px``) or a fraction in [0, 1]. Keypoint
    order is :mod:`hupbench.core.keypoints`: 0..20 the hand (0 = wrist, the root), 21..28 the probe box
    corners. MPJPE is the absolute camera-frame error (no alignment); docs/metrics.md defines each metric.

Callers pass well-formed arrays (eval, validation and the losses build them): shapes are asserted, not
re-checked for users.
"""

from __future__ import annotations

import numpy as np
import torch

from hupbench.core.geometry import proper_rotation
from hupbench.core.keypoints import CORNER_BITS, CORNER_SLICE, HAND_SLICE, NUM_HAND, NUM_KEYPOINTS
from hupbench.core.probe_symmetry import HALF_TURN_Z, symmetry_permutation

__all__ = ["ADD_THRESHOLD_DIAMETER", "ALL_AVERAGING", "BOP_REFERENCE_WIDTH_PX", "MIDDLE_MCP_INDEX",
           "MSPD_THRESHOLDS_PX", "MSSD_THRESHOLDS_DIAMETER", "PCK_THRESHOLDS_MM", "PROBE_SYMMETRIES",
           "PROBE_SYMMETRY_ROTATIONS", "ROOT_INDEX", "SPREAD_AXES", "SPREAD_RATIO_WARN", "add_mm", "add_s_mm",
           "average_recall", "bop_scores", "breakdown_mpjpe_mm", "collapsed_axes", "keypoint_errors_mm",
           "mpjpe_mm", "mpjpe_split_mm", "mspd_px", "mspd_thresholds_px", "mssd_mm", "pa_mpjpe_mm",
           "pck_auc_from_errors", "pck_mm", "permute_keypoints", "pixel_error_px", "pixel_errors_px",
           "probe_symmetric_errors_mm", "procrustes_align", "recall", "root_relative_mpjpe_mm",
           "split_from_errors_mm", "spread_ratios", "symmetry_costs"]

#: how "all" in :func:`mpjpe_split_mm` is averaged (written into the results JSON)
ALL_AVERAGING = "mean over all 29 keypoints and all frames (keypoint-weighted: (21 hand + 8 probe) / 29)"
#: the hand root for root-relative errors: the wrist (OpenPose keypoint 0)
ROOT_INDEX = 0
#: the second reference of root-relative errors: the middle finger's MCP joint (OpenPose keypoint 9), the
#: centre of the hand's 2D box and so of every hupbench frame, and less often hidden than the wrist
MIDDLE_MCP_INDEX = 9
#: thresholds of the 3D PCK curve whose area is :func:`pck_auc_from_errors`: 0 to 50 mm in 0.5 mm steps (101)
PCK_THRESHOLDS_MM = np.linspace(0.0, 50.0, 101)
#: a set whose mean squared distance from its centroid is below this (m^2, i.e. 1e-12 m RMS) has
#: no defined scale: Procrustes maps it to the target centroid instead of dividing by ~0
PROCRUSTES_MIN_VARIANCE_M2 = 1e-24
HAND = tuple(range(NUM_HAND))
PROBE = tuple(range(NUM_HAND, NUM_KEYPOINTS))
#: the probe's symmetry groups as rotations of its own frame about its origin (BOP's symmetries, with t = 0):
#: "none" the identity only, "half_turn" adds :data:`hupbench.core.probe_symmetry.HALF_TURN_Z`;
#: :data:`PROBE_SYMMETRIES` are these groups acting on the 8 box corners
PROBE_SYMMETRY_ROTATIONS = {"none": (np.eye(3),), "half_turn": (np.eye(3), HALF_TURN_Z)}
#: ADD(-S) accuracy: a pose is correct when its ADD (ADD-S) is below this fraction of the object's
#: diameter (Hinterstoisser et al. 2012; the BOP toolkit's ``correct_th`` of "add" and "adi")
ADD_THRESHOLD_DIAMETER = 0.1
#: BOP 2019+ MSSD thresholds as fractions of the object's diameter: 0.05, 0.10, ..., 0.50
#: (bop_toolkit scripts/eval_bop19_pose.py)
MSSD_THRESHOLDS_DIAMETER = 0.05 * np.arange(1, 11)
#: BOP 2019+ MSPD thresholds in pixels of an image ``BOP_REFERENCE_WIDTH_PX`` wide: 5, 10, ..., 50;
#: :func:`mspd_thresholds_px` scales them to another width
MSPD_THRESHOLDS_PX = 5.0 * np.arange(1, 11)
BOP_REFERENCE_WIDTH_PX = 640
#: frames per chunk of the dense point-to-point errors (a chunk holds (F, G, V, 3) float64)
_POSE_ERROR_CHUNK = 64
#: the camera axes of :func:`spread_ratios`, in order
SPREAD_AXES = ("x", "y", "z")
#: ``hupbench eval`` warns when a spread ratio is below this: the model barely follows the image on that axis
SPREAD_RATIO_WARN = 0.5
#: a truth whose spread along an axis is below this (metres) does not vary there: its ratio is None
SPREAD_MIN_M = 1e-9

_MM_PER_M = 1000.0


def _is_torch(x) -> bool:
    return isinstance(x, torch.Tensor)


def _assert_points(pred, gt, dim: int) -> None:
    """(N, K, dim) arrays of one backend and one shape."""
    assert _is_torch(pred) == _is_torch(gt) and tuple(pred.shape) == tuple(gt.shape), (type(pred), type(gt))
    assert pred.ndim == 3 and pred.shape[-1] == dim, tuple(pred.shape)


def _index(keypoints, k: int) -> list[int]:
    """Keypoint selection (None, slice or sequence of ints) -> list of indices into range(k)."""
    if keypoints is None:
        return list(range(k))
    if isinstance(keypoints, slice):
        idx = list(range(k))[keypoints]
    else:
        idx = [int(i) for i in np.asarray(keypoints).reshape(-1)]
    assert idx and all(0 <= i < k for i in idx), (idx, k)
    return idx


def _mean(x):
    return x.mean() if _is_torch(x) else float(np.mean(x))


def keypoint_errors_mm(pred_m, gt_m):
    """(N, K) Euclidean 3D errors, mm (numpy float64, or a tensor of the input dtype), of (N, K, 3) float
    predicted and true keypoints in metres, same frame."""
    _assert_points(pred_m, gt_m, 3)
    if _is_torch(pred_m):
        return torch.linalg.vector_norm(pred_m - gt_m, dim=-1) * _MM_PER_M
    return np.linalg.norm(np.asarray(pred_m, np.float64) - np.asarray(gt_m, np.float64), axis=-1) * _MM_PER_M


def mpjpe_mm(pred_m, gt_m, keypoints=None):
    """MPJPE, mm, of (N, K, 3) float keypoints in metres, same frame, over frames and ``keypoints`` (None:
    all K, a slice or indices); a python float, or a 0-dim tensor for torch input."""
    errors = keypoint_errors_mm(pred_m, gt_m)
    return _mean(errors[:, _index(keypoints, errors.shape[1])])


def split_from_errors_mm(errors_mm) -> dict[str, float]:
    """{"all", "hand", "probe"} MPJPE (python floats, mm) from (N, 29) per-keypoint errors in mm
    ("all" as ``ALL_AVERAGING`` says)."""
    assert errors_mm.ndim == 2 and errors_mm.shape[0] > 0 and errors_mm.shape[1] == NUM_KEYPOINTS, errors_mm.shape
    return {"all": float(errors_mm.mean()), "hand": float(errors_mm[:, HAND_SLICE].mean()),
            "probe": float(errors_mm[:, CORNER_SLICE].mean())}


def mpjpe_split_mm(pred_m, gt_m) -> dict[str, float]:
    """{"all", "hand", "probe"} MPJPE, mm, python floats, of (N, 29, 3) float keypoints in metres, same
    frame (numpy or torch); "all" is keypoint-weighted (:func:`split_from_errors_mm`)."""
    with torch.no_grad():
        return split_from_errors_mm(keypoint_errors_mm(pred_m, gt_m))


def root_relative_mpjpe_mm(pred_m, gt_m, root: int = ROOT_INDEX, keypoints=HAND):
    """MPJPE, mm, of (N, K, 3) keypoints in metres after translating prediction and truth by their own
    ``root`` (the wrist; ``MIDDLE_MCP_INDEX`` for the middle-finger MCP), averaged over ``keypoints`` (the 21
    hand joints, the root with its zero error included, as in the FreiHAND / HO-3D evaluation); a python
    float, or a 0-dim tensor for torch input."""
    _assert_points(pred_m, gt_m, 3)
    (root,) = _index([root], pred_m.shape[1])
    return mpjpe_mm(pred_m - pred_m[:, root:root + 1], gt_m - gt_m[:, root:root + 1], keypoints)


def procrustes_align(pred_m, gt_m):
    """Similarity transform (scale, rotation, translation) that best maps each prediction onto its ground truth.

    Minimises sum_k ||s R p_k + t - g_k||^2 per frame (Umeyama 1991): R = U D V^T from the SVD
    U S V^T of the cross-covariance of the centred sets, D = diag(1, 1, sign(det U det V)) so that
    R is a proper rotation (never a reflection), s = tr(S D) / var(p), t = mean(g) - s R mean(p).
    Degenerate sets stay finite: collinear or coplanar sets give one of the equally optimal rotations;
    a prediction with (near) zero spread is mapped to the ground-truth centroid (s = 0).

    Args:
        pred_m, gt_m: (N, K, 3) float, metres, predicted and target points (K >= 1).

    Returns:
        (N, K, 3) the aligned prediction, same type and dtype as ``pred_m``.
    """
    _assert_points(pred_m, gt_m, 3)
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
    rot, s, d = proper_rotation(cov)                                            # (N, 3, 3), (N, 3), (N,)
    trace = s[:, 0] + s[:, 1] + d * s[:, 2]                                      # tr(S D)
    has_scale = var_p > PROCRUSTES_MIN_VARIANCE_M2
    scale = np.where(has_scale, trace / np.where(has_scale, var_p, 1.0), 0.0)   # (N,)
    return scale[:, None, None] * np.einsum("nij,nkj->nki", rot, x) + mu_g


def pa_mpjpe_mm(pred_m, gt_m, keypoints=HAND):
    """MPJPE, mm, of (N, K, 3) keypoints in metres after a Procrustes alignment fitted on ``keypoints`` (the
    21 hand joints) and averaged over them; a python float, or a 0-dim tensor for torch input."""
    _assert_points(pred_m, gt_m, 3)
    idx = _index(keypoints, pred_m.shape[1])
    pred_sel, gt_sel = pred_m[:, idx], gt_m[:, idx]
    return mpjpe_mm(procrustes_align(pred_sel, gt_sel), gt_sel)


def pck_mm(errors_mm, thresholds_mm=PCK_THRESHOLDS_MM):
    """(T,) fractions of the errors (any shape, mm) at or below each of the (T,) thresholds (mm): the PCK
    curve (numpy float64, or a tensor for tensor input)."""
    if _is_torch(errors_mm):
        t = torch.as_tensor(np.asarray(thresholds_mm), dtype=errors_mm.dtype, device=errors_mm.device)
        return (errors_mm.reshape(-1, 1) <= t).to(errors_mm.dtype).mean(dim=0)
    e = np.asarray(errors_mm, np.float64).reshape(-1, 1)
    return (e <= np.asarray(thresholds_mm, np.float64)).mean(axis=0)


def pck_auc_from_errors(errors_mm, thresholds_mm=PCK_THRESHOLDS_MM):
    """Area under the 3D PCK curve of (N, K) errors in mm, sampled at the (T,) increasing thresholds (mm,
    T >= 2), integrated with the trapezoidal rule and divided by the threshold range: 1 when every error
    is 0, 0 when every error is above the last threshold; a python float, or a 0-dim tensor for torch."""
    th = np.asarray(thresholds_mm, np.float64)
    assert th.ndim == 1 and len(th) >= 2 and np.all(np.diff(th) > 0), th
    curve = pck_mm(errors_mm, th)
    widths = np.diff(th) / (th[-1] - th[0])
    if _is_torch(curve):
        w = torch.as_tensor(widths, dtype=curve.dtype, device=curve.device)
        return (0.5 * (curve[1:] + curve[:-1]) * w).sum()
    return float((0.5 * (curve[1:] + curve[:-1]) * widths).sum())


def pixel_errors_px(pred_px, gt_px):
    """(N, K) Euclidean 2D errors in pixels from (N, K, 2) predicted and true pixel coordinates."""
    _assert_points(pred_px, gt_px, 2)
    if _is_torch(pred_px):
        return torch.linalg.vector_norm(pred_px - gt_px, dim=-1)
    return np.linalg.norm(np.asarray(pred_px, np.float64) - np.asarray(gt_px, np.float64), axis=-1)


def pixel_error_px(pred_px, gt_px, mask=None):
    """Mean 2D error, pixels, of (N, K, 2) float pixel coordinates of the same image, over the keypoints of
    an (N, K) bool ``mask`` (default all); a python float, or a 0-dim tensor for torch input."""
    errors = pixel_errors_px(pred_px, gt_px)
    if mask is None:
        return _mean(errors)
    assert tuple(mask.shape) == tuple(errors.shape) and bool(mask.any()), tuple(mask.shape)
    return _mean(errors[mask])


def breakdown_mpjpe_mm(errors_mm, labels) -> dict[str, dict]:
    """{label: {"frames": int, "mpjpe_mm": {"all", "hand", "probe"}}}, labels sorted, of (N, 29) errors in
    mm (numpy or torch) split by (N,) per-frame labels (anything with a str())."""
    errors = errors_mm.detach().cpu().numpy() if _is_torch(errors_mm) else np.asarray(errors_mm, np.float64)
    labels = np.asarray(labels).reshape(-1).astype(str)
    assert errors.ndim == 2 and len(labels) == errors.shape[0], (errors.shape, labels.shape)
    out = {}
    for label in sorted(set(labels.tolist())):
        rows = errors[labels == label]
        out[label] = {"frames": int(rows.shape[0]), "mpjpe_mm": split_from_errors_mm(rows)}
    return out


# ----------------------------------------------------------------------------- symmetric probe error


def _box_symmetries() -> dict[str, tuple[tuple[int, ...], ...]]:
    # a box with three different sides, corners in hupbench.core.keypoints.CORNER_BITS order: the
    # permutation is read off the coordinates, not written by hand
    box = (2.0 * np.array(CORNER_BITS, np.float64) - 1.0) * np.array([0.036, 0.015, 0.0825]) + [0.0, 0.0, 0.0825]
    return {name: tuple(symmetry_permutation(box, r) for r in rotations)
            for name, rotations in PROBE_SYMMETRY_ROTATIONS.items()}


#: the probe corners' symmetry groups as permutations of the 8 corners (indices into 21..28 minus
#: 21): "none" is the identity only, "half_turn" adds the half turn about the long axis, which maps
#: corner (ix, iy, iz) to (1 - ix, 1 - iy, iz): (6, 7, 4, 5, 2, 3, 0, 1)
PROBE_SYMMETRIES = _box_symmetries()


def _permutations(permutations, k: int) -> np.ndarray:
    """(G, k) int64 from G permutations of range(k)."""
    perms = np.asarray(permutations, dtype=np.int64)
    assert perms.ndim == 2 and len(perms) >= 1 and all(sorted(row) == list(range(k)) for row in perms.tolist()), perms
    return perms


def symmetry_costs(pred, gt, permutations, keypoints=PROBE, squared: bool = False):
    """Error of the chosen keypoints under each element of a symmetry group, per frame: ``cost[n, g]`` is
    the mean over the selected keypoints k of ``|pred[n, sel[k]] - gt[n, sel[perm_g[k]]]|`` (squared with
    ``squared``).

    Args:
        pred, gt: (N, K, D) float, same frame and unit; numpy or torch.
        permutations: (G, S) permutations of range(S) over the S selected ``keypoints`` (default the
            probe corners), e.g. ``PROBE_SYMMETRIES["half_turn"]``.

    Returns:
        (N, G) in the input's unit: float64 numpy, or a differentiable tensor of the input dtype.
    """
    _assert_points(pred, gt, pred.shape[-1])
    idx = _index(keypoints, pred.shape[1])
    perms = _permutations(permutations, len(idx))
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
    """``out[n, sel[k]] = points[n, sel[perm[k]]]`` with ``perm = permutations[choice[n]]``, the other
    keypoints unchanged: with ``choice`` the argmin of :func:`symmetry_costs`, the truth relabelled to the
    symmetric copy nearest the prediction.

    Args:
        points: (N, K, D) float, numpy or torch. permutations: as :func:`symmetry_costs`'.
        choice: (N,) int, the group element per frame.

    Returns:
        (N, K, D), a new array of the same type, dtype and device (gradients flow for torch).
    """
    assert points.ndim == 3, tuple(points.shape)
    idx = _index(keypoints, points.shape[1])
    perms = _permutations(permutations, len(idx))
    sel = np.asarray(idx)[perms]                                                  # (G, S)
    n = points.shape[0]
    assert tuple(choice.shape) == (n,), (tuple(choice.shape), n)
    if _is_torch(points):
        choice = torch.as_tensor(choice, dtype=torch.int64, device=points.device)
        source = torch.as_tensor(sel, device=points.device)[choice]               # (N, S)
        rows = torch.arange(n, device=points.device)[:, None]
        out = points.clone()
        out[:, idx] = points[rows, source]
        return out
    choice = np.asarray(choice, np.int64)
    out = np.array(points, copy=True)
    out[:, idx] = points[np.arange(n)[:, None], sel[choice]]
    return out


def probe_symmetric_errors_mm(pred_m, gt_m, permutations=PROBE_SYMMETRIES["half_turn"]):
    """(errors, choice): (N,) mean probe corner error, mm, under the best element of the group
    ``permutations`` of the 8 corners (:data:`PROBE_SYMMETRIES`), and (N,) int64 its index, of (N, 29, 3)
    float keypoints in metres, same frame (numpy, or tensors for torch input)."""
    _assert_points(pred_m, gt_m, 3)
    assert pred_m.shape[1] == NUM_KEYPOINTS, tuple(pred_m.shape)
    costs = symmetry_costs(pred_m, gt_m, permutations) * _MM_PER_M               # (N, G) mm
    if _is_torch(costs):
        best, choice = costs.min(dim=1)
        return best, choice
    return costs.min(axis=1), costs.argmin(axis=1).astype(np.int64)


# ----------------------------------------------------------------------------- object pose (BOP)
# The object side of the BOP benchmark (Hodan et al., bop_toolkit_lib/pose_error.py and
# scripts/eval_calc_scores.py), for one rigid object seen once per frame. A pose is a (N, 4, 4)
# T_cam_obj mapping object-frame points (metres) into the OpenCV camera frame.


def _assert_poses(T_cam_pred, T_cam_true, points_obj_m) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    pred, true = np.asarray(T_cam_pred, np.float64), np.asarray(T_cam_true, np.float64)
    pts = np.asarray(points_obj_m, np.float64)
    assert pred.shape == true.shape and pred.ndim == 3 and pred.shape[1:] == (4, 4), (pred.shape, true.shape)
    assert pts.ndim == 2 and pts.shape[-1] == 3 and len(pts) >= 1, pts.shape
    return pred, true, pts


def _symmetries(symmetries) -> np.ndarray:
    """(G, 3, 3) proper rotations, the identity among them."""
    sym = np.asarray(symmetries, np.float64).reshape(-1, 3, 3)
    assert np.allclose(sym @ sym.transpose(0, 2, 1), np.eye(3), atol=1e-9) and np.all(np.linalg.det(sym) > 0), sym
    assert np.any(np.all(np.isclose(sym, np.eye(3)), axis=(1, 2))), "a symmetry group holds the identity"
    return sym


def _posed_chunks(T_cam_pred, T_cam_true, points_obj_m, symmetries):
    """Yield (frames slice, (F, V, 3) predicted and (F, G, V, 3) truth-under-each-symmetry camera points, metres)."""
    pred, true, pts = _assert_poses(T_cam_pred, T_cam_true, points_obj_m)
    sym = _symmetries(symmetries)
    for start in range(0, len(pred), _POSE_ERROR_CHUNK):
        rows = slice(start, start + _POSE_ERROR_CHUNK)
        p, t = pred[rows], true[rows]
        posed_pred = pts @ p[:, :3, :3].transpose(0, 2, 1) + p[:, None, :3, 3]                 # (F, V, 3)
        rot_true = np.einsum("fij,gjk->fgik", t[:, :3, :3], sym)                               # (F, G, 3, 3) R S
        posed_true = np.einsum("vk,fgik->fgvi", pts, rot_true) + t[:, None, None, :3, 3]       # (F, G, V, 3)
        yield rows, posed_pred, posed_true


def add_mm(T_cam_pred, T_cam_true, points_obj_m) -> np.ndarray:
    """ADD (Hinterstoisser et al. 2012): (N,) float64 mm, the mean over the (V, 3) object points (metres,
    object frame) of the distance between each point under the predicted and under the true (N, 4, 4)
    T_cam_obj; no symmetry."""
    out = np.empty(len(T_cam_pred))
    for rows, posed_pred, posed_true in _posed_chunks(T_cam_pred, T_cam_true, points_obj_m, np.eye(3)[None]):
        out[rows] = np.linalg.norm(posed_pred - posed_true[:, 0], axis=-1).mean(axis=1)
    return out * _MM_PER_M


def add_s_mm(T_cam_pred, T_cam_true, points_obj_m) -> np.ndarray:
    """ADD-S (ADI; Hinterstoisser et al. 2012, bop_toolkit ``adi``): (N,) float64 mm, the mean over the
    (V, 3) object points (metres, object frame) under the true (N, 4, 4) T_cam_obj of the distance to the
    nearest object point under the predicted pose; blind to every symmetry (and to some errors that are
    none)."""
    from scipy.spatial import cKDTree

    pred, true, pts = _assert_poses(T_cam_pred, T_cam_true, points_obj_m)
    tree = cKDTree(pts)
    # distances are rigid-invariant: take the truth-posed points into the predicted object frame and
    # query one tree of the model points, instead of a tree per frame
    T_pred_true = np.linalg.inv(pred) @ true                                             # (N, 4, 4)
    out = np.empty(len(pred))
    for start in range(0, len(pred), _POSE_ERROR_CHUNK):
        rows = slice(start, start + _POSE_ERROR_CHUNK)
        T = T_pred_true[rows]
        moved = pts @ T[:, :3, :3].transpose(0, 2, 1) + T[:, None, :3, 3]                 # (F, V, 3)
        out[rows] = tree.query(moved.reshape(-1, 3))[0].reshape(len(T), -1).mean(axis=1)
    return out * _MM_PER_M


def mssd_mm(T_cam_pred, T_cam_true, points_obj_m, symmetries=PROBE_SYMMETRY_ROTATIONS["half_turn"]) -> np.ndarray:
    """MSSD (BOP 2019+, bop_toolkit ``mssd``): (N,) float64 mm, over the symmetries S of a group (G, 3, 3)
    rotations about the object origin, the smallest of the largest distance over the (V, 3) object
    points (metres, object frame) between the point under the predicted (N, 4, 4) T_cam_obj and under the
    true pose composed with S (T_true S)."""
    out = np.empty(len(T_cam_pred))
    for rows, posed_pred, posed_true in _posed_chunks(T_cam_pred, T_cam_true, points_obj_m, symmetries):
        out[rows] = np.linalg.norm(posed_pred[:, None] - posed_true, axis=-1).max(axis=2).min(axis=1)
    return out * _MM_PER_M


def _project_px(points_cam_m: np.ndarray, K: np.ndarray) -> np.ndarray:
    """(F, ..., 2) pixels of (F, ..., 3) camera points under the (F, 3, 3) pinhole K, no distortion."""
    uvw = np.einsum("fij,f...j->f...i", K, points_cam_m)
    return uvw[..., :2] / uvw[..., 2:]


def mspd_px(T_cam_pred, T_cam_true, K, points_obj_m, symmetries=PROBE_SYMMETRY_ROTATIONS["half_turn"]) -> np.ndarray:
    """MSPD (BOP 2019+, bop_toolkit ``mspd``): (N,) float64 pixels, as :func:`mssd_mm` but between the
    points' projections through each frame's (N, 3, 3) K (pinhole, no distortion): the smallest over the
    symmetries of the largest 2D distance. inf for a frame where a posed point is not in front of the
    camera (z <= 0), whose projection is undefined."""
    K = np.asarray(K, np.float64)
    assert K.shape == (len(T_cam_pred), 3, 3), K.shape
    out = np.empty(len(T_cam_pred))
    for rows, posed_pred, posed_true in _posed_chunks(T_cam_pred, T_cam_true, points_obj_m, symmetries):
        behind = (posed_pred[..., 2] <= 0.0).any(axis=1) | (posed_true[..., 2] <= 0.0).any(axis=(1, 2))
        with np.errstate(divide="ignore", invalid="ignore"):
            uv_pred = _project_px(posed_pred, K[rows])                                    # (F, V, 2)
            uv_true = _project_px(posed_true, K[rows])                                    # (F, G, V, 2)
            e = np.linalg.norm(uv_pred[:, None] - uv_true, axis=-1).max(axis=2).min(axis=1)
        out[rows] = np.where(behind, np.inf, e)
    return out


def recall(errors, thresholds) -> np.ndarray:
    """(T,) float64 fractions of the (N,) errors strictly below each of the (T,) thresholds (same unit): BOP's
    recall with one object per image and one estimate for it (a pose is correct when its error < threshold)."""
    e = np.asarray(errors, np.float64).reshape(-1, 1)
    assert e.size > 0, "recall of no frames"
    return (e < np.asarray(thresholds, np.float64).reshape(1, -1)).mean(axis=0)


def average_recall(errors, thresholds) -> float:
    """BOP's average recall (AR_MSSD, AR_MSPD): the mean of :func:`recall` over the (T,) thresholds."""
    return float(recall(errors, thresholds).mean())


def mspd_thresholds_px(image_width_px: int) -> np.ndarray:
    """(10,) MSPD thresholds in pixels of an image ``image_width_px`` wide: BOP's 5..50 px at 640 px scaled
    by width / 640 (BOP scales the error by 640 / width, the same comparison)."""
    return MSPD_THRESHOLDS_PX * float(image_width_px) / BOP_REFERENCE_WIDTH_PX


def bop_scores(add, add_s, mssd, mspd, diameter_mm: float, image_width_px: int) -> dict[str, float | None]:
    """The object's BOP-style summary over N frames from the (N,) per-frame errors of :func:`add_mm`,
    :func:`add_s_mm`, :func:`mssd_mm` (mm) and :func:`mspd_px` (pixels of an image ``image_width_px`` wide).

    Returns:
        {"add_mm", "add_s_mm", "mssd_mm", "mspd_px": means over frames (mspd_px None when a frame's is inf),
        "add_accuracy", "add_s_accuracy": fractions of frames below ``ADD_THRESHOLD_DIAMETER`` x diameter,
        "ar_mssd": average recall at ``MSSD_THRESHOLDS_DIAMETER`` x diameter, "ar_mspd": at
        :func:`mspd_thresholds_px`, "diameter_mm", "image_width_px"}, python floats (and int).
    """
    mspd = np.asarray(mspd, np.float64)
    add_threshold = [ADD_THRESHOLD_DIAMETER * diameter_mm]
    return {
        "add_mm": float(np.mean(add)), "add_s_mm": float(np.mean(add_s)), "mssd_mm": float(np.mean(mssd)),
        "mspd_px": float(mspd.mean()) if np.isfinite(mspd).all() else None,
        "add_accuracy": float(recall(add, add_threshold)[0]), "add_s_accuracy": float(recall(add_s, add_threshold)[0]),
        "ar_mssd": average_recall(mssd, MSSD_THRESHOLDS_DIAMETER * diameter_mm),
        "ar_mspd": average_recall(mspd, mspd_thresholds_px(image_width_px)),
        "diameter_mm": float(diameter_mm), "image_width_px": int(image_width_px),
    }


# ----------------------------------------------------------------------------- spread (collapse guard)


def spread_ratios(pred_m, gt_m) -> dict[str, float | None]:
    """How much the predicted 3D keypoints vary across frames, relative to the truth, per camera axis.

    For each camera axis a, ``spread_a(P)`` is the mean over keypoints of the (population) standard
    deviation over frames of ``P[n, k, a]``, and the ratio ``spread_a(pred) / spread_a(gt)``: 1 when the
    prediction varies as much as the truth, 0 when it is the same for every frame (a collapsed model);
    None where the truth does not vary (spread below ``SPREAD_MIN_M``, e.g. a single frame).

    Args:
        pred_m, gt_m: (N, K, 3) float, metres, the same frames and keypoints (numpy or torch).

    Returns:
        {"x", "y", "z"}: python floats or None.
    """
    _assert_points(pred_m, gt_m, 3)
    if _is_torch(pred_m):
        pred_m, gt_m = (x.detach().cpu().double().numpy() for x in (pred_m, gt_m))
    pred, gt = np.asarray(pred_m, np.float64), np.asarray(gt_m, np.float64)
    assert pred.shape[0] > 0 and pred.shape[1] > 0, pred.shape
    spread_pred = pred.std(axis=0).mean(axis=0)                                    # (3,) metres
    spread_gt = gt.std(axis=0).mean(axis=0)
    return {axis: (float(sp / sg) if sg >= SPREAD_MIN_M else None)
            for axis, sp, sg in zip(SPREAD_AXES, spread_pred, spread_gt)}


def collapsed_axes(ratios: dict[str, float | None], threshold: float = SPREAD_RATIO_WARN) -> list[str]:
    """The axes whose spread ratio (not None) is below ``threshold``, in x, y, z order."""
    assert set(ratios) <= set(SPREAD_AXES), ratios
    return [a for a in SPREAD_AXES if ratios.get(a) is not None and ratios[a] < threshold]
