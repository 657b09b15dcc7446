"""The hand posed from the measured depth: a model's 21 hand joints refined by fitting a capsule hand, built on
those joints, to the depth input.

The depth input sees the hand's near surface; a hand of capsules around the predicted bones, moved and bent until
that surface lies on it, places the hand the image shows. The model and its terms follow articulated ICP for hand
tracking (Tagliasacchi et al., "Robust Articulated-ICP for Real-Time Hand Tracking", Computer Graphics Forum 34(5),
2015: a hand of cylinders, the measured points' distances to it, a term against model parts the sensor would have
seen where it saw something else, a pose prior), solved by Gauss-Newton (Nocedal and Wright, "Numerical
Optimization", 2nd ed., 2006, sec. 10.3) with analytic Jacobians: a joint's derivative by a rotation vector through
SO(3)'s right Jacobian (Sola, Deray and Atchuthan, "A micro Lie theory for state estimation in robotics",
arXiv:1812.01537, 2018, eq. 143), chained along each finger. Numpy only: ``hupbench predict`` runs it without torch.

How, per frame, in the camera of the model input (``K_input``), with :class:`HandFitSettings` ``s``:
    0. The start: given the model's training hands (``s.templates``, :func:`training_hands`: one per training grasp,
       recorded in the model file), the one nearest the network's 21 joints once turned and moved onto them
       (Kabsch, :func:`hupbench.core.geometry.fit_rigid_pose`; the nearest by the mean distance of its joints), so
       that the fit starts from a whole hand of the right proportions in a grasp's shape where the network's fingers
       are off; else the network's joints. Below, "the network's" hand is this start.
    1. The hand: a capsule along each finger bone (the generator's radii, :mod:`hupbench.datagen.assets.hand_anatomy`; a
       fingertip keypoint sits on the surface, so the last capsule stops one radius short of it) and the palm as
       capsules from the wrist to each finger's base (``s.palm_radius_m``) and across the knuckles
       (``s.knuckle_radius_m``).
    2. The measured points: pixels with a surface (depth 0 is unknown, never far), unprojected with their depth,
       within ``s.reach_m`` of the network's capsules and more than ``s.probe_gap_m`` outside the probe posed by the
       output's 8 corners (their box, Kabsch), and, given a segmentation, among its hand pixels; ``s.max_points`` of
       them in a fixed pseudo-random order.
    3. ``s.iterations`` Gauss-Newton steps on 66 parameters: a rotation about the hand's centroid and a
       translation (6), a rotation of each of the 15 finger bones about its proximal joint (45), and each finger
       bone's length as a share of the network's (15; the palm's bones, wrist to each finger's base, stay the
       network's). The residuals: each point's distance to the surface of its nearest capsule
       (points farther than ``s.trim_m`` left out: the arm, the other objects; first half, second half of the
       steps); where a capsule's axis (``s.free_samples`` points on each) is seen in front of the measured
       surface's depth by more than ``s.free_margin_m`` (and at most ``s.free_band_m``: farther, the sensor saw
       past the hand, onto the patient or the room, and pushing the capsule back would pull it there) the capsule
       would be visible there, and it is pushed back (``s.free_weight``); and each bone's rotation times
       ``s.bone_prior_m`` (metres per radian): a finger without measured points, hidden by the probe or the palm,
       keeps the network's pose; each bone's change of length (a share of the network's) times ``s.length_prior_m``:
       the network, which reads the image, gives the lengths the depth corrects (a hand larger or smaller than the
       one the network was trained on), from step ``s.length_from`` x ``s.iterations`` on (before it the lengths
       stay, while the pose comes near: from a start far off, free lengths stretch a finger towards points that
       belong to its neighbour); and the fitted wrist's distance from the network's times ``s.wrist_weight`` (started
       from the true joints the capsule hand's wrist drifts 5 mm; on 48 frames of the paper protocol's val split the
       fitted wrist was 8.6 mm off where the network's was 5.2).
    4. With fewer than ``s.min_points`` measured points (no depth, the hand hidden, too few to fix a rigid
       motion), or a step whose equations could not be solved, or a fit that is not finite, the hand stays where
       the network put it (its own joints, not the start).

The keypoints out are the fitted hand's joints; their 2D points are their projection with ``K_input``. The probe's
corners are not touched (:mod:`hupbench.fits.probe_fit` runs first where a model asks for both).
"""

from __future__ import annotations

import functools
import itertools
from dataclasses import dataclass

import numpy as np

from hupbench.core import keypoints as kp
from hupbench.core.geometry import fit_rigid_pose
from hupbench.core.processes import one_blas_thread
from hupbench.fits.depth_points import (MIN_PROJECTION_Z_M, input_points2d, sample_points, surface_pixels,
                                        unproject_pixels)
from hupbench.fits.known_probe import FitProbe, default_fit_probe
from hupbench.fits.settings import HandFitSettings

__all__ = ["MAX_TEMPLATES", "HandFit", "HandFitSettings", "fit_hand", "pose_and_jacobian", "training_hands"]

#: the parameters: rigid motion (6), the 15 finger bones' turns (3 each), then their lengths (1 each)
_TURNS = slice(6, 6 + 15 * 3)
_LENGTHS = slice(_TURNS.stop, _TURNS.stop + 15)
N_PARAMS = _LENGTHS.stop
#: the normal equations' diagonal, (row, column) index
_DIAGONAL = np.arange(N_PARAMS)
#: the most training hands a model file carries (:func:`training_hands`)
MAX_TEMPLATES = 64


def training_hands(keypoints3d: np.ndarray, grasp_ids: np.ndarray) -> np.ndarray:
    """(T, 21, 3) float64 metres: the hands a model's hand fit may start from (module docstring, step 0): the 21 hand
    joints of the first frame of each grasp of a training split (a grasp's hand has one shape in all its views, up
    to the rigid motion the fit's start takes out), of at most :data:`MAX_TEMPLATES` grasps evenly spaced in the
    order of their ids. ``keypoints3d``: (N, 29, 3) the split's camera-frame keypoints; ``grasp_ids``: (N,)."""
    ids, first = np.unique(np.asarray(grasp_ids), return_index=True)
    keep = first[np.unique(np.linspace(0, len(ids) - 1, min(len(ids), MAX_TEMPLATES)).round().astype(np.int64))]
    return np.asarray(keypoints3d, dtype=np.float64)[keep][:, kp.HAND_SLICE]


def _template_start(hand: np.ndarray, templates: np.ndarray) -> np.ndarray:
    """(B, 21, 3): for each of the network's hands (B, 21, 3), the template (T, 21, 3) turned and moved onto it
    (Kabsch) whose joints lie nearest it on average (module docstring, step 0)."""
    B, T = len(hand), len(templates)
    target = np.repeat(hand, T, axis=0)                                          # (B * T, 21, 3)
    source = np.tile(templates, (B, 1, 1))
    pose = fit_rigid_pose(source, target)
    placed = (source @ pose[:, :3, :3].transpose(0, 2, 1) + pose[:, None, :3, 3]).reshape(B, T, -1, 3)
    nearest = np.linalg.norm(placed - hand[:, None], axis=-1).mean(-1).argmin(axis=1)
    return placed[np.arange(B), nearest]


@dataclass(frozen=True)
class HandFit:
    """What :func:`fit_hand` did, per frame: ``points`` (B,) int64 measured points near the hand, ``fitted`` (B,)
    bool whether its joints are the fit's (else the network's, kept: module docstring, step 4)."""

    points: np.ndarray
    fitted: np.ndarray


@dataclass(frozen=True)
class _Capsules:
    start: np.ndarray     # (C,) keypoint at one end
    end: np.ndarray       # (C,) keypoint at the other
    radius: np.ndarray    # (C,) metres
    tip: np.ndarray       # (C,) bool: the end is a fingertip keypoint on the surface


@functools.lru_cache(maxsize=4)
def _capsules(palm_radius_m: float, knuckle_radius_m: float) -> _Capsules:
    """The capsule hand's capsules (module docstring, step 1), by keypoint index."""
    from hupbench.datagen.assets.hand_anatomy import FINGER_RADII_MM, MM, THUMB_RADII_MM

    rows = []
    for finger in kp.FINGERS:
        base = kp.FINGER_START[finger]
        radii = THUMB_RADII_MM if finger == "thumb" else FINGER_RADII_MM[finger]
        rows += [(base + k, base + k + 1, radii[k] * MM, k == 2) for k in range(3)]
        rows.append((0, base, palm_radius_m, False))
    knuckles = [kp.FINGER_START[f] for f in ("index", "middle", "ring", "little")]
    rows += [(a, b, knuckle_radius_m, False) for a, b in itertools.pairwise(knuckles)]
    start, end, radius, tip = (np.array(c) for c in zip(*rows))
    return _Capsules(start, end, radius.astype(np.float64), tip.astype(bool))


#: the cross-product matrices of the unit vectors x, y, z, a row each: [v]x = v @ this, reshaped (one product
#: instead of nine stacked components; the same numbers, 6 % of the hand's fit at batch 1)
_SKEW_BASIS = np.array([[[0, 0, 0], [0, 0, -1], [0, 1, 0]],
                        [[0, 0, 1], [0, 0, 0], [-1, 0, 0]],
                        [[0, -1, 0], [1, 0, 0], [0, 0, 0]]], dtype=np.float64).reshape(3, 9)


def _skew(v: np.ndarray) -> np.ndarray:
    """(..., 3, 3) cross-product matrices of vectors (..., 3) (unchecked: a fit's numbers may not be finite)."""
    return (v @ _SKEW_BASIS).reshape(*v.shape[:-1], 3, 3)


def _rodrigues_and_right_jacobian(w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(..., 3, 3) rotations of axis-angle vectors w (..., 3) and SO(3)'s right Jacobians there, with
    d(R(w) x)/dw = -R(w) [x]x Jr(w); both smooth through 0 (Taylor terms below 1e-4 rad)."""
    angle2 = (w * w).sum(-1)[..., None, None]
    angle = np.sqrt(angle2)
    small = angle < 1e-4
    safe = np.where(small, 1.0, angle)
    sin = np.sin(safe)
    sin_a = np.where(small, 1.0 - angle2 / 6.0, sin / safe)                               # sin t / t
    cos_a = np.where(small, 0.5 - angle2 / 24.0, (1.0 - np.cos(safe)) / safe ** 2)       # (1 - cos t) / t^2
    cube = np.where(small, 1.0 / 6.0 - angle2 / 120.0, (safe - sin) / safe ** 3)          # (t - sin t) / t^3
    W = _skew(w)
    WW = W @ W
    eye = np.eye(3)
    return eye + sin_a * W + cos_a * WW, eye - cos_a * W + cube * WW


#: the wrist's keypoint index
_WRIST = kp.HAND_NAMES.index("wrist")
#: each finger's first keypoint (the MCP joint; the CMC for the thumb), in :data:`kp.FINGERS` order
_FINGER_BASE = np.array([kp.FINGER_START[f] for f in kp.FINGERS])
#: each finger's keypoints, base to tip (5, 4): bone k runs from column k to column k + 1
_CHAIN = _FINGER_BASE[:, None] + np.arange(4)
#: (k, j) 1 where bone j lies at or above bone k along its finger (j <= k): bone j moves the joint after bone k
_AT_OR_ABOVE = np.tril(np.ones((3, 3)))


def pose_and_jacobian(theta: np.ndarray, hand: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Hands (B, 21, 3) moved by their (B, 66) parameters (module docstring, step 3), and the joints' Jacobian
    (B, 21, 3, 66) by the parameters.

    Along each finger, with T_k = B_k ... B_0 the turns of bones 0..k, v_k the network's bone k (moved rigidly) and
    (1 + l_k) its length's share: the joint after bone k is the finger's base + sum_{i <= k} T_i (1 + l_i) v_i; its
    derivative by bone j's turn (j <= k) sums -T_i [(1 + l_i) v_i]x T_{j-1}^T Jr_j over i = j..k, by bone i's length
    T_i v_i. Every finger and bone at once (a few dozen array operations: at batch 1 each costs its call)."""
    B = len(hand)
    turns = np.concatenate([theta[:, None, :3], theta[:, _TURNS].reshape(B, 15, 3)], axis=1)
    rotations, right = _rodrigues_and_right_jacobian(turns)                               # (B, 16, 3, 3)
    R0, J0 = rotations[:, 0], right[:, 0]
    bones, bone_jr = rotations[:, 1:].reshape(B, 5, 3, 3, 3), right[:, 1:].reshape(B, 5, 3, 3, 3)
    centre = hand.mean(1, keepdims=True)
    local = hand - centre
    moved = local @ R0.swapaxes(-1, -2) + centre + theta[:, None, 3:6]
    # d(R0 x)/d(rotation) = -R0 [x]x Jr(w0): linear in x, so a bone's is its two joints' difference
    d_global = -R0[:, None] @ _skew(local) @ J0[:, None]                                  # (B, 21, 3, 3)
    grow = 1.0 + theta[:, _LENGTHS].reshape(B, 5, 3)                  # each bone's length over the network's
    above = bones[:, :, 1] @ bones[:, :, 0]
    turned = np.stack([bones[:, :, 0], above, bones[:, :, 2] @ above], axis=2)             # T_k (B, 5, 3, 3, 3)
    before = np.concatenate([np.broadcast_to(np.eye(3), (B, 5, 1, 3, 3)), turned[:, :, :2]], axis=2)   # T_{k-1}
    network_bone = moved[:, _CHAIN[:, 1:]] - moved[:, _CHAIN[:, :-1]]                    # v_k (B, 5, 3, 3)
    turned_bone = (turned @ network_bone[..., None])[..., 0]                               # T_k v_k
    out = moved.copy()
    out[:, _CHAIN[:, 1:]] = moved[:, _FINGER_BASE, None] + np.cumsum(turned_bone * grow[..., None], axis=2)

    jac = np.zeros((B, kp.NUM_HAND, 3, N_PARAMS))
    jac[..., :3], jac[..., 3:6] = d_global, np.eye(3)
    bone_global = d_global[:, _CHAIN[:, 1:]] - d_global[:, _CHAIN[:, :-1]]              # (B, 5, 3, 3, 3)
    jac[:, _CHAIN[:, 1:], :, :3] = d_global[:, _FINGER_BASE, None] + np.cumsum(
        grow[..., None, None] * (turned @ bone_global), axis=2)
    # by bone j's turn: -T_i [(1 + l_i) v_i]x (i, rows) times T_{j-1}^T Jr_j (j, columns), summed over i = j..k
    lever = -turned @ _skew(network_bone * grow[..., None])                                 # (B, 5, 3, 3, 3)
    frame = before.swapaxes(-1, -2) @ bone_jr                                              # (B, 5, 3, 3, 3)
    pairs = (lever[:, :, :, None] @ frame[:, :, None]) * _AT_OR_ABOVE[:, :, None, None]     # (B, 5, i, j, 3, 3)
    by_turn = np.cumsum(pairs, axis=2).transpose(0, 1, 2, 4, 3, 5).reshape(B, 5, 3, 3, 9)    # (B, 5, k, xyz, 9)
    by_length = turned_bone.swapaxes(-1, -2)[:, :, None] * _AT_OR_ABOVE[:, None, :]         # (B, 5, k, xyz, 3)
    eye = np.eye(5)
    jac[:, _CHAIN[:, 1:], :, _TURNS] = np.einsum("bfkxp,fg->bfkxgp", by_turn, eye).reshape(B, 5, 3, 3, 45)
    jac[:, _CHAIN[:, 1:], :, _LENGTHS] = np.einsum("bfkxl,fg->bfkxgl", by_length, eye).reshape(B, 5, 3, 3, 15)
    return out, jac


def _ends(hand: np.ndarray, caps: _Capsules, jac: np.ndarray | None = None):
    """The capsules' axis ends (B, C, 3) of hands (B, 21, 3) and, given the joints' Jacobian (B, 21, 3, N), theirs
    (B, C, 3, N)."""
    a, b = hand[:, caps.start], hand[:, caps.end]
    length = np.maximum(np.linalg.norm(b - a, axis=-1, keepdims=True), 1e-6)
    along = (b - a) / length
    shorten = caps.radius[:, None] * caps.tip[:, None]                  # r at a tip capsule, else 0
    end = b - along * shorten
    if jac is None:
        return a, end
    ja, jb = jac[:, caps.start], jac[:, caps.end]
    across = (np.eye(3) - along[..., :, None] * along[..., None, :]) * (shorten / length)[..., None]  # (B, C, 3, 3)
    return a, end, ja, jb - across @ (jb - ja)


def _nearest(points: np.ndarray, a: np.ndarray, b: np.ndarray, radius: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each point's (B, P) signed distance to the capsules with axes a-b (B, C, 3) and ``radius`` (C,), the index
    of its nearest capsule, and the place t in [0, 1] of the closest point on that capsule's axis.

    Every point against every capsule (B, P, C) from two batched products, p.a and p.(b - a): with q = p - a and
    t = clip(q.ab / ab.ab), the squared distance is q.q - 2 t q.ab + t^2 ab.ab (a quarter of the time of taking
    each difference at 512 points and 20 capsules; in float64 the cancellation costs under a nanometre at the
    hand's scale)."""
    ab = b - a                                                                     # (B, C, 3)
    C = ab.shape[1]
    products = points @ np.concatenate([a, ab], axis=1).swapaxes(-1, -2)          # (B, P, 2C): p.a, p.ab
    p_a = products[..., :C]
    q_ab = products[..., C:] - (a * ab).sum(-1)[:, None]                           # (q = p - a) . ab
    ab_ab = (ab * ab).sum(-1)[:, None]
    q_q = (points * points).sum(-1)[..., None] - 2.0 * p_a + (a * a).sum(-1)[:, None]
    t = np.clip(q_ab / np.maximum(ab_ab, 1e-12), 0.0, 1.0)
    d = np.sqrt(np.maximum(q_q - t * (2.0 * q_ab - t * ab_ab), 0.0)) - radius
    nearest = d.argmin(axis=-1)
    return (np.take_along_axis(d, nearest[..., None], -1)[..., 0], nearest,
            np.take_along_axis(t, nearest[..., None], -1)[..., 0])


@functools.lru_cache(maxsize=4)
def _free_lambdas(samples: int) -> np.ndarray:
    """(F, 1) places of the free-space samples along a capsule's axis, 0 to 1 (read-only)."""
    lam = np.linspace(0.0, 1.0, samples)[:, None]
    lam.flags.writeable = False
    return lam


@functools.lru_cache(maxsize=4)
def _prior_weights(bone_prior_m: float, length_prior_m: float) -> np.ndarray:
    """(66,) the priors' squared weights on the normal equations' diagonal: 0 for the rigid motion, each bone's turn
    ``bone_prior_m`` ** 2, each bone's length ``length_prior_m`` ** 2 (read-only)."""
    prior = np.zeros(N_PARAMS)
    prior[_TURNS], prior[_LENGTHS] = bone_prior_m ** 2, length_prior_m ** 2
    prior.flags.writeable = False
    return prior


def _normal_equations(theta, hand, points, real, trim, depth, K, s: HandFitSettings, caps: _Capsules):
    """Gauss-Newton's (B, 66, 66) J^T J and (B, 66) J^T r of the residuals (module docstring, step 3) at parameters
    theta (B, 66): hands (B, 21, 3), points (B, P, 3) with weights (B, P) (those farther than ``trim`` from the
    capsules left out), depth (B, S, S), K (3, 3)."""
    B, C = len(theta), len(caps.radius)
    joints, jac = pose_and_jacobian(theta, hand)
    a, b, ja, jb = _ends(joints, caps, jac)
    distance, nearest, t = _nearest(points, a, b, caps.radius)
    weight = real * (np.abs(distance) < trim)
    start = np.take_along_axis(a, nearest[..., None], axis=1)
    e = points - start - t[..., None] * (np.take_along_axis(b, nearest[..., None], axis=1) - start)  # from the axis
    d = np.sqrt(e[..., 0] * e[..., 0] + e[..., 1] * e[..., 1] + e[..., 2] * e[..., 2])   # exact, unlike _nearest's
    n = e / np.where(d > 1e-12, d, np.inf)[..., None]               # the unit direction (0 at distance 0)
    r_surface = (d - caps.radius[nearest]) * weight
    # a point's row of J is x^T G[c] for its capsule c, G = the capsule's two ends' Jacobians (6, 66) and x its
    # distance's gradient by them (6): J^T J sums G^T (x x^T) G, so the x x^T are summed per capsule first
    x = np.concatenate([-(1 - t)[..., None] * n, -t[..., None] * n], -1) * weight[..., None]      # (B, P, 6)
    of_capsule = (nearest[:, None, :] == np.arange(C)[:, None]).astype(np.float64)               # (B, C, P)
    moments = (of_capsule @ (x[..., :, None] * x[..., None, :]).reshape(B, -1, 36)).reshape(B, C, 6, 6)
    pulls = of_capsule @ (x * r_surface[..., None])                                              # (B, C, 6)

    # free space: samples along each capsule's axis seen in front of the measured surface
    lam = _free_lambdas(s.free_samples)
    samples = a[:, :, None] + lam * (b - a)[:, :, None]                                   # (B, C, F, 3)
    unclamped = samples[..., 2] > MIN_PROJECTION_Z_M
    z = np.maximum(samples[..., 2], MIN_PROJECTION_Z_M)[..., None]
    focal = K[[0, 1], [0, 1]]
    uv = focal * samples[..., :2] / z + K[:2, 2]                                           # (B, C, F, 2) pixels
    size = depth.shape[-1]
    clamped = np.clip(uv, 0.0, size - 1.001)
    cell = np.floor(clamped)
    fu, fv = np.moveaxis(clamped - cell, -1, 0)
    idx = (cell @ np.array([1.0, size])).astype(np.int64).reshape(B, -1, 1) + np.array([0, 1, size, size + 1])
    corner = np.take_along_axis(depth.reshape(B, -1), idx.reshape(B, -1), axis=1).reshape(*uv.shape, 2)  # [v, u]
    across = corner[..., 1] - corner[..., 0]                                  # along u, at the cell's two rows
    rows = corner[..., 0] + fu[..., None] * across                            # bilinear: along u, then along v
    measured = rows[..., 0] + fv * (rows[..., 1] - rows[..., 0])
    inside = ((uv > 0) & (uv < size - 1)).all(-1) & (measured > 0)
    behind = measured - (z[..., 0] - caps.radius[:, None])   # how far the measured surface lies behind the front
    gap = behind - s.free_margin_m
    active = inside & (gap > 0) & (behind <= s.free_band_m)
    r_free = np.where(active, gap, 0.0) * s.free_weight
    # d(measured - z)/d(sample): the measured depth's by (u, v) through the projection's (u by x and z, v by y and z)
    slope = np.stack([across[..., 0] + fv * (across[..., 1] - across[..., 0]), rows[..., 1] - rows[..., 0]], -1)
    slope = slope * ((uv > 0) & (uv < size - 1.001))
    along_z = -(slope * focal * samples[..., :2]).sum(-1) / z[..., 0] ** 2 * unclamped - unclamped
    grad = np.concatenate([slope * focal / z, along_z[..., None]], -1) * (active * s.free_weight)[..., None]
    x_free = np.concatenate([grad * (1 - lam), grad * lam], -1)                                  # (B, C, F, 6)
    moments += x_free.swapaxes(-1, -2) @ x_free
    pulls += (x_free * r_free[..., None]).sum(2)
    G = np.concatenate([ja, jb], axis=2)                                                         # (B, C, 6, 66)
    JTJ = (moments @ G).reshape(B, -1, N_PARAMS).swapaxes(-1, -2) @ G.reshape(B, -1, N_PARAMS)
    JTr = (G.reshape(B, -1, N_PARAMS).swapaxes(-1, -2) @ pulls.reshape(B, -1, 1))[..., 0]

    # each bone's turn and length, a prior towards the network's
    prior = _prior_weights(s.bone_prior_m, s.length_prior_m)
    JTJ[:, _DIAGONAL, _DIAGONAL] += prior
    JTr += prior * theta
    # the network's wrist, held: the capsule hand's own wrist drifts from the true one (module docstring, step 3)
    wrist = jac[:, _WRIST] * s.wrist_weight                                                  # (B, 3, 66)
    JTJ += wrist.swapaxes(-1, -2) @ wrist
    JTr += (wrist.swapaxes(-1, -2) @ ((joints[:, _WRIST] - hand[:, _WRIST]) * s.wrist_weight)[..., None])[..., 0]
    return JTJ, JTr


def _solve(A: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each frame's solution of A x = y (B, N, N), (B, N) and whether it has one (finite; else x = 0)."""
    try:
        x = np.linalg.solve(A, y[..., None])[..., 0]
    except np.linalg.LinAlgError:   # a singular frame: solve frame by frame
        x = np.zeros_like(y)
        for i in range(len(A)):
            try:
                x[i] = np.linalg.solve(A[i], y[i])
            except np.linalg.LinAlgError:
                x[i] = np.nan
    ok = np.isfinite(x).all(axis=1)
    return np.where(ok[:, None], x, 0.0), ok


def _measured_points(depth: np.ndarray, K: np.ndarray, hand: np.ndarray, probe_pose: np.ndarray,
                     s: HandFitSettings, caps: _Capsules, probe: FitProbe, pixels: np.ndarray | None
                     ) -> tuple[np.ndarray, np.ndarray]:
    """(B, P, 3) camera-frame points of the depth maps (B, S, S) near the hands (B, 21, 3), off the probes posed
    by (B, 4, 4) and among ``pixels`` (B, S, S) bool where given, and their (B, P) weights (1 real, 0 padding),
    P = ``s.max_points`` (module docstring, step 2)."""
    # only pixels in the box around the joints can lie within reach of a capsule: the distances are taken there
    margin = float(caps.radius.max()) + s.reach_m
    lo, hi = hand.min(1) - margin, hand.max(1) + margin
    wanted = surface_pixels(depth, pixels)
    for b, where in enumerate(wanted):
        cand = np.flatnonzero(where)
        p = unproject_pixels(depth[b], K, cand)
        box = ((p > lo[b]) & (p < hi[b])).all(-1)
        cand, p = cand[box], p[box]
        where[:] = False
        if len(cand):
            off_probe = probe.signed_distance_and_gradient(
                (p - probe_pose[b, :3, 3]) @ probe_pose[b, :3, :3])[0] > s.probe_gap_m
            where[cand] = (_nearest(p[None], *_ends(hand[b:b + 1], caps), caps.radius)[0][0] < s.reach_m) & off_probe
    return sample_points(depth, K, wanted, s.max_points)


@one_blas_thread()
def fit_hand(points2d: np.ndarray, points3d: np.ndarray, images: np.ndarray, K_input: np.ndarray,
             settings: HandFitSettings = HandFitSettings(), probe: FitProbe | None = None,
             pixels: np.ndarray | None = None, templates: np.ndarray | None = None
             ) -> tuple[np.ndarray, np.ndarray, HandFit]:
    """The hand joints of a model's output refined against its depth input (module docstring).

    Args:
        points2d: (B, 29, 2) float, normalised input coordinates, and points3d: (B, 29, 3) float, metres, camera
            frame of ``K_input``: the model's output (the probe's corners as the probe's fit left them).
        images: (B, 4, S, S) float32 model images: RGB in [0, 1], then the depth channel (metres, 0 = none).
        K_input: (3, 3) intrinsics of the model input, pixels.
        settings: the fit's tuning values (:class:`HandFitSettings`).
        probe: the probe whose surface is left out (None: the default procedural probe).
        pixels: (B, S, S) bool, the pixels that may be the hand's (a segmentation's, :func:`hupbench.fits.
            after_network`); a measured point elsewhere (the probe, the patient's skin) is left out. None: any pixel.
        templates: (T, 21, 3) float, metres, the model's training hands (:func:`training_hands`, a model config's
            ``hand_templates``): with ``settings.templates`` the fit starts from the nearest (step 0). None: the
            network's joints.

    Returns:
        (points2d (B, 29, 2), points3d (B, 29, 3)) float64 with the 21 hand joints replaced, and :class:`HandFit`.
    """
    assert images.ndim == 4 and images.shape[1] == 4, images.shape
    assert points3d.shape == (len(images), kp.NUM_KEYPOINTS, 3), points3d.shape
    s, probe = settings, probe or default_fit_probe()
    caps = _capsules(s.palm_radius_m, s.knuckle_radius_m)
    K = np.asarray(K_input, dtype=np.float64)
    depth = np.asarray(images[:, 3], dtype=np.float64)
    network = np.asarray(points3d[:, kp.HAND_SLICE], dtype=np.float64)
    use_templates = s.templates and templates is not None and len(templates) and len(network)
    hand = _template_start(network, np.asarray(templates, dtype=np.float64)) if use_templates else network
    probe_pose = fit_rigid_pose(probe.corners, np.asarray(points3d[:, kp.CORNER_SLICE], dtype=np.float64))
    points, real = _measured_points(depth, K, hand, probe_pose, s, caps, probe, pixels)
    B = len(images)
    count = real.sum(1).astype(np.int64)
    rows = np.flatnonzero(count >= s.min_points)     # the others keep the network's hand (step 4): not fitted
    theta, solved = np.zeros((B, N_PARAMS)), np.ones(B, dtype=bool)
    if len(rows):
        fitting, ok_rows = np.zeros((len(rows), N_PARAMS)), np.ones(len(rows), dtype=bool)
        for step in range(s.iterations):
            trim = s.trim_m[0 if step < s.iterations // 2 else 1]
            JTJ, JTr = _normal_equations(fitting, hand[rows], points[rows], real[rows], trim, depth[rows], K, s, caps)
            # the lengths held (the network's) until the pose has come near: the parameters before them solved alone
            n = N_PARAMS if step >= s.length_from * s.iterations else _LENGTHS.start
            delta = np.zeros_like(fitting)
            delta[:, :n], ok = _solve(JTJ[:, :n, :n] + s.damping * np.eye(n), -JTr[:, :n])
            ok_rows &= ok
            fitting = fitting + np.where(ok_rows[:, None], delta, 0.0)
        theta[rows], solved[rows] = fitting, ok_rows
    fitted = pose_and_jacobian(theta, hand)[0]
    use = (count >= s.min_points) & solved & np.isfinite(fitted).all(axis=(1, 2))
    fitted = np.where(use[:, None, None], fitted, network)
    out3d, out2d = np.array(points3d, dtype=np.float64), np.array(points2d, dtype=np.float64)
    out3d[:, kp.HAND_SLICE] = fitted
    out2d[:, kp.HAND_SLICE] = np.where(use[:, None, None], input_points2d(fitted, K_input, images.shape[-1]),
                                       out2d[:, kp.HAND_SLICE])
    return out2d, out3d, HandFit(count, use)
