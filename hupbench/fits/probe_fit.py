"""The probe posed from the measured depth: a model's 8 box corners refined by a rigid fit of the probe's
surface to the depth input, and its half turn read from the orientation marker.

The depth input sees the probe's surface and the probe's shape is known (:class:`hupbench.fits.known_probe.FitProbe`:
the generator's probe, or the one a model file carries, its signed distance), so a rigid fit of that shape to the
measured points recovers the turn the image shows where a network recalls the turns of its training grasps. The
fit is a point-to-surface ICP (Besl and McKay, "A method for registration of 3-D shapes", IEEE TPAMI 14(2), 1992;
Chen and Medioni, "Object modelling by registration of multiple range images", Image and Vision Computing 10(3),
1992) on the probe's signed distance, solved by
Gauss-Newton (Nocedal and Wright, "Numerical Optimization", 2nd ed., 2006, sec. 10.3), with trimmed residuals and
several starting turns because the probe is nearly symmetric about its long axis.

Numpy only: ``hupbench predict`` runs it without torch.

How, per frame, in the camera of the model input (``K_input``), with :class:`ProbeFitSettings` ``s``:
    1. The network's pose: the probe's box (:attr:`FitProbe.corners`) fitted to its
       8 corners (Kabsch, :func:`hupbench.core.geometry.fit_rigid_pose`), R0, t0.
    2. The measured points: every pixel with a surface, unprojected with its depth, within the probe's half
       diagonal + ``s.reach_m`` of the network's box centre (and, given a segmentation, among its probe pixels);
       ``s.max_points`` of them in a fixed pseudo-random order (without a segmentation fingers, palm, arm and skin
       are among them: the trimmed fit is robust to a few of them).
    3. ``s.hypotheses`` turns of that pose about the probe's long axis (+z), each refined by ``s.iterations``
       Gauss-Newton steps of the points' signed distance to the probe (points farther than ``s.trim_m`` from
       the surface are left out: the hand) on ``s.coarse_points`` of the points, the best ``s.finalists`` again
       on all of them, and scored by the points on the surface (within ``s.inlier_m``) less
       ``s.inside_penalty`` times the points inside the probe (deeper than ``s.inside_m``), which no real
       surface can be. The best is the pose up to the probe's half turn: its shape is mirror-symmetric but
       for the marker.
    4. The half turn: at the marker's site of each of the two poses (the pose and its half turn), the pixel
       window where the measured depth agrees with the site's (``s.marker_depth_m``), and, given a segmentation,
       its probe pixels without depth (a time-of-flight camera returns none from much of the dark plastic), is
       looked at. A site
       whose pixels have the marker's colour (its strongest channel ahead of the others by
       ``s.marker_chroma``) wins ("marker"); else, given a segmentation, where at least ``s.marker_pixels`` of its
       probe pixels anywhere have the marker's colour (ahead by ``s.marker_pixel_chroma``), the pose whose site
       projects nearer their centre wins ("marker pixels": the marker seen beside its site, where the pose is off
       by a few pixels or the site is edge-on); else a site that faces the camera, unoccluded, without that colour
       loses ("no marker"; where both sites do, the one facing it more loses: the marker's normal leans along the
       long axis, so both turns' sites can face the camera); else the network's own turn decides ("network").
       Without a segmentation, the probe's pixels of a fitted frame are those whose measured point lies within
       ``s.marker_surface_m`` of the fitted surface, read for the marker's pixels as a segmentation's; where none of
       them has its colour (and no site decides), the marker is on the side the camera does not see: the turn whose
       site faces away from the camera wins ("marker hidden") where the two sites' facings differ by more than
       ``s.marker_hidden_margin`` and at least ``s.marker_seen`` of the window of the site facing the camera has
       depth (else the network's turn: a sensor without depth there may have missed the marker). Given a
       segmentation and ``s.marker_under_hand``, where neither site nor the marker's pixels decide (the site facing
       the camera hidden, most often by the fingers), the marker is taken to be under the hand: the turn whose site
       faces the camera more wins ("marker under hand").
    5. When fewer than ``s.min_inliers`` points lie on the surface of the best pose (no depth, or the probe
       hidden), the network's corners stay ("kept"); a frame with fewer measured points than that skips step 3.
       Given a segmentation whose probe pixels show the marker's colour (step 4), such a frame takes the network's
       box (its corners' Kabsch pose) turned about its long axis, in steps of ``s.marker_roll_deg``, to the roll
       whose marker site faces the camera and projects nearest those pixels' centre, then moved across the view (at
       the site's depth) until the site projects there ("kept, marker pixels"): the network's roll is its largest
       error where a time-of-flight camera gives no depth on the probe, and the marker's pixels read it. So does a
       fitted frame, given a segmentation, whose marker's pixels lie farther than ``s.marker_reroll_px`` from both
       turns' sites (decision "marker pixels"): its depth's roll is wrong there (76 degrees off, median, modulo the
       half turn, on the clinic val frames whose half turn those pixels lost, docs/clinic.md).

Tracking a video (``start``, the frame before's :attr:`ProbeFit.pose`): a frame whose frame before was fitted takes
its points around that pose (step 2); that pose and the network's are each refined by ``s.tracking_iterations`` steps
on all the points and the better scored is kept, instead of step 3's search over turns; and where the marker does
not decide (step 4: the sites' windows; the marker's pixels elsewhere are not read), the half turn nearer the
frame before's stays ("previous").

The corners out are the probe's box in the chosen pose: an exact rigid box. Their 2D points are its
projection with ``K_input``. The hand's keypoints are not touched.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hupbench.core import keypoints as kp
from hupbench.core.geometry import axis_angle_to_matrix, fit_rigid_pose
from hupbench.core.processes import one_blas_thread
from hupbench.fits.depth_points import (MIN_PROJECTION_Z_M, input_pixels, input_points2d, sample_points,
                                        surface_pixels, unproject_pixels, unproject_uv)
from hupbench.fits.known_probe import FitProbe, default_fit_probe
from hupbench.fits.settings import ProbeFitSettings

__all__ = ["DECISIONS", "ProbeFit", "ProbeFitSettings", "fit_probe"]

#: how each frame's probe was decided (:attr:`ProbeFit.decision` indexes this)
DECISIONS = ("kept", "marker", "no marker", "network", "previous", "marker pixels", "kept, marker pixels",
             "marker hidden", "marker under hand")


@dataclass(frozen=True)
class ProbeFit:
    """What :func:`fit_probe` did, per frame: ``decision`` (B,) int64 indexing :data:`DECISIONS`, ``inliers``
    (B,) int64 measured points on the chosen pose's surface (a frame with fewer measured points than ``min_inliers``
    is not refined: its measured points), ``pose`` (B, 4, 4) float64 the fitted probe's pose
    (probe frame to camera; NaN where the network's corners were kept): the next frame's ``start``."""

    decision: np.ndarray
    inliers: np.ndarray
    pose: np.ndarray


#: each axis's next and the one after (y z x, z x y): a x b = a[_NEXT] b[_AFTER] - a[_AFTER] b[_NEXT] (numpy's cross
#: takes several times as long on these small arrays)
_NEXT, _AFTER = [1, 2, 0], [2, 0, 1]


def _turn_z(angles: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotations by ``angles`` about +z."""
    c, s = np.cos(angles), np.sin(angles)
    zero, one = np.zeros_like(c), np.ones_like(c)
    return np.stack([c, -s, zero, s, c, zero, zero, zero, one], axis=-1).reshape(*np.shape(angles), 3, 3)


def _refine(probe: FitProbe, p: np.ndarray, w_real: np.ndarray, R: np.ndarray, t: np.ndarray, s: ProbeFitSettings,
            iterations: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Poses (N, 3, 3), (N, 3) refined by ``iterations`` Gauss-Newton steps on the signed distance of points (N, P, 3)
    with weights (N, P): the poses, their scores (N,) and inliers (N,) (module docstring, step 3)."""
    for step in range(iterations):
        q = (p - t[:, None]) @ R                                                # R^T (p - t), probe frame
        d, g = probe.signed_distance_and_gradient(q)
        trim = s.trim_m[0] if step < iterations // 2 else s.trim_m[1]
        w = w_real * (np.abs(d) < trim)
        J = np.concatenate([q[..., _NEXT] * g[..., _AFTER] - q[..., _AFTER] * g[..., _NEXT], g], axis=-1)  # q x g, g
        A = J.swapaxes(1, 2) @ (J * w[..., None]) + 1e-6 * np.maximum(w.sum(1), 1.0)[:, None, None] * np.eye(6)
        delta = np.linalg.solve(A, -(J.swapaxes(1, 2) @ (w * d)[..., None]))[..., 0]   # (N, 6)
        R = R @ axis_angle_to_matrix(delta[:, :3]).transpose(0, 2, 1)
        t = t - (R @ delta[:, 3:, None])[..., 0]
    d, _ = probe.signed_distance_and_gradient((p - t[:, None]) @ R)
    inliers = (w_real * (np.abs(d) < s.inlier_m)).sum(1)
    return R, t, inliers - s.inside_penalty * (w_real * (d < -s.inside_m)).sum(1), inliers


def _search(probe: FitProbe, points: np.ndarray, weight: np.ndarray, R0: np.ndarray, t0: np.ndarray,
            s: ProbeFitSettings) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The best pose (B, 3, 3), (B, 3) and its inliers (B,) among ``s.hypotheses`` turns of the network's poses R0, t0
    about the probe's long axis: every turn refined on ``s.coarse_points`` of the points (B, P, 3) with weights
    (B, P), the best ``s.finalists`` again on all of them (module docstring, step 3)."""
    B, H, F = len(points), s.hypotheses, s.finalists
    angles = np.arange(H) * (2 * np.pi / H)
    R = (R0[:, None] @ _turn_z(angles)).reshape(B * H, 3, 3)
    t = np.repeat(t0, H, axis=0)
    few = s.coarse_points
    R, t, score, _ = _refine(probe, np.repeat(points[:, :few], H, axis=0), np.repeat(weight[:, :few], H, axis=0),
                             R, t, s, s.iterations)
    top = np.argsort(-score.reshape(B, H), axis=1, kind="stable")[:, :F] + np.arange(B)[:, None] * H   # (B, F)
    R, t = R[top.reshape(-1)], t[top.reshape(-1)]
    R, t, score, inliers = _refine(probe, np.repeat(points, F, axis=0), np.repeat(weight, F, axis=0), R, t, s,
                                   s.iterations)
    pick = np.arange(B) * F + score.reshape(B, F).argmax(axis=1)
    return R[pick], t[pick], inliers[pick].astype(np.int64)


def _near_points(probe: FitProbe, depth: np.ndarray, K: np.ndarray, own: np.ndarray | None, R: np.ndarray,
                 t: np.ndarray, s: ProbeFitSettings) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The measured points around the poses (B, 3, 3), (B, 3) (module docstring, step 2): (near (B, S * S) bool, the
    pixels within the probe's half diagonal + ``s.reach_m`` of the pose's box centre, among ``own`` where given;
    points (B, P, 3) and weights (B, P), :func:`hupbench.fits.depth_points.sample_points` of them)."""
    box_centre = probe.corners.mean(0)
    reach = float(np.linalg.norm(probe.corners - box_centre, axis=-1).max()) + s.reach_m
    centre = box_centre @ R.transpose(0, 2, 1) + t                                # (B, 3)
    near = surface_pixels(depth, own)
    for b, where in enumerate(near):
        cand = np.flatnonzero(where)
        where[cand] = np.linalg.norm(unproject_pixels(depth[b], K, cand) - centre[b], axis=-1) < reach
    points, weight = sample_points(depth, K, near, s.max_points)
    return near, points, weight


def _track(probe: FitProbe, points: np.ndarray, weight: np.ndarray, R_before: np.ndarray, t_before: np.ndarray,
           R0: np.ndarray, t0: np.ndarray, s: ProbeFitSettings) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Tracked frames' poses (N, 3, 3), (N, 3) and inliers (N,): the frame before's pose and the network's, each
    refined by ``s.tracking_iterations`` steps on all the points (N, P, 3) with weights (N, P), the better scored."""
    R = np.stack([R_before, R0], axis=1).reshape(-1, 3, 3)
    t = np.stack([t_before, t0], axis=1).reshape(-1, 3)
    R, t, score, inliers = _refine(probe, np.repeat(points, 2, axis=0), np.repeat(weight, 2, axis=0), R, t, s,
                                   s.tracking_iterations)
    pick = np.arange(len(points)) * 2 + score.reshape(-1, 2).argmax(axis=1)
    return R[pick], t[pick], inliers[pick]


def _site(probe: FitProbe, rotation: np.ndarray, translation: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The marker's site (..., 3), camera frame, metres, of poses (..., 3, 3), (..., 3), and how it faces the camera
    (...): the cosine between its normal and the way from it to the camera."""
    site = rotation @ probe.marker + translation
    normal = rotation @ probe.marker_normal
    return site, -(normal * site).sum(-1) / np.maximum(np.linalg.norm(site, axis=-1), 1e-9)


def _marker_site(probe: FitProbe, rotation: np.ndarray, translation: np.ndarray, rgb: np.ndarray, depth: np.ndarray,
                 K: np.ndarray, s: ProbeFitSettings, pixels: np.ndarray | None = None
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """For poses (B, 3, 3), (B, 3): (facing, seen, chroma, measured), each (B,): the site's normal towards the camera
    (cosine), the share of its pixel window that shows it (its depth agrees with the site's; or, given the probe's
    ``pixels`` (B, S, S) bool, it has no depth and is the probe's), the marker colour's lead there, the share of the
    window with any depth."""
    B, _, S, _ = rgb.shape
    site, facing = _site(probe, rotation, translation)                            # (B, 3), (B,)
    u, v = np.round(input_pixels(site, K)).T
    r = s.marker_window
    inside = ((u >= r) & (u < S - r) & (v >= r) & (v < S - r) & (site[:, 2] > MIN_PROJECTION_Z_M)).astype(float)
    u, v = np.clip(u, -S, 2 * S).astype(np.int64), np.clip(v, -S, 2 * S).astype(np.int64)
    offsets = np.arange(-r, r + 1)
    cols = np.clip(u[:, None] + offsets, 0, S - 1)                                # (B, W)
    rows = np.clip(v[:, None] + offsets, 0, S - 1)
    index = np.arange(B)[:, None, None]
    window_depth = depth[index, rows[:, :, None], cols[:, None, :]]               # (B, W, W)
    window_rgb = rgb.transpose(0, 2, 3, 1)[index, rows[:, :, None], cols[:, None, :]]  # (B, W, W, 3)
    shows = np.abs(window_depth - site[:, 2, None, None]) < s.marker_depth_m
    if pixels is not None:   # a sensor without depth on the probe's dark plastic: its pixels show the probe
        shows |= (window_depth <= 0) & pixels[index, rows[:, :, None], cols[:, None, :]]
    lead = np.where(shows, probe.marker_lead(window_rgb), -1.0)
    return (facing, shows.mean(axis=(1, 2)) * inside, lead.max(axis=(1, 2)) * inside,
            (window_depth > 0).mean(axis=(1, 2)) * inside)


def _marker_pixels(probe: FitProbe, rgb: np.ndarray, pixels: np.ndarray, s: ProbeFitSettings
                   ) -> tuple[np.ndarray, np.ndarray]:
    """(found (B,) bool, centre (B, 2) pixels u, v): whether at least ``s.marker_pixels`` of the probe's ``pixels``
    (B, S, S) have the marker's colour (its channel ahead of the others by ``s.marker_pixel_chroma`` in ``rgb``
    (B, 3, S, S)), and the centre of those pixels (module docstring, step 4)."""
    coloured = (probe.marker_lead(rgb, axis=1) > s.marker_pixel_chroma) & pixels   # (B, S, S)
    count = coloured.sum(axis=(1, 2))
    centre = np.stack([coloured.sum(axis=1) @ np.arange(rgb.shape[-1]),
                       coloured.sum(axis=2) @ np.arange(rgb.shape[-2])], -1) / np.maximum(count, 1)[:, None]   # u, v
    return count >= s.marker_pixels, centre


def _on_surface(probe: FitProbe, depth: np.ndarray, K: np.ndarray, near: np.ndarray, R: np.ndarray, t: np.ndarray,
                fitted: np.ndarray, s: ProbeFitSettings) -> np.ndarray:
    """(B, S, S) bool: the ``near`` pixels (B, S * S) whose measured point lies within ``s.marker_surface_m`` of the
    surface of the poses (B, 3, 3), (B, 3), for the ``fitted`` frames (B,) bool; none for the others (step 4)."""
    out = np.zeros_like(near)
    for b in np.flatnonzero(fitted):
        cand = np.flatnonzero(near[b])
        distance, _ = probe.signed_distance_and_gradient(((unproject_pixels(depth[b], K, cand) - t[b]) @ R[b])[None])
        out[b, cand[np.abs(distance[0]) < s.marker_surface_m]] = True
    return out.reshape(depth.shape)


def _roll_to_marker(probe: FitProbe, R: np.ndarray, t: np.ndarray, centre: np.ndarray, K: np.ndarray,
                    s: ProbeFitSettings) -> tuple[np.ndarray, np.ndarray]:
    """Poses (N, 3, 3), (N, 3) turned about their long axis to the roll, in steps of ``s.marker_roll_deg``, whose
    marker site faces the camera and projects nearest ``centre`` (N, 2) (a site facing away only where none faces
    it), then moved across the view at the site's depth until it projects on ``centre`` (module docstring, step 5)."""
    turns = _turn_z(np.radians(np.arange(0.0, 360.0, s.marker_roll_deg)))        # (A, 3, 3)
    Rs = R[:, None] @ turns                                                      # (N, A, 3, 3)
    sites, facing = _site(probe, Rs, t[:, None])                                 # (N, A, 3), (N, A)
    far = np.linalg.norm(input_pixels(sites, K) - centre[:, None], axis=-1) + np.where(facing <= 0, 1e9, 0.0)
    pick = far.argmin(axis=1)                                                    # pixels, a site facing away last
    rows = np.arange(len(R))
    R, site = Rs[rows, pick], sites[rows, pick]
    return R, t + unproject_uv(centre[:, 0], centre[:, 1], site[:, 2], K) - site


def _read_marker_pixels(probe: FitProbe, R: np.ndarray, t: np.ndarray, centre: np.ndarray, found: np.ndarray,
                        kept: np.ndarray, K: np.ndarray, s: ProbeFitSettings) -> tuple[np.ndarray, np.ndarray]:
    """Where the marker's pixels centred on ``centre`` (B, 2) were ``found`` (B,) bool, the poses (B, 3, 3), (B, 3)
    (changed in place) of ``kept`` frames, and of fitted ones whose sites (the pose's and its half turn's) both lie
    farther than ``s.marker_reroll_px`` from ``centre``, turned to the roll those pixels read (step 5,
    :func:`_roll_to_marker`): (rolled (B,) bool, (B,) bool whether the pose's site lies nearer ``centre`` than its half
    turn's)."""

    def to_pixels() -> np.ndarray:   # (B, 2) pixels from the centre to the sites of the poses and their half turns
        sites, _ = _site(probe, np.stack([R, R @ _turn_z(np.pi)], axis=1), t[:, None])   # (B, 2, 3)
        return np.linalg.norm(input_pixels(sites, K) - centre[:, None], axis=-1)

    roll = found & (kept | (to_pixels().min(axis=1) > s.marker_reroll_px))
    if roll.any():
        R[roll], t[roll] = _roll_to_marker(probe, R[roll], t[roll], centre[roll], K, s)
    return roll, np.less_equal(*to_pixels().T)


@one_blas_thread()
def fit_probe(points2d: np.ndarray, points3d: np.ndarray, images: np.ndarray, K_input: np.ndarray,
              settings: ProbeFitSettings = ProbeFitSettings(), probe: FitProbe | None = None,
              pixels: np.ndarray | None = None, start: np.ndarray | None = None
              ) -> tuple[np.ndarray, np.ndarray, ProbeFit]:
    """The probe's corners of a model's output refined against its depth input (module docstring).

    Args:
        points2d: (B, 29, 2) float, normalised input coordinates, and points3d: (B, 29, 3) float, metres, camera
            frame of ``K_input``: the model's output.
        images: (B, 4, S, S) float32 model images: RGB in [0, 1], then the depth channel (metres, 0 = none).
        K_input: (3, 3) intrinsics of the model input, pixels.
        settings: the fit's tuning values (:class:`ProbeFitSettings`).
        probe: the probe to fit (None: the default procedural probe, :func:`default_fit_probe`).
        pixels: (B, S, S) bool, the pixels that may be the probe's (a segmentation's, :func:`hupbench.fits.
            after_network`); a measured point elsewhere (the hand, the patient's skin) is left out. None: any pixel.
        start: (B, 4, 4) float, the probe's fitted pose in the frame before (:attr:`ProbeFit.pose`), tracking a
            video: a frame with one (finite) takes its measured points around it, refines it and the network's
            pose by ``settings.tracking_iterations`` steps on all of them instead of the search over turns (step 3),
            and, where the marker does not decide, keeps the half turn nearest it ("previous"). None or NaN rows:
            the search.

    Returns:
        (points2d (B, 29, 2), points3d (B, 29, 3)) float64 with the 8 corners replaced where the fit holds,
        and :class:`ProbeFit`.
    """
    assert images.ndim == 4 and images.shape[1] == 4, images.shape
    assert points3d.shape == (len(images), kp.NUM_KEYPOINTS, 3), points3d.shape
    probe, s = probe or default_fit_probe(), settings
    K, B = np.asarray(K_input, dtype=np.float64), len(images)
    rgb, depth = np.asarray(images[:, :3], np.float64), np.asarray(images[:, 3], np.float64)
    network = fit_rigid_pose(probe.corners, np.asarray(points3d[:, kp.CORNER_SLICE], dtype=np.float64))
    R0, t0 = network[:, :3, :3], network[:, :3, 3]                                # the network's pose
    warm = np.zeros(B, bool) if start is None else np.isfinite(start).all(axis=(1, 2))
    # where a frame's points are taken, and the turn it keeps where the marker does not decide: the frame before's
    # pose, else the network's
    reference = network if start is None else np.where(warm[:, None, None], start, network)
    R_ref, t_ref = reference[:, :3, :3], reference[:, :3, 3]
    own = None if pixels is None else np.asarray(pixels, dtype=bool)
    near, points, weight = _near_points(probe, depth, K, own, R_ref, t_ref, s)

    # fewer measured points than min_inliers cannot put that many on any pose's surface: kept (step 5) unrefined
    inliers = weight.sum(1).astype(np.int64)
    enough = inliers >= s.min_inliers
    RA, tA = R0.copy(), t0.copy()
    cold, tracked = ~warm & enough, warm & enough
    if cold.any():
        RA[cold], tA[cold], inliers[cold] = _search(probe, points[cold], weight[cold], R0[cold], t0[cold], s)
    if tracked.any():
        RA[tracked], tA[tracked], inliers[tracked] = _track(probe, points[tracked], weight[tracked], R_ref[tracked],
                                                            t_ref[tracked], R0[tracked], t0[tracked], s)
    kept = inliers < s.min_inliers
    # the probe's pixels (a segmentation's, else the fitted surface's), the marker's colour anywhere among them, read
    # against the fitted pose (its turn), or for a kept frame against the network's (its roll, step 5); a frame
    # tracked keeps the frame before's turn instead
    if own is not None and probe.has_marker:
        RA, tA = np.where(kept[:, None, None], R0, RA), np.where(kept[:, None], t0, tA)
    on_surface = own is None and probe.has_marker and s.marker_surface_m > 0
    read = _on_surface(probe, depth, K, near, RA, tA, ~kept & ~warm, s) if on_surface else own
    found, seen_at = np.zeros(B, bool), np.zeros((B, 2))
    if read is not None and probe.has_marker:
        found, seen_at = _marker_pixels(probe, rgb, read, s)
    found &= ~warm
    hidden = on_surface & ~kept & ~warm & ~found   # the visible surface shows no marker: its site faces away
    # the kept frames, and given a segmentation the fitted ones, that the marker's pixels turn (step 5)
    roll, pixel_a = _read_marker_pixels(probe, RA, tA, seen_at, found if own is not None else found & kept, kept, K, s)
    RB = RA @ _turn_z(np.pi)

    facing_a, seen_a, lead_a, measured_a = _marker_site(probe, RA, tA, rgb, depth, K, s, own)
    facing_b, seen_b, lead_b, measured_b = _marker_site(probe, RB, tA, rgb, depth, K, s, own)
    # edge-on sites: their facing tells nothing; a window without depth at the site facing the camera: the sensor
    # may have missed the marker there (a time-of-flight camera on coloured plastic)
    hidden &= ((np.abs(facing_a - facing_b) > s.marker_hidden_margin)
               & (np.where(facing_a > facing_b, measured_a, measured_b) >= s.marker_seen))
    turn = R_ref.transpose(0, 2, 1) @ RA                      # the fit relative to the network (or the frame before)
    network_a = np.abs(np.arctan2(turn[:, 1, 0], turn[:, 0, 0])) <= np.pi / 2
    # a probe without a marker: neither site decides, the network's (or the frame before's) turn does
    marker = (np.maximum(lead_a, lead_b) > s.marker_chroma) & probe.has_marker
    absent_a = (facing_a > s.marker_facing) & (seen_a > s.marker_seen) & probe.has_marker
    absent_b = (facing_b > s.marker_facing) & (seen_b > s.marker_seen) & probe.has_marker
    # given a segmentation, where neither site nor the marker's pixels decide: the marker under the hand, facing
    under = ~warm & (own is not None and probe.has_marker and s.marker_under_hand)
    choose_a = roll | np.where(marker, lead_a >= lead_b, np.where(found, pixel_a, np.where(
        absent_a | absent_b, np.where(absent_a & absent_b, facing_a < facing_b, absent_b), np.where(
            hidden, facing_a <= facing_b, np.where(under, facing_a >= facing_b, network_a)))))
    decision = np.where(marker, 1, np.where(found, 5, np.where(absent_a | absent_b, 2, np.where(
        warm, 4, np.where(hidden, 7, np.where(under, 8, 3))))))
    decision = np.where(kept, np.where(found, 6, 0), np.where(roll, 5, decision)).astype(np.int64)
    rotation = np.where(choose_a[:, None, None], RA, RB)
    fitted = probe.corners @ rotation.transpose(0, 2, 1) + tA[:, None]
    use = ~kept | found       # a kept frame whose marker shows: the network's box, in the turn the marker reads
    out3d, out2d = np.array(points3d, dtype=np.float64), np.array(points2d, dtype=np.float64)
    out3d[use, kp.CORNER_SLICE] = fitted[use]
    out2d[use, kp.CORNER_SLICE] = input_points2d(fitted[use], K_input, images.shape[-1])
    pose = np.full((B, 4, 4), np.nan)
    posed = ~kept             # a kept frame's box was not fitted: no start for the next frame
    pose[posed, :3, :3], pose[posed, :3, 3], pose[posed, 3] = rotation[posed], tA[posed], (0.0, 0.0, 0.0, 1.0)
    return out2d, out3d, ProbeFit(decision, inliers, pose)
