"""Grasp generation end to end: starts -> refinement -> scores -> selection -> files.

For each probe orientation Theta_Vol the hand approaches from the same side
of the generator frame (the operator's side, -y), so the orientation decides
which face of the handle it meets. Starts come from the sampler ("cvae":
the shipped conditional VAE, then a short refinement, as RefineNet does) or
are randomised around the handle ("random": full refinement). Every
candidate is scored; the plausible ones are reduced to N diverse grasps by
farthest-point sampling on their joint positions, unless ids are pinned.

Convention:
    Candidates and outputs are in the probe frame (the renderer's world:
    lens apex at the origin); the generator frame of each Theta_Vol is kept
    beside them (see :mod:`hupbench.datagen.grasps.frames`). Metres and radians.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, fields

import numpy as np
import torch

from hupbench.core import keypoints as kp
from hupbench.datagen.assets.hand import build_hand
from hupbench.datagen.assets.hand_anatomy import HandSpec, anatomical_to_pose
from hupbench.datagen.assets.probe import Probe, ProbeSpec, build_probe
from hupbench.datagen.assets.probe_mesh import PROBE_MESH_FIELDS, probe_arrays
from hupbench.core.errors import BadValueError
from hupbench.core.geometry import matrix_to_axis_angle
from hupbench.datagen.grasps.approach import approach_azimuth, to_generator_frame
from hupbench.datagen.grasps.frames import T_gen_probe, check_euler_deg, probe_z_offset
from hupbench.datagen.grasps.refine import (
    MAX_ITERATIONS,
    GraspBatch,
    GraspEnergy,
    RefineConfig,
    random_starts,
    refine,
)
from hupbench.datagen.grasps.scores import (
    PLAUSIBLE,
    SCORE_NAMES,
    farthest_point_selection,
    score_grasps,
)
from hupbench.core.input_checks import check_int, is_whole

SAMPLERS = ("random", "cvae")
#: starts per orientation at most: they are refined as one batch, whose arrays grow with it
MAX_STARTS_PER_THETA = 4096
#: seeds are whole numbers that numpy's and torch's generators both take
MAX_SEED = 2**32 - 1
#: contact-sheet tiles: below 32 px a hand is a few pixels; above 4096 px the three tiles of a grasp
#: exceed the framebuffer offscreen GL drivers guarantee
MIN_TILE_PX, MAX_TILE_PX = 32, 4096


@dataclass(frozen=True)
class GraspGenConfig:
    """What to generate.

    Attributes:
        theta_vol_deg: list of (alpha, beta, gamma) probe orientations, degrees.
        starts_per_theta: candidates per orientation.
        sampler: "random" (randomised starts, full refinement) or "cvae".
        short_refine_iterations: refinement steps after CVAE samples.
        n_select: how many grasps to keep.
        pinned_ids: candidate ids to keep instead of selecting (None to select).
        seed: everything random derives from it.
    """

    theta_vol_deg: tuple = ((0.0, 0.0, 0.0),)
    starts_per_theta: int = 16
    sampler: str = "cvae"
    short_refine_iterations: int = 40
    n_select: int = 11
    pinned_ids: tuple | None = None
    seed: int = 0

    def __post_init__(self) -> None:
        try:
            theta = check_euler_deg(self.theta_vol_deg)
        except ValueError as exc:
            raise BadValueError(f"theta_vol_deg: {exc}") from None
        if theta.ndim != 2 or len(theta) == 0:
            raise BadValueError(f"theta_vol_deg must be a non-empty list of [alpha, beta, gamma], got {self.theta_vol_deg!r}")
        object.__setattr__(self, "theta_vol_deg", tuple(tuple(map(float, t)) for t in theta))
        if self.sampler not in SAMPLERS:
            raise BadValueError(f"sampler must be one of {SAMPLERS}, got {self.sampler!r}")
        for name in ("starts_per_theta", "n_select"):
            check_int(getattr(self, name), name, low=1)
        if self.starts_per_theta > MAX_STARTS_PER_THETA:
            raise BadValueError(f"starts_per_theta must be at most {MAX_STARTS_PER_THETA:,} (one orientation's starts "
                             f"are refined as one batch), got {self.starts_per_theta:,}")
        v = check_int(self.short_refine_iterations, "short_refine_iterations", low=0)
        if v > MAX_ITERATIONS:
            raise BadValueError(f"short_refine_iterations must be at most {MAX_ITERATIONS:,}, got {v:,}")
        check_int(self.seed, "seed", 0, MAX_SEED)
        if self.pinned_ids is not None:
            ids = tuple(self.pinned_ids) if isinstance(self.pinned_ids, (list, tuple)) else ()
            if not ids or not all(is_whole(i) for i in ids):
                raise BadValueError(f"pinned_ids must be a non-empty list of ints, got {self.pinned_ids!r}")
            if len(set(ids)) != len(ids):
                raise BadValueError(f"pinned_ids must be unique, got {list(ids)}")
            object.__setattr__(self, "pinned_ids", ids)


def check_selection(config: GraspGenConfig) -> None:
    """n_select, or the pinned ids, against the number of candidates the config makes, before the minutes of
    refinement (:class:`hupbench.verbs.grasps.GraspsRun` calls it). Not in :class:`GraspGenConfig` itself,
    whose candidates are also made without a selection.

    Raises:
        ValueError: naming n_select or pinned_ids and the candidates' count.
    """
    n_theta, starts = len(config.theta_vol_deg), config.starts_per_theta
    candidates = n_theta * starts
    if config.pinned_ids is not None:
        unknown = [i for i in config.pinned_ids if not 0 <= i < candidates]
        if unknown:
            raise BadValueError(f"pinned_ids: unknown grasp id(s) {unknown}: the {n_theta} x {starts} candidates are "
                             f"numbered 0..{candidates - 1}")
    elif config.n_select > candidates:
        raise BadValueError(f"cannot select {config.n_select} grasps (n_select): there are only {n_theta} x {starts} = "
                         f"{candidates} candidates (theta_vol_deg x starts_per_theta)")


def _cvae_starts(n: int, theta, probe, hand, rng: np.random.Generator) -> GraspBatch:
    from hupbench.datagen.grasps.cvae_sampling import sample_grasps

    return sample_grasps(n, theta, probe, hand, rng)


def generate_candidates(config: GraspGenConfig, hand_spec: HandSpec = HandSpec(),
                        probe_spec: ProbeSpec = ProbeSpec(), refine_config: RefineConfig | None = None,
                        log=print, probe: Probe | None = None) -> dict:
    """Make, refine and score the candidates of every Theta_Vol (on ``probe``, default the procedural
    probe of ``probe_spec``).

    Returns:
        dict with "grasps" (:class:`GraspBatch`, probe frame), "theta_index" (M,),
        "scores" (dict of (M,) arrays), "seconds" (float).
    """
    hand, probe = build_hand(hand_spec), probe or build_probe(probe_spec)
    settings = refine_config or RefineConfig()
    energy = GraspEnergy(hand, probe, settings)
    rng = np.random.default_rng(config.seed)
    torch.manual_seed(config.seed)
    start_time = time.perf_counter()
    batches, theta_index = [], []
    for k, theta in enumerate(config.theta_vol_deg):
        if config.sampler == "cvae":
            starts = _cvae_starts(config.starts_per_theta, theta, probe, hand, rng)
            iterations = config.short_refine_iterations
        else:
            starts = random_starts(config.starts_per_theta, rng, hand.limits_rad, approach_azimuth(theta, probe))
            iterations = settings.iterations
        refined = refine(energy, starts, iterations=iterations)
        batches.append(refined)
        theta_index += [k] * len(refined)
        log(f"  Theta_Vol {list(theta)}: {len(refined)} candidates refined "
            f"({time.perf_counter() - start_time:.0f} s so far)")
    grasps = GraspBatch.concat(batches)
    scores = score_grasps(energy, grasps)
    return {"grasps": grasps, "theta_index": np.array(theta_index), "scores": scores,
            "seconds": time.perf_counter() - start_time}


def select_grasps(candidates: dict, hand, n: int, seed: int, pinned_ids=None) -> np.ndarray:
    """Candidate ids of the selected grasps: pinned ones (:func:`check_selection` bounded them), or N
    diverse plausible ones."""
    M = len(candidates["grasps"])
    if pinned_ids is not None:
        assert all(0 <= i < M for i in pinned_ids), (pinned_ids, M)
        return np.array(pinned_ids, dtype=np.int64)
    ok = np.flatnonzero(candidates["scores"]["plausible"])
    if n > len(ok):
        raise BadValueError(f"cannot select {n} grasps: only {len(ok)} of {M} candidates are plausible "
                         f"(thresholds {PLAUSIBLE}); add starts or orientations")
    g = candidates["grasps"]
    with torch.no_grad():
        keypoints, _ = hand.forward_torch(torch.as_tensor(g.R_global[ok]), torch.as_tensor(g.trans[ok]),
                                          torch.as_tensor(g.angles[ok]), vertex_index=torch.arange(1))
    picked = farthest_point_selection(keypoints.numpy().reshape(len(ok), -1), n, np.random.default_rng(seed))
    return ok[picked]


def grasp_arrays(candidates: dict, ids: np.ndarray, config: GraspGenConfig, probe,
                 hand_spec: HandSpec = HandSpec()) -> dict[str, np.ndarray]:
    """The arrays of ``grasps.npz`` for the chosen candidate ids, their keypoints on the hand ``hand_spec`` that
    the candidates were refined for."""
    g = candidates["grasps"].take(ids)
    thetas = np.array(config.theta_vol_deg)[candidates["theta_index"][ids]]
    T_gen = np.stack([T_gen_probe(t, probe) for t in thetas])
    gen = [to_generator_frame(g.take([i]), T_gen[i]) for i in range(len(ids))]
    pose = anatomical_to_pose(g.angles, matrix_to_axis_angle(g.R_global))
    pose_gen = np.concatenate([anatomical_to_pose(b.angles, matrix_to_axis_angle(b.R_global)) for b in gen])
    hand = build_hand(hand_spec)
    keypoints = hand.keypoints(pose, g.trans, clamp=False)
    out = {
        "grasp_id": ids.astype(np.int64),
        "hand_pose": pose.astype(np.float64),
        "hand_trans": g.trans,
        "hand_angles": g.angles,
        "keypoints_probe": keypoints,
        "probe_euler_deg": thetas,
        "T_gen_probe": T_gen,
        "hand_pose_gen": pose_gen,
        "hand_trans_gen": np.concatenate([b.trans for b in gen]),
        "T_world_probe": np.broadcast_to(np.eye(4), (len(ids), 4, 4)).copy(),
        "probe_z_offset_m": np.array(probe_z_offset(probe)),
        "energy": g.energy,
    }
    for name in SCORE_NAMES:
        out[f"score_{name}"] = candidates["scores"][name][ids]
    return out | probe_arrays(probe)


def take_rows(arrays: dict, ids: np.ndarray) -> dict[str, np.ndarray]:
    """The rows ``ids`` of :func:`grasp_arrays` output for all candidates (per-probe scalars kept)."""
    n = len(arrays["grasp_id"])
    return {k: (v[ids] if v.ndim and len(v) == n and k not in PROBE_MESH_FIELDS else v) for k, v in arrays.items()}


def scores_json(arrays: dict, config: GraspGenConfig) -> dict:
    """Human-readable record of the selected grasps and their scores."""
    rows = []
    for i, gid in enumerate(arrays["grasp_id"]):
        row = {"grasp_id": int(gid), "probe_euler_deg": arrays["probe_euler_deg"][i].tolist()}
        for name in SCORE_NAMES:
            v = arrays[f"score_{name}"][i]
            row[name] = bool(v) if name in ("plausible", "thumb_contact") else round(float(v), 4)
        rows.append(row)
    return {"thresholds": PLAUSIBLE, "config": {f.name: getattr(config, f.name) for f in fields(config)},
            "probe_z_offset_m": float(arrays["probe_z_offset_m"]), "keypoint_names": list(kp.HAND_NAMES),
            "grasps": rows}
