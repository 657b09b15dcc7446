"""The hand posed from the measured depth: a model's 21 hand joints refined by fitting a capsule hand, built on
those joints, to the depth input.

The depth input sees the hand's near surface; a hand of capsules around the predicted bones, moved and bent until
that surface lies on it, places the hand the image shows. The model and its terms follow articulated ICP for hand
tracking (Tagliasacchi et al., "Robust Articulated-ICP for Real-Time Hand Tracking", Computer Graphics Forum 34(5),
2015: a hand of cylinders, the measured points' distances to it, a term against model parts the sensor would have
seen where it saw something else, a pose prior), solved by Gauss-Newton (Nocedal and Wright, "Numerical Optimization", 2nd ed., 2006, sec. 10.3) with
Jacobians by forward-mode automatic differentiation (``torch.func.jacfwd``).

How, per frame, in the camera of the model input (``K_input``), with :class:`HandFitSettings` ``s``:
    1. The hand: a capsule along each finger bone (the generator's radii, :mod:`hupbench.datagen.assets.hand_anatomy`; a
       fingertip keypoint sits on the surface, so the last capsule stops one radius short of it) and the palm as
       capsules from the wrist to each finger's base (``s.palm_radius_m``) and across the knuckles
       (``s.knuckle_radius_m``).
    2. The measured points: pixels with a surface, unprojected with their depth, within ``s.reach_m`` of the
       network's capsules and more than ``s.probe_gap_m`` outside the probe posed by the output's 8 corners (their
       box, Kabsch); ``s.max_points`` of them in a fixed pseudo-random order.
    3. ``s.iterations`` Gauss-Newton steps on 51 parameters: a rotation about the hand's centroid and a
       translation (6), and a rotation of each of the 15 finger bones about its proximal joint (45; the bone
       lengths stay the network's). The residuals: each point's distance to the surface of its nearest capsule
       (points farther than ``s.trim_m`` left out: the arm, the other objects; first half, second half of the
       steps); where a capsule's axis (``s.free_samples`` points on each) is seen in front of the measured
       surface's depth by more than ``s.free_margin_m`` the capsule would be visible there, and it is pushed back
       (``s.free_weight``); and each bone's rotation times ``s.bone_prior_m`` (metres per radian): a finger
       without measured points, hidden by the probe or the palm, keeps the network's pose.
    4. With fewer than ``s.min_points`` measured points (no depth, the hand hidden, too few to fix a rigid
       motion), or a step whose equations could not be solved, or a fit that is not finite, the hand stays where
       the network put it.

The keypoints out are the fitted hand's joints; their 2D points are their projection with ``K_input``. The probe's
corners are not touched (:mod:`hupbench.fits.probe_fit` runs first where a model asks for both).
"""

from __future__ import annotations

import functools
import itertools
from dataclasses import dataclass

import numpy as np
import torch

from hupbench.core import keypoints as kp
from hupbench.fits.depth_points import MIN_PROJECTION_Z_M, input_points2d, sample_points, unproject_depth
from hupbench.fits.probe_fit import probe_model
from hupbench.fits.settings import HandFitSettings
from hupbench.metrics import fit_rigid_pose

__all__ = ["HandFit", "HandFitSettings", "fit_hand"]

#: rigid motion (6) and the 15 finger bones' turns (3 each)
N_PARAMS = 6 + 15 * 3


@dataclass(frozen=True)
class HandFit:
    """What :func:`fit_hand` did, per frame: ``points`` (B,) int64 measured points near the hand, ``fitted`` (B,)
    bool whether its joints are the fit's (else the network's, kept: module docstring, step 4)."""

    points: np.ndarray
    fitted: np.ndarray


@dataclass(frozen=True)
class _Capsules:
    start: torch.Tensor     # (C,) keypoint at one end
    end: torch.Tensor       # (C,) keypoint at the other
    radius: torch.Tensor    # (C,) metres
    tip: torch.Tensor       # (C,) bool: the end is a fingertip keypoint on the surface


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
    start, end, radius, tip = zip(*rows)
    return _Capsules(torch.tensor(start), torch.tensor(end), torch.tensor(radius, dtype=torch.float32),
                     torch.tensor(tip))


def _ends(hand: torch.Tensor, caps: _Capsules) -> tuple[torch.Tensor, torch.Tensor]:
    """The capsules' axis ends (..., C, 3) of hands (..., 21, 3)."""
    a, b = hand[..., caps.start, :], hand[..., caps.end, :]
    along = (b - a) / (b - a).norm(dim=-1, keepdim=True).clamp_min(1e-6)
    return a, torch.where(caps.tip[:, None], b - along * caps.radius[:, None], b)


def _segment_distance(points: torch.Tensor, a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Distance from points (..., 3) to segments a-b (..., 3), broadcast."""
    ab, ap = b - a, points - a
    t = ((ap * ab).sum(-1) / (ab * ab).sum(-1).clamp_min(1e-12)).clamp(0.0, 1.0)
    return (ap - t[..., None] * ab).norm(dim=-1)


def _nearest(points: torch.Tensor, hand: torch.Tensor, caps: _Capsules) -> tuple[torch.Tensor, torch.Tensor]:
    """Each point's (B, P) signed distance to the capsule hand and the index of its nearest capsule."""
    a, b = _ends(hand, caps)
    d = _segment_distance(points[:, :, None], a[:, None], b[:, None]) - caps.radius
    return d.min(dim=-1)


def _rodrigues(w: torch.Tensor) -> torch.Tensor:
    """(..., 3, 3) rotations of axis-angle vectors (..., 3), smooth through 0 (differentiable there)."""
    angle2 = (w * w).sum(-1)[..., None, None]
    angle = torch.sqrt(angle2 + 1e-12)
    x, y, z = w.unbind(-1)
    zero = torch.zeros_like(x)
    cross = torch.stack([zero, -z, y, z, zero, -x, -y, x, zero], -1).reshape(*w.shape[:-1], 3, 3)
    return torch.eye(3) + torch.sin(angle) / angle * cross + (1 - torch.cos(angle)) / (angle2 + 1e-12) * cross @ cross


def _pose(theta: torch.Tensor, hand: torch.Tensor) -> torch.Tensor:
    """One hand (21, 3) moved by its (51,) parameters (module docstring, step 3)."""
    centre = hand.mean(0)
    moved = (hand - centre) @ _rodrigues(theta[:3]).T + centre + theta[3:6]
    bones = _rodrigues(theta[6:].reshape(5, 3, 3))
    out = [moved[0]] + [None] * (kp.NUM_HAND - 1)
    for i, finger in enumerate(kp.FINGERS):
        base = kp.FINGER_START[finger]
        out[base] = moved[base]
        turned = torch.eye(3)
        for k in range(3):
            turned = bones[i, k] @ turned
            out[base + k + 1] = out[base + k] + turned @ (moved[base + k + 1] - moved[base + k])
    return torch.stack(out)


def _residuals(theta, hand, points, weight, nearest, depth, K, s: HandFitSettings, caps: _Capsules):
    """One frame's residuals (module docstring, step 3) for parameters (51,): hand (21, 3), points (P, 3) with
    weights (P,) and nearest capsules (P,), depth (S, S), K (3, 3)."""
    a, b = _ends(_pose(theta, hand), caps)
    surface = (_segment_distance(points, a[nearest], b[nearest]) - caps.radius[nearest]) * weight
    samples = a[:, None] + torch.linspace(0.0, 1.0, s.free_samples)[None, :, None] * (b - a)[:, None]   # (C, F, 3)
    z = samples[..., 2].clamp_min(MIN_PROJECTION_Z_M)
    u = K[0, 0] * samples[..., 0] / z + K[0, 2]
    v = K[1, 1] * samples[..., 1] / z + K[1, 2]
    size = depth.shape[-1]
    uc, vc = u.clamp(0.0, size - 1.001), v.clamp(0.0, size - 1.001)
    u0, v0 = uc.detach().floor(), vc.detach().floor()
    fu, fv = uc - u0, vc - v0
    flat = depth.reshape(-1)
    at = lambda dv, du: flat[((v0.long() + dv) * size + u0.long() + du).reshape(-1)].reshape(u.shape)
    measured = (at(0, 0) * (1 - fu) * (1 - fv) + at(0, 1) * fu * (1 - fv) + at(1, 0) * (1 - fu) * fv
                + at(1, 1) * fu * fv)
    inside = (u > 0) & (u < size - 1) & (v > 0) & (v < size - 1) & (measured > 0)
    front = z - caps.radius[:, None]
    free = torch.relu(measured - front - s.free_margin_m) * inside.float() * s.free_weight
    return torch.cat([surface, free.reshape(-1), theta[6:] * s.bone_prior_m])


def _measured_points(depth: torch.Tensor, K: torch.Tensor, hand: torch.Tensor, probe_rotation: torch.Tensor,
                     probe_translation: torch.Tensor, s: HandFitSettings, caps: _Capsules
                     ) -> tuple[torch.Tensor, torch.Tensor]:
    """(B, P, 3) camera-frame points of the depth maps (B, S, S) near the hands (B, 21, 3) and off the probes,
    and their (B, P) weights (1 real, 0 padding), P = ``s.max_points`` (module docstring, step 2)."""
    points = unproject_depth(depth, K)
    near = (points[..., 2] > 0) & (_nearest(points, hand, caps)[0] < s.reach_m)
    on_probe, _ = probe_model().probe.signed_distance_and_gradient_torch((points - probe_translation[:, None])
                                                                            @ probe_rotation)
    return sample_points(points, near & (on_probe > s.probe_gap_m), s.max_points)


def fit_hand(points2d: np.ndarray, points3d: np.ndarray, images: np.ndarray, K_input: np.ndarray,
             settings: HandFitSettings = HandFitSettings()) -> tuple[np.ndarray, np.ndarray, HandFit]:
    """The hand joints of a model's output refined against its depth input (module docstring).

    Args:
        points2d: (B, 29, 2) float, normalised input coordinates, and points3d: (B, 29, 3) float, metres, camera
            frame of ``K_input``: the model's output (the probe's corners as the probe's fit left them).
        images: (B, 4, S, S) float32 model images: RGB in [0, 1], then the depth channel (metres, 0 = none).
        K_input: (3, 3) intrinsics of the model input, pixels.
        settings: the fit's tuning values (:class:`HandFitSettings`).

    Returns:
        (points2d (B, 29, 2), points3d (B, 29, 3)) float64 with the 21 hand joints replaced, and :class:`HandFit`.
    """
    from torch.func import jacfwd, vmap

    assert images.ndim == 4 and images.shape[1] == 4, images.shape
    assert points3d.shape == (len(images), kp.NUM_KEYPOINTS, 3), points3d.shape
    s = settings
    caps = _capsules(s.palm_radius_m, s.knuckle_radius_m)
    probe = fit_rigid_pose(probe_model().corners.double().numpy(), points3d[:, kp.CORNER_SLICE])   # (B, 4, 4)
    with torch.inference_mode(False), torch.no_grad():
        K = torch.as_tensor(np.asarray(K_input, dtype=np.float64), dtype=torch.float32)
        depth = torch.as_tensor(images[:, 3], dtype=torch.float32)
        hand = torch.as_tensor(np.asarray(points3d[:, kp.HAND_SLICE]), dtype=torch.float32)
        probe = torch.as_tensor(probe, dtype=torch.float32)
        points, real = _measured_points(depth, K, hand, probe[:, :3, :3], probe[:, :3, 3], s, caps)
        B = len(images)
        theta, solved = torch.zeros(B, N_PARAMS), torch.ones(B, dtype=torch.bool)
        frames = (0, 0, 0, 0, 0, 0, None)
        one_frame = functools.partial(_residuals, s=s, caps=caps)
        residuals, jacobian = vmap(one_frame, in_dims=frames), vmap(jacfwd(one_frame), in_dims=frames)
        for step in range(s.iterations):
            distance, nearest = _nearest(points, vmap(_pose)(theta, hand), caps)
            weight = real * (distance.abs() < s.trim_m[0 if step < s.iterations // 2 else 1]).float()
            args = (hand, points, weight, nearest, depth, K)
            r, J = residuals(theta, *args), jacobian(theta, *args)
            JT = J.transpose(1, 2)
            delta, info = torch.linalg.solve_ex(JT @ J + s.damping * torch.eye(N_PARAMS), -(JT @ r[..., None])[..., 0])
            solved &= info == 0
            theta = theta + torch.where(solved[:, None], delta, torch.zeros_like(delta))
        fitted = vmap(_pose)(theta, hand).double().numpy()
        count = real.sum(1).numpy().astype(np.int64)
    use = (count >= s.min_points) & solved.numpy() & np.isfinite(fitted).all(axis=(1, 2))
    fitted = np.where(use[:, None, None], fitted, np.asarray(points3d[:, kp.HAND_SLICE], dtype=np.float64))
    out3d, out2d = np.array(points3d, dtype=np.float64), np.array(points2d, dtype=np.float64)
    out3d[:, kp.HAND_SLICE] = fitted
    out2d[:, kp.HAND_SLICE] = np.where(use[:, None, None], input_points2d(fitted, K_input, images.shape[-1]),
                                       out2d[:, kp.HAND_SLICE])
    return out2d, out3d, HandFit(count, use)
