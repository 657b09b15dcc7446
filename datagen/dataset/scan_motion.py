"""A scan over time: the probe sweeping, rocking and fanning on the patient's skin, its lens in contact throughout.

A sonographer moves the probe over the abdomen: sliding it over the skin (sweep), tilting it in the image plane
(rock) and across it (fan), with the slow moves of the search, the quicker corrections of aiming, and the
hand's physiological tremor. :func:`scan_motion` makes one clip of that motion for a grasp's patient placement
(:mod:`hupbench.datagen.assets.patient`):

1. **How fast.** Each clip draws a skill between a consultant's and a fellow's and the probe's mean speed,
   acceleration and jerk around the figures measured for that skill (:data:`SKILL_KINEMATICS`).
2. **The moves.** Four channels, the sweep along the probe's array (x) and across it (y) as arc lengths on
   the skin, rock (about the probe's y axis) and fan (about its x axis) as angles about the lens apex, are
   each a sum of sinusoids in three bands of frequency (:data:`BANDS_HZ`): the search (slow), aiming
   corrections (about 1-3 Hz) and tremor (8-12 Hz). Each band's gain is one number for all channels.
3. **On the skin.** The abdomen's cap is a sphere (``placement.radius_m``): a sweep rotates the probe about
   the sphere's centre, which keeps its apex on the skin; a tilt turns it about its apex. After both, the
   probe moves along the skin's normal until its deepest lens vertex is ``press_m`` inside the skin, as
   :func:`hupbench.datagen.assets.patient.place_patient` set it: the lens stays in contact in every sample.
4. **Matching the draw.** The motion is sampled at :data:`OVERSAMPLE` times the clip's frame rate; the
   three gains are scaled until the probe centre's mean speed, acceleration and jerk relative to the patient
   (and to the room, fixed to the bed; finite differences at
   that rate, :func:`hupbench.core.motion_metrics.point_kinematics`) match the drawn ones within
   :data:`CALIBRATION_RTOL` (each band mostly sets one of them: the search the speed, the corrections the
   acceleration, the tremor the jerk). Kinematics the drawn moves cannot meet (e.g. a jerk whose tremor
   alone would exceed the drawn acceleration) or moves that would tilt the probe beyond ``max_tilt_deg``
   are drawn again, kinematics and moves together: a clip's kinematics are the draw of step 1 conditioned
   on the moves reaching them. So are moves that, in some frame, sink a probe vertex deeper than the placement
   allows (``PROBE_MAX_DEPTH_M``) or the hand or forearm into the body or the bed (``MAX_PENETRATION_M``).

The hand holds the probe as in its grasp, so it moves with the probe; the world (probe) frame of the grasp
stays the world of every frame, and the patient (with the bed and room fixed to it) moves in it.

Convention:
    Metres, seconds, radians inside; mm/s^n in the kinematics records. World = the probe frame of
    :mod:`hupbench.datagen.assets.probe`; body frame and ``T_world_body`` as in
    :mod:`hupbench.datagen.assets.patient`. The probe's centre is the centre of its box (keypoints 21-28).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from hupbench.core.errors import RunFailedError
from hupbench.core.geometry import axis_angle_to_matrix, invert_transform
from hupbench.core.input_checks import check_interval, check_number
from hupbench.core.motion_metrics import KINEMATICS_KEYS, point_kinematics, time_derivatives
from hupbench.datagen.assets.patient import (MAX_PENETRATION_M, PROBE_MAX_DEPTH_M, PatientPlacement, below_skin,
                                             body_sdf_local, sphere_centre)

__all__ = ["BANDS_HZ", "OVERSAMPLE", "SKILL_KINEMATICS", "ScanMotion", "ScanMotionSpec", "band_noise", "clip_frames",
           "draw_kinematics", "scan_motion"]

#: the probe's mean speed (mm/s), acceleration (mm/s^2) and jerk (mm/s^3) during obstetric anomaly scans, mean
#: and standard deviation over operators, of consultants and of fellows (Le Lous et al. 2024, probe motion
#: measured over 17 second- and third-trimester anomaly scans); the jerk's deviation is not among the figures
#: cited here: it is drawn with the acceleration's coefficient of variation
SKILL_KINEMATICS = {
    "consultant": {"speed_mm_per_s": (12.9, 3.4), "acceleration_mm_per_s2": (170.0, 26.0),
                   "jerk_mm_per_s3": (7492.0, None)},
    "fellow": {"speed_mm_per_s": (24.6, 5.7), "acceleration_mm_per_s2": (329.0, 63.0),
               "jerk_mm_per_s3": (14944.0, None)},
}
#: the frequency bands of the moves, Hz: the search, the aiming corrections, and the physiological tremor of
#: the hand (8-12 Hz: Elble and Koller, "Tremor", Johns Hopkins University Press, 1990). The corrections' band
#: sits at the figures' ratio of acceleration to speed (170 / 12.9 and 329 / 24.6 mm/s^2 per mm/s, 13 rad/s:
#: 2.1 Hz) and above: slower corrections would need more speed than the figures have for their acceleration
BANDS_HZ = ((0.05, 0.3), (2.0, 4.0), (8.0, 12.0))
#: sinusoids per channel and band (:func:`band_noise`)
SINUSOIDS = 3
#: the motion is sampled at this many times the clip's frame rate to measure its kinematics
OVERSAMPLE = 8
#: the channels: sweep along the probe's x and y on the skin (metres of arc), rock and fan (radians)
CHANNELS = ("sweep_x", "sweep_y", "rock", "fan")
#: rounds of gain scaling, and the relative error of the kinematics at which it stops
CALIBRATION_ROUNDS, CALIBRATION_RTOL = 60, 1e-3
#: draws of a clip's kinematics and moves before the clip is given up (:func:`scan_motion`)
DRAWS = 20
#: Newton steps that press the lens back onto the skin (each removes the error to first order)
PRESS_STEPS = 8


@dataclass(frozen=True)
class ScanMotionSpec:
    """How clips of a scan are drawn (config node ``dataset.scan``).

    Attributes:
        duration_s: (min, max) seconds, a clip's length drawn uniformly.
        fps: frames per second of the clip, > 0.
        tilt_share: (min, max) the share of each band's gain given to the tilts (rock and fan) rather than the
            sweep, drawn per clip; the tilts' angles are that gain over the lever from the apex to the centre.
        max_tilt_deg: the rock and fan angles stay within this of the grasp's (the gains that would exceed it
            are refused: the clip's draws are repeated).
        press_m: metres, how deep the deepest lens vertex sits in the skin in every frame.
    """

    duration_s: tuple = (5.0, 10.0)
    fps: float = 30.0
    tilt_share: tuple = (0.2, 0.5)
    max_tilt_deg: float = 20.0
    press_m: float = 0.0005

    def __post_init__(self) -> None:
        object.__setattr__(self, "duration_s", check_interval(self.duration_s, "dataset.scan.duration_s", 0.5, 600.0,
                                                              unit="s"))
        object.__setattr__(self, "fps", check_number(self.fps, "dataset.scan.fps", 1.0, 1000.0))
        object.__setattr__(self, "tilt_share", check_interval(self.tilt_share, "dataset.scan.tilt_share", 0.0, 1.0))
        object.__setattr__(self, "max_tilt_deg", check_number(self.max_tilt_deg, "dataset.scan.max_tilt_deg", 0.0,
                                                              45.0))
        object.__setattr__(self, "press_m", check_number(self.press_m, "dataset.scan.press_m", 0.0, 0.002))


@dataclass(frozen=True)
class ScanMotion:
    """One clip of a scan.

    Attributes:
        time_s: (F,) float64, the frames' times, seconds from the clip's start.
        T_world_body: (F, 4, 4) float64, the patient's body frame in the world (probe) frame per frame.
        centre_body_m: (F, 3) float64, metres, the probe's centre in the body frame per frame.
        lens_skin_m: (F,) float64, metres, the signed distance of the deepest lens vertex per frame (-press_m).
        skill: float in [0, 1], 0 a consultant's figures, 1 a fellow's.
        target: {KINEMATICS_KEYS: float}, the drawn mean speed, acceleration and jerk.
        kinematics: the same measured on the oversampled motion (what the clip has).
        bounds: {"speed_mm_per_s", "acceleration_mm_per_s2", "jerk_mm_per_s3": float}, their maxima over the
            oversampled motion (what no frame-to-frame change may exceed).
    """

    time_s: np.ndarray
    T_world_body: np.ndarray
    centre_body_m: np.ndarray
    lens_skin_m: np.ndarray
    skill: float
    target: dict
    kinematics: dict
    bounds: dict


def clip_frames(duration_s: float, fps: float) -> int:
    """The frames of a clip of ``duration_s`` seconds at ``fps``: its start and end both included."""
    return int(round(duration_s * fps)) + 1


def draw_kinematics(rng: np.random.Generator) -> tuple[float, dict]:
    """A skill uniformly between a consultant's (0) and a fellow's (1), and the probe's mean speed,
    acceleration and jerk: each the skill's interpolated mean times a log-normal factor with the interpolated
    coefficient of variation (the acceleration's for the jerk, see :data:`SKILL_KINEMATICS`).

    Returns:
        (skill, {KINEMATICS_KEYS: float}).
    """
    skill = float(rng.uniform(0.0, 1.0))
    consultant, fellow = SKILL_KINEMATICS["consultant"], SKILL_KINEMATICS["fellow"]
    out = {}
    for key in KINEMATICS_KEYS:
        stats = [consultant[key], fellow[key]]
        spread_key = key if stats[0][1] is not None else "acceleration_mm_per_s2"
        cv = [g[spread_key][1] / g[spread_key][0] for g in (consultant, fellow)]
        mean = stats[0][0] + skill * (stats[1][0] - stats[0][0])
        sigma = cv[0] + skill * (cv[1] - cv[0])
        out[key] = float(mean * rng.lognormal(-0.5 * sigma ** 2, sigma))
    return skill, out


def band_noise(rng: np.random.Generator, time_s: np.ndarray, band_hz: tuple, axes: int) -> np.ndarray:
    """(F, axes) smooth random signals: per axis a sum of :data:`SINUSOIDS` sinusoids of frequencies, phases and
    amplitudes drawn uniformly (in ``band_hz``, [0, 2 pi), [0.5, 1]), 0 at the first time, standard deviation 1 (of
    the sinusoids over all time)."""
    out = np.zeros((len(time_s), axes))
    for a in range(axes):
        omega = 2.0 * math.pi * rng.uniform(*band_hz, SINUSOIDS)
        phase = rng.uniform(0.0, 2.0 * math.pi, SINUSOIDS)
        amplitude = rng.uniform(0.5, 1.0, SINUSOIDS)
        wave = amplitude[:, None] * (np.sin(omega[:, None] * (time_s - time_s[0]) + phase[:, None])
                                     - np.sin(phase[:, None]))
        out[:, a] = wave.sum(axis=0) / math.sqrt(0.5 * float(np.sum(amplitude ** 2)))
    return out


def _signals(rng: np.random.Generator, t: np.ndarray, tilt_share: float, lever_m: float) -> np.ndarray:
    """(3 bands, 4 channels, N) the channels' unit-gain signals: metres of arc for the sweeps, radians for the
    tilts (a metre at the probe's centre over ``lever_m``), split between them by ``tilt_share``."""
    weight = np.array([1.0 - tilt_share, 1.0 - tilt_share, tilt_share / lever_m, tilt_share / lever_m])
    return np.stack([weight[:, None] * band_noise(rng, t, band, len(CHANNELS)).T for band in BANDS_HZ])


class _Skin:
    """Poses of the probe on the abdomen's cap for given channel values (module steps 3)."""

    def __init__(self, placement: PatientPlacement, lens_probe: np.ndarray, centre_probe: np.ndarray,
                 press_m: float) -> None:
        self.radius = float(placement.radius_m)
        self.centre = sphere_centre(self.radius)
        self.T_body_probe0 = invert_transform(placement.T_world_body)
        R0 = self.T_body_probe0[:3, :3]
        # the lens apex (the probe's origin) is on the cap, a fraction of a millimetre inside: its direction
        # from the sphere's centre is the skin's normal there
        apex = self.T_body_probe0[:3, 3] - self.centre
        self.normal0 = apex / np.linalg.norm(apex)
        # the skin's tangent directions along the probe's x and y at the first contact
        ex = R0[:, 0] - np.dot(R0[:, 0], self.normal0) * self.normal0
        self.ex = ex / np.linalg.norm(ex)
        self.ey = np.cross(self.normal0, self.ex)
        self.lens, self.centre_probe, self.press = lens_probe, centre_probe, press_m
        self._lens_squared = (lens_probe ** 2).sum(axis=1)

    def poses(self, channels: np.ndarray, press: bool = True) -> np.ndarray:
        """(N, 4, 4) T_body_probe of (4, N) channel values, the lens pressed onto the skin (``press``) or the
        apex on it as the sweep keeps it (the tilts about it lift or sink the lens by a fraction of a mm)."""
        sweep = channels[0][:, None] * self.ex + channels[1][:, None] * self.ey  # (N, 3) metres along the skin
        R_sweep = axis_angle_to_matrix(np.cross(self.normal0, sweep) / self.radius)  # (N, 3, 3) about the centre
        zeros = np.zeros(channels.shape[1])
        R_tilt = axis_angle_to_matrix(np.stack([channels[3], channels[2], zeros], axis=1))  # probe frame, apex
        R0, t0 = self.T_body_probe0[:3, :3], self.T_body_probe0[:3, 3]
        T = np.tile(np.eye(4), (channels.shape[1], 1, 1))
        T[:, :3, :3] = R_sweep @ R0 @ R_tilt
        T[:, :3, 3] = self.centre + np.einsum("nij,j->ni", R_sweep, t0 - self.centre)
        normal = np.einsum("nij,j->ni", R_sweep, self.normal0)  # (N, 3) the skin's normal at the apex
        for _ in range(PRESS_STEPS if press else 0):
            T[:, :3, 3] -= (self._lens_sphere(T) + self.press)[:, None] * normal
        return T

    def _lens_sphere(self, T: np.ndarray) -> np.ndarray:
        """(N,) the deepest lens vertex's signed distance to the abdomen's sphere: the body's signed distance
        on the cap, where the lens stays (the union with the torso is far from it), at a fraction of the cost."""
        # |R l + t - c|^2 = |l|^2 + 2 l . R^T (t - c) + |t - c|^2: one (L, 3) x (3, N) product
        offset = T[:, :3, 3] - self.centre  # (N, 3)
        q = np.einsum("nji,nj->ni", T[:, :3, :3], offset)  # (N, 3) R^T (t - c)
        nearest = (self._lens_squared[:, None] + 2.0 * (self.lens @ q.T)).min(axis=0)  # (N,)
        return np.sqrt(np.maximum(nearest + (offset ** 2).sum(axis=1), 0.0)) - self.radius

    def lens_skin(self, T: np.ndarray) -> np.ndarray:
        """(N,) the deepest lens vertex's signed distance to the body (the full union with the torso)."""
        lens_body = np.einsum("nij,lj->nli", T[:, :3, :3], self.lens) + T[:, None, :3, 3]  # (N, L, 3)
        return body_sdf_local(self.radius, lens_body.reshape(-1, 3)).reshape(lens_body.shape[:2]).min(axis=1)

    def centres(self, T: np.ndarray) -> np.ndarray:
        return np.einsum("nij,j->ni", T[:, :3, :3], self.centre_probe) + T[:, :3, 3]


def _contact_kept(T: np.ndarray, radius_m: float, probe_vertices: np.ndarray, keep_out: np.ndarray | None) -> bool:
    """Whether in every pose of ``T`` ((F, 4, 4) T_body_probe) no probe vertex is deeper than ``PROBE_MAX_DEPTH_M``
    in the body and no ``keep_out`` vertex (the hand and forearm, probe frame) deeper than ``MAX_PENETRATION_M`` in
    it or below the bed's top: what :func:`hupbench.datagen.assets.patient.place_patient` keeps for the grasp's own
    pose, kept over the clip."""
    probe_body = np.einsum("fij,vj->fvi", T[:, :3, :3], probe_vertices) + T[:, None, :3, 3]
    if body_sdf_local(radius_m, probe_body.reshape(-1, 3)).min() < -PROBE_MAX_DEPTH_M:
        return False
    if keep_out is None:
        return True
    parts = np.einsum("fij,vj->fvi", T[:, :3, :3], keep_out) + T[:, None, :3, 3]
    return bool(below_skin(radius_m, parts).max() <= MAX_PENETRATION_M)


def scan_motion(placement: PatientPlacement, probe, spec: ScanMotionSpec, rng: np.random.Generator,
                keep_out: np.ndarray | None = None) -> ScanMotion:
    """One clip of a scan for a grasp's patient placement (the module's steps 1-4).

    Args:
        placement: the grasp's patient, its first frame's placement.
        probe: the :class:`hupbench.datagen.assets.probe.Probe` the hand holds.
        spec: the clip's ranges.
        rng: the seeded generator of the clip's draws.
        keep_out: (V, 3) float, metres, probe frame: the hand's and forearm's vertices, which may not sink into the
            body or the bed by more than ``MAX_PENETRATION_M`` in any frame; None: not checked.

    Returns:
        The clip, its first frame at the placement's pose pressed by ``spec.press_m``; in every frame no probe vertex
        deeper than ``PROBE_MAX_DEPTH_M`` and no ``keep_out`` vertex deeper than ``MAX_PENETRATION_M``.

    Raises:
        RunFailedError: none of :data:`DRAWS` draws of kinematics and moves met the kinematics within
            ``spec.max_tilt_deg`` (the figures need a few degrees: a limit of a degree or less cannot hold them)
            with the contact kept.
    """
    vertices = np.asarray(probe.mesh.vertices, dtype=np.float64)
    lens = vertices[np.unique(probe.mesh.faces[probe.lens_face_mask])]
    centre_probe = probe.corners_probe.mean(axis=0)
    skin = _Skin(placement, lens, centre_probe, spec.press_m)
    lever = float(np.linalg.norm(centre_probe))
    duration = float(rng.uniform(*spec.duration_s))
    frames = clip_frames(duration, spec.fps)
    rate = spec.fps * OVERSAMPLE
    t = np.arange((frames - 1) * OVERSAMPLE + 1) / rate
    for _ in range(DRAWS):
        skill, target = draw_kinematics(rng)
        want = np.array([target[key] for key in KINEMATICS_KEYS])
        signals = _signals(rng, t, float(rng.uniform(*spec.tilt_share)), lever)
        gains = np.array([want[0] / (2 * math.pi * 0.15), want[1] / (2 * math.pi * 2.0) ** 2,
                          want[2] / (2 * math.pi * 10.0) ** 3]) * 1e-3  # metres: each band alone
        # the gains of the rigid moves first (cheap), then with the lens pressed onto the skin (a small change)
        for press in (False, True):
            for _ in range(CALIBRATION_ROUNDS):
                T = skin.poses(np.einsum("b,bcn->cn", gains, signals), press)
                got = np.array(list(point_kinematics(skin.centres(T), rate).values()))
                met = bool(np.all(np.abs(got / want - 1.0) < CALIBRATION_RTOL))
                if met:
                    break
                gains = gains * (want / got)
        tilt = np.degrees(np.abs(np.einsum("b,bcn->cn", gains, signals)[2:])).max()
        contact = met and tilt <= spec.max_tilt_deg and _contact_kept(T[::OVERSAMPLE], skin.radius, vertices,
                                                                       keep_out)
        if contact:
            break
    else:
        raise RunFailedError(f"scan motion: {DRAWS} draws of kinematics and moves met the kinematics within "
                             f"dataset.scan.max_tilt_deg {spec.max_tilt_deg:g} deg in none, with the probe, hand and "
                             f"forearm out of the body (the last: tilts of {tilt:.1f} deg, kinematics "
                             f"{'met' if met else 'not met'}, contact {'kept' if contact else 'not kept or not tried'}):"
                             " raise it")
    centres = skin.centres(T)
    bounds = {key: float(np.linalg.norm(derivative, axis=-1).max() * 1e3)
              for key, derivative in zip(KINEMATICS_KEYS, time_derivatives(centres, rate))}
    keep = slice(None, None, OVERSAMPLE)
    return ScanMotion(time_s=t[keep], T_world_body=invert_transform(T[keep]), centre_body_m=centres[keep],
                      lens_skin_m=skin.lens_skin(T[keep]), skill=skill, target=target,
                      kinematics=dict(zip(KINEMATICS_KEYS, map(float, got))), bounds=bounds)
