"""The probe posed from the measured depth: a model's 8 box corners refined by a rigid fit of the probe's
surface to the depth input, and its half turn read from the orientation marker.

The depth input sees the probe's surface and the probe's shape is known (:mod:`hupbench.datagen.assets.probe`, its
signed distance), so a rigid fit of that shape to the measured points recovers the turn the image shows where a
network recalls the turns of its training grasps. The fit is a point-to-surface ICP (Besl and McKay, "A method
for registration of 3-D shapes", IEEE TPAMI 14(2), 1992; Chen and Medioni, "Object modelling by registration of
multiple range images", Image and Vision Computing 10(3), 1992) on the probe's signed distance, solved by
Gauss-Newton (Nocedal and Wright, "Numerical Optimization", 2nd ed., 2006, sec. 10.3), with trimmed residuals and
several starting turns because the probe is nearly symmetric about its long axis.

How, per frame, in the camera of the model input (``K_input``), with :class:`ProbeFitSettings` ``s``:
    1. The network's pose: the probe's box (:attr:`hupbench.datagen.assets.probe.Probe.corners_probe`) fitted to its
       8 corners (Kabsch, :func:`hupbench.metrics.fit_rigid_pose`), R0, t0.
    2. The measured points: every pixel with a surface, unprojected with its depth, within the probe's half
       diagonal + ``s.reach_m`` of the network's box centre; ``s.max_points`` of them in a fixed pseudo-random
       order (fingers, palm and arm are among them: the trimmed fit is robust to them).
    3. ``s.hypotheses`` turns of that pose about the probe's long axis (+z), each refined by ``s.iterations``
       Gauss-Newton steps of the points' signed distance to the probe (points farther than ``s.trim_m`` from
       the surface are left out: the hand) on ``s.coarse_points`` of the points, the best ``s.finalists`` again
       on all of them, and scored by the points on the surface (within ``s.inlier_m``) less
       ``s.inside_penalty`` times the points inside the probe (deeper than ``s.inside_m``), which no real
       surface can be. The best is the pose up to the probe's half turn: its shape is mirror-symmetric but
       for the marker.
    4. The half turn: at the marker's site of each of the two poses (the pose and its half turn), the pixel
       window where the measured depth agrees with the site's (``s.marker_depth_m``) is looked at. A site
       whose pixels have the marker's colour (its strongest channel ahead of the others by
       ``s.marker_chroma``) wins ("marker"); else a site that faces the camera, unoccluded, without that colour
       loses ("no marker"); else the network's own turn decides ("network").
    5. When fewer than ``s.min_inliers`` points lie on the surface of the best pose (no depth, or the probe
       hidden), the network's corners stay ("kept").

The corners out are the probe's box in the chosen pose: an exact rigid box. Their 2D points are its
projection with ``K_input``. The hand's keypoints are not touched.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from hupbench.core import keypoints as kp
from hupbench.core.rotations_torch import axis_angle_to_matrix
from hupbench.fits.depth_points import MIN_PROJECTION_Z_M, input_points2d, sample_points, unproject_depth
from hupbench.fits.settings import ProbeFitSettings
from hupbench.metrics import fit_rigid_pose

__all__ = ["DECISIONS", "ProbeFit", "ProbeFitSettings", "ProbeModel", "fit_probe", "probe_model"]

#: how each frame's probe was decided (:attr:`ProbeFit.decision` indexes this)
DECISIONS = ("kept", "marker", "no marker", "network")


@dataclass(frozen=True)
class ProbeFit:
    """What :func:`fit_probe` did, per frame: ``decision`` (B,) int64 indexing :data:`DECISIONS`, ``inliers``
    (B,) int64 measured points on the chosen pose's surface."""

    decision: np.ndarray
    inliers: np.ndarray


@dataclass(frozen=True)
class ProbeModel:
    """The probe as the fits use it (:func:`probe_model`)."""

    probe: Any                    # hupbench.datagen.assets.probe.Probe: its signed distance and gradient
    corners: torch.Tensor         # (8, 3) box corners, probe frame, metres
    marker: torch.Tensor          # (3,) the marker's centre, probe frame
    marker_normal: torch.Tensor   # (3,) its outward normal
    marker_channel: int           # the marker colour's strongest channel


@functools.lru_cache(maxsize=1)
def probe_model() -> ProbeModel:
    """The procedural probe as the fits use it (its signed distance, box, marker), built once per process; the
    probe's fit poses it and the hand's fit leaves its surface out."""
    from hupbench.datagen.assets.probe import build_probe
    from hupbench.datagen.render.scene import PROBE_MARKER_RGB

    probe = build_probe()
    mesh = probe.mesh
    marked = np.flatnonzero(probe.marker_face_mask)
    area = mesh.area_faces[marked]
    centre = (mesh.triangles_center[marked] * area[:, None]).sum(0) / area.sum()
    normal = (mesh.face_normals[marked] * area[:, None]).sum(0)
    as_t = lambda a: torch.tensor(np.array(a, dtype=np.float64), dtype=torch.float32)  # noqa: E731
    return ProbeModel(probe, as_t(probe.corners_probe), as_t(centre), as_t(normal / np.linalg.norm(normal)),
                       int(np.argmax(PROBE_MARKER_RGB)))


def _turn_z(angles: torch.Tensor) -> torch.Tensor:
    """(..., 3, 3) rotations by ``angles`` about +z."""
    c, s = torch.cos(angles), torch.sin(angles)
    zero, one = torch.zeros_like(c), torch.ones_like(c)
    return torch.stack([c, -s, zero, s, c, zero, zero, zero, one], dim=-1).reshape(*angles.shape, 3, 3)


def _measured_points(depth: torch.Tensor, K: torch.Tensor, centre: torch.Tensor, reach: float, max_points: int
                     ) -> tuple[torch.Tensor, torch.Tensor]:
    """(B, P, 3) camera-frame points of the depth map (B, S, S) within ``reach`` metres of ``centre`` (B, 3) and
    their (B, P) weights (1 real, 0 padding), P = ``max_points`` (fewer for a smaller map)."""
    points = unproject_depth(depth, K)
    near = (points[..., 2] > 0) & ((points - centre[:, None]).norm(dim=-1) < reach)
    return sample_points(points, near, max_points)


def _refine(model: ProbeModel, p: torch.Tensor, w_real: torch.Tensor, R: torch.Tensor, t: torch.Tensor,
            s: ProbeFitSettings) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Poses (N, 3, 3), (N, 3) refined by Gauss-Newton on the signed distance of points (N, P, 3) with weights
    (N, P): the poses, their scores (N,) and inliers (N,) (module docstring, step 3)."""
    for step in range(s.iterations):
        q = (p - t[:, None]) @ R                                                 # R^T (p - t), probe frame
        d, g = model.probe.signed_distance_and_gradient_torch(q)
        trim = s.trim_m[0] if step < s.iterations // 2 else s.trim_m[1]
        w = w_real * (d.abs() < trim).float()
        J = torch.cat([torch.cross(q, g, dim=-1), g], dim=-1)                   # (N, P, 6)
        A = (J * w[..., None]).transpose(1, 2) @ J + 1e-6 * w.sum(1).clamp_min(1.0)[:, None, None] * torch.eye(6)
        delta = torch.linalg.solve(A, -((J * (w * d)[..., None]).sum(1)))      # (N, 6)
        R = R @ axis_angle_to_matrix(delta[:, :3]).transpose(1, 2)
        t = t - (R @ delta[:, 3:, None]).squeeze(-1)
    d, _ = model.probe.signed_distance_and_gradient_torch((p - t[:, None]) @ R)
    inliers = (w_real * (d.abs() < s.inlier_m)).sum(1)
    return R, t, inliers - s.inside_penalty * (w_real * (d < -s.inside_m)).sum(1), inliers


def _marker_site(model: ProbeModel, rotation: torch.Tensor, translation: torch.Tensor, rgb: torch.Tensor,
                 depth: torch.Tensor, K: torch.Tensor, s: ProbeFitSettings
                 ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """For poses (B, 3, 3), (B, 3): (facing, seen, chroma), each (B,): the site's normal towards the camera
    (cosine), the share of its pixel window whose depth shows it, the marker colour's lead there."""
    B, _, S, _ = rgb.shape
    site = rotation @ model.marker + translation                                  # (B, 3)
    normal = rotation @ model.marker_normal
    facing = -(normal * site).sum(-1) / site.norm(dim=-1).clamp_min(1e-9)
    z = site[:, 2].clamp_min(MIN_PROJECTION_Z_M)
    u = torch.round(K[0, 0] * site[:, 0] / z + K[0, 2]).long()
    v = torch.round(K[1, 1] * site[:, 1] / z + K[1, 2]).long()
    r = s.marker_window
    offsets = torch.arange(-r, r + 1)
    cols = (u[:, None] + offsets).clamp(0, S - 1)                                 # (B, W)
    rows = (v[:, None] + offsets).clamp(0, S - 1)
    inside = ((u >= r) & (u < S - r) & (v >= r) & (v < S - r) & (site[:, 2] > MIN_PROJECTION_Z_M)).float()
    index = torch.arange(B)[:, None, None]
    window_depth = depth[index, rows[:, :, None], cols[:, None, :]]               # (B, W, W)
    window_rgb = rgb.permute(0, 2, 3, 1)[index, rows[:, :, None], cols[:, None, :]]  # (B, W, W, 3)
    shows = (window_depth - site[:, 2, None, None]).abs() < s.marker_depth_m
    c = model.marker_channel
    others = torch.cat([window_rgb[..., :c], window_rgb[..., c + 1:]], dim=-1).amax(-1)
    lead = torch.where(shows, window_rgb[..., c] - others, torch.full_like(others, -1.0))
    return facing, shows.float().mean(dim=(1, 2)) * inside, lead.amax(dim=(1, 2)) * inside


def fit_probe(points2d: np.ndarray, points3d: np.ndarray, images: np.ndarray, K_input: np.ndarray,
              settings: ProbeFitSettings = ProbeFitSettings()) -> tuple[np.ndarray, np.ndarray, ProbeFit]:
    """The probe's corners of a model's output refined against its depth input (module docstring).

    Args:
        points2d: (B, 29, 2) float, normalised input coordinates, and points3d: (B, 29, 3) float, metres, camera
            frame of ``K_input``: the model's output.
        images: (B, 4, S, S) float32 model images: RGB in [0, 1], then the depth channel (metres, 0 = none).
        K_input: (3, 3) intrinsics of the model input, pixels.
        settings: the fit's tuning values (:class:`ProbeFitSettings`).

    Returns:
        (points2d (B, 29, 2), points3d (B, 29, 3)) float64 with the 8 corners replaced where the fit holds,
        and :class:`ProbeFit`.
    """
    assert images.ndim == 4 and images.shape[1] == 4, images.shape
    assert points3d.shape == (len(images), kp.NUM_KEYPOINTS, 3), points3d.shape
    model, s = probe_model(), settings
    # no_grad, not inference_mode: the probe caches its signed distance grid as tensors on first use, and
    # inference tensors in that cache would break the grasp refinement's autograd later in the same process
    with torch.no_grad():
        K = torch.as_tensor(np.asarray(K_input, dtype=np.float64), dtype=torch.float32)
        rgb = torch.as_tensor(images[:, :3], dtype=torch.float32)
        depth = torch.as_tensor(images[:, 3], dtype=torch.float32)
        corners = np.asarray(points3d[:, kp.CORNER_SLICE], dtype=np.float64)
        B = len(images)
        network = torch.as_tensor(fit_rigid_pose(model.corners.double().numpy(), corners), dtype=torch.float32)
        R0, t0 = network[:, :3, :3], network[:, :3, 3]                            # the network's pose
        box_centre = model.corners.mean(0)
        reach = float((model.corners - box_centre).norm(dim=-1).max()) + s.reach_m
        points, weight = _measured_points(depth, K, box_centre @ R0.transpose(1, 2) + t0, reach, s.max_points)

        # every turn refined on a few points, the best again on all of them
        H, F = s.hypotheses, s.finalists
        angles = torch.arange(H, dtype=torch.float32) * (2 * np.pi / H)
        R = (R0[:, None] @ _turn_z(angles)).reshape(B * H, 3, 3)
        t = t0.repeat_interleave(H, dim=0)
        few = s.coarse_points
        R, t, score, _ = _refine(model, points[:, :few].repeat_interleave(H, dim=0),
                                 weight[:, :few].repeat_interleave(H, dim=0), R, t, s)
        top = score.reshape(B, H).topk(F, dim=1).indices + torch.arange(B)[:, None] * H    # (B, F)
        R, t = R[top.reshape(-1)], t[top.reshape(-1)]
        R, t, score, inliers = _refine(model, points.repeat_interleave(F, dim=0), weight.repeat_interleave(F, dim=0),
                                       R, t, s)
        pick = torch.arange(B) * F + score.reshape(B, F).argmax(dim=1)
        RA, tA, inliers = R[pick], t[pick], inliers[pick].long()
        RB = RA @ _turn_z(torch.tensor(np.pi, dtype=torch.float32))

        facing_a, seen_a, lead_a = _marker_site(model, RA, tA, rgb, depth, K, s)
        facing_b, seen_b, lead_b = _marker_site(model, RB, tA, rgb, depth, K, s)
        turn = R0.transpose(1, 2) @ RA                                             # the fit relative to the network
        network_a = torch.atan2(turn[:, 1, 0], turn[:, 0, 0]).abs() <= np.pi / 2
        marker = torch.maximum(lead_a, lead_b) > s.marker_chroma
        absent_a = (facing_a > s.marker_facing) & (seen_a > s.marker_seen)
        absent_b = (facing_b > s.marker_facing) & (seen_b > s.marker_seen)
        choose_a = torch.where(marker, lead_a >= lead_b,
                               torch.where(absent_a, False, torch.where(absent_b, True, network_a)))
        decision = torch.where(marker, 1, torch.where(absent_a | absent_b, 2, 3))
        kept = inliers < s.min_inliers
        decision = torch.where(kept, 0, decision)
        rotation = torch.where(choose_a[:, None, None], RA, RB)
        fitted = model.corners @ rotation.transpose(1, 2) + tA[:, None]
        fitted = fitted.double().numpy()
    use = ~kept.numpy()
    out3d, out2d = np.array(points3d, dtype=np.float64), np.array(points2d, dtype=np.float64)
    out3d[use, kp.CORNER_SLICE] = fitted[use]
    out2d[use, kp.CORNER_SLICE] = input_points2d(fitted[use], K_input, images.shape[-1])
    return out2d, out3d, ProbeFit(decision.numpy().astype(np.int64), inliers.numpy().astype(np.int64))
