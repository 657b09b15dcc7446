"""The refinement stage: energy-based optimisation of a hand grasping the probe.

Variables per grasp (a batch is optimised at once, one row per restart): a
residual rotation on the starting global rotation, the wrist translation,
and the 45 anatomical joint angles through a sigmoid onto their limits (hard
bounds: no joint can leave its range). Energies, in millimetres:

- contact: the fingertip pads (thumb, index, middle, ring, little) and the
  palm pad attracted to the probe surface (a Charbonnier penalty, about mm,
  on |SDF| of each pad's closest point; the thumb weighted 3x);
- penetration: hand and forearm points inside the probe (SDF < 0), weight
  annealed geometrically upward over the iterations;
- self-penetration: phalanx capsules of different fingers overlapping;
- clinical: hand points near the probe below the neck (the head and the
  acoustic lens must stay uncovered);
- prior: small pulls of abduction and twist towards 0 and DIP towards 2/3
  of PIP, which keep unobserved degrees of freedom natural.

Gradients are sanitised (NaN/inf -> 0) and clipped per grasp so one bad
restart never disturbs the others.

Convention:
    All geometry here is in the probe frame (metres; lens apex at the
    origin, +z along the handle). Angles in radians.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np
import torch

from hupbench.core import keypoints as kp
from hupbench.datagen.assets.arm import ArmSpec, forearm_rest
from hupbench.core.geometry import axis_angle_to_matrix as aa_to_matrix_np
from hupbench.datagen.assets.hand import HandModel
from hupbench.datagen.assets.hand_mesh import bone_radii
from hupbench.datagen.assets.probe import Probe
from hupbench.core.input_checks import check_int
from hupbench.core.rotations_torch import axis_angle_to_matrix
from hupbench.core.errors import BadValueError

#: refinement steps at most: the energy settles within a few hundred (default 300); 10^5 steps take hours
#: per orientation on a CPU
MAX_ITERATIONS = 100_000
PADS = ("thumb", "index", "middle", "ring", "little", "palm")
MM = 1000.0


@dataclass(frozen=True)
class RefineConfig:
    """Optimiser settings and energy weights (penalties in mm^2, contact in mm).

    Attributes:
        iterations: Adam steps.
        lr_rotation, lr_translation, lr_joints: step sizes (radians, metres, logits).
        w_contact, w_self, w_clinical, w_prior: fixed weights.
        w_penetration_start, w_penetration_end: annealed geometrically from start to end.
        clip_norm: per-grasp gradient norm limit, per variable group.
        clinical_margin_m: hand points closer than this to the probe count as touching it.
        min_contact_z_m: None for the probe's neck start minus 6 mm; touching points must stay above.
    """

    iterations: int = 300
    lr_rotation: float = 0.02
    lr_translation: float = 0.002
    lr_joints: float = 0.08
    w_contact: float = 20.0
    w_penetration_start: float = 10.0
    w_penetration_end: float = 1000.0
    w_self: float = 2.0
    w_clinical: float = 5.0
    w_prior: float = 200.0
    clip_norm: float = 1e3
    clinical_margin_m: float = 0.008
    min_contact_z_m: float | None = None

    def __post_init__(self) -> None:
        v = check_int(self.iterations, "iterations", low=0)
        if v > MAX_ITERATIONS:
            raise BadValueError(f"iterations must be at most {MAX_ITERATIONS:,}, got {v:,}")
        for name in ("lr_rotation", "lr_translation", "lr_joints", "clip_norm", "clinical_margin_m"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise BadValueError(f"{name} must be positive and finite, got {v!r}")
        for name in ("w_contact", "w_penetration_start", "w_penetration_end", "w_self", "w_clinical", "w_prior"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise BadValueError(f"{name} must be finite and >= 0, got {v!r}")
        v = self.min_contact_z_m
        if v is not None and not (not isinstance(v, bool) and isinstance(v, (int, float)) and math.isfinite(v)):
            raise BadValueError(f"min_contact_z_m must be a finite height in metres or null, got {v!r}")


@dataclass
class GraspBatch:
    """A batch of grasps in the probe frame (numpy, float64).

    Attributes:
        R_global: (B, 3, 3) hand frame -> probe frame.
        trans: (B, 3) metres, wrist position in the probe frame.
        angles: (B, 15, 3) anatomical angles, radians, MANO joint order.
        energy: (B,) final total energy, or NaN before refinement.
        history: per-iteration energy statistics, filled by :func:`refine`.
    """

    R_global: np.ndarray
    trans: np.ndarray
    angles: np.ndarray
    energy: np.ndarray | None = None
    history: list = field(default_factory=list)

    def __post_init__(self) -> None:
        B = len(self.R_global)
        shapes = {"R_global": (B, 3, 3), "trans": (B, 3), "angles": (B, 15, 3)}
        for name, shape in shapes.items():
            value = np.asarray(getattr(self, name), dtype=np.float64)
            assert value.shape == shape and np.all(np.isfinite(value)), (name, value.shape)
            setattr(self, name, value)
        if self.energy is None:
            self.energy = np.full(B, np.nan)

    def __len__(self) -> int:
        return len(self.R_global)

    def take(self, index) -> "GraspBatch":
        return GraspBatch(self.R_global[index], self.trans[index], self.angles[index], self.energy[index])

    @staticmethod
    def concat(batches: list["GraspBatch"]) -> "GraspBatch":
        return GraspBatch(*(np.concatenate([getattr(b, n) for b in batches]) for n in ("R_global", "trans", "angles")),
                          energy=np.concatenate([b.energy for b in batches]))


# --- hand regions --------------------------------------------------------------------


@dataclass(frozen=True)
class HandRegions:
    """Vertex sets of the rest hand used by the energies.

    Attributes:
        pads: name -> (K,) vertex indices of the palmar pad of each fingertip and the palm.
        capsules: (15, 2) OpenPose keypoint index pairs of the phalanx segments;
            capsule_finger: (15,) finger id of each; capsule_radius: (15,) metres.
        forearm_points: (P, 3) forearm surface points in the hand frame (neutral wrist).
    """

    pads: dict
    capsules: np.ndarray
    capsule_finger: np.ndarray
    capsule_radius: np.ndarray
    forearm_points: np.ndarray


@functools.lru_cache(maxsize=4)
def hand_regions(hand: HandModel) -> HandRegions:
    """The pads, capsules and forearm points of a hand model (cached)."""
    import trimesh

    mesh = trimesh.Trimesh(hand.vertices_rest, hand.faces, process=False)
    normals = np.asarray(mesh.vertex_normals)
    owner = hand.weights.argmax(axis=1)
    frames = hand.buffers(torch.float64)["frames"].numpy()
    tips = hand.keypoints_rest
    pads = {}
    for i, finger in enumerate(kp.MANO_FINGER_ORDER):
        distal = 3 + 3 * i  # MANO joint whose bone is the distal phalanx
        palmar = -frames[distal - 1][:, 1]  # the abduction axis points dorsal
        tip = tips[kp.FINGER_START[finger] + 3]
        near_tip = np.linalg.norm(hand.vertices_rest - tip, axis=1) < 0.014 * hand.spec.scale
        pads[finger] = np.flatnonzero((owner == distal) & (normals @ palmar > 0.5) & near_tip)
    x = hand.vertices_rest[:, 0] / hand.spec.scale
    palm = (owner == 0) & (normals @ np.array([0.0, -1.0, 0.0]) > 0.8) & (x > 0.025) & (x < 0.07)
    pads["palm"] = np.flatnonzero(palm)
    assert all(len(idx) for idx in pads.values()), {name: len(idx) for name, idx in pads.items()}
    capsules, fingers, radii = [], [], []
    bone_radii_m = bone_radii(hand.spec)
    for i, finger in enumerate(kp.MANO_FINGER_ORDER):
        start = kp.FINGER_START[finger]
        for k in range(3):
            capsules.append((start + k, start + k + 1))
            fingers.append(i)
            radii.append(bone_radii_m[1 + 3 * i + k])
    verts, _ = forearm_rest(ArmSpec(scale=hand.spec.scale))
    # the near end overlaps the hand by design; keep points from 3 cm up the forearm
    forearm = verts[verts[:, 0] < -0.03][::3]
    return HandRegions(pads, np.array(capsules), np.array(fingers), np.array(radii), forearm)


# --- energies ------------------------------------------------------------------------


def _segment_samples(a: torch.Tensor, b: torch.Tensor, n: int = 5) -> torch.Tensor:
    t = torch.linspace(0.0, 1.0, n, dtype=a.dtype, device=a.device)
    return a[..., None, :] + t[:, None] * (b - a)[..., None, :]


class GraspEnergy:
    """Energies of hand grasps on one probe (probe frame).

    Args:
        hand: the hand model. probe: the probe model. config: weights.
        dtype: torch dtype for the optimisation.
    """

    def __init__(self, hand: HandModel, probe: Probe, config: RefineConfig = RefineConfig(),
                 dtype=torch.float32) -> None:
        self.hand, self.probe, self.config, self.dtype = hand, probe, config, dtype
        regions = hand_regions(hand)
        self.regions = regions
        self.pad_index = {name: torch.as_tensor(idx) for name, idx in regions.pads.items()}
        # the thumb opposes the fingers in every clinical grip, so its contact counts most
        self.pad_weight = torch.tensor([3.0 if name == "thumb" else 1.0 for name in regions.pads], dtype=dtype)
        self.forearm_points = torch.as_tensor(regions.forearm_points, dtype=dtype)
        self.capsules = torch.as_tensor(regions.capsules)
        self.capsule_radius = torch.as_tensor(regions.capsule_radius, dtype=dtype)
        finger = regions.capsule_finger
        pairs = [(a, b) for a in range(15) for b in range(a + 1, 15) if finger[a] != finger[b]]
        self.pairs = torch.as_tensor(pairs)
        neck_start = probe.region_z.neck[0]
        self.min_contact_z = config.min_contact_z_m if config.min_contact_z_m is not None else neck_start - 0.006
        limits = hand.buffers(dtype)["limits"]
        self.limits = limits
        # joint indices (0-based over MANO joints 1..15) of PIP and DIP joints of the four fingers
        self.pip = torch.tensor([1 + 3 * i for i in range(4)])
        self.dip = self.pip + 1

    def sdf(self, points: torch.Tensor) -> torch.Tensor:
        return self.probe.signed_distance_torch(points)

    def terms(self, R_global: torch.Tensor, trans: torch.Tensor, angles: torch.Tensor) -> dict:
        """Per-grasp energy terms (each (B,), mm^2 units) and the quantities the scores need."""
        keypoints, verts = self.hand.forward_torch(R_global, trans, angles)
        sdf_mm = self.sdf(verts) * MM  # (B, V)
        pad_dist = torch.stack([sdf_mm[:, idx].abs().min(dim=1).values for idx in self.pad_index.values()], dim=1)
        # Charbonnier (about |d| beyond 1 mm): a pull that does not fade as a pad nears the surface
        contact = ((torch.sqrt(pad_dist**2 + 1.0) - 1.0) * self.pad_weight).sum(dim=1) / self.pad_weight.sum()
        penetration = (torch.relu(-sdf_mm) ** 2).sum(dim=1)
        forearm = (R_global @ self.forearm_points.T).transpose(-1, -2) + trans[:, None, :]
        forearm_pen = (torch.relu(-self.sdf(forearm) * MM) ** 2).sum(dim=1)
        # self-penetration: capsules of different fingers
        seg = _segment_samples(keypoints[:, self.capsules[:, 0]], keypoints[:, self.capsules[:, 1]])  # (B,15,5,3)
        a, b = seg[:, self.pairs[:, 0]], seg[:, self.pairs[:, 1]]  # (B, P, 5, 3)
        d = torch.cdist(a, b).flatten(-2).min(dim=-1).values  # (B, P)
        overlap_mm = torch.relu(self.capsule_radius[self.pairs].sum(-1) - d) * MM
        self_pen = (overlap_mm**2).sum(dim=1)
        near = torch.sigmoid((self.config.clinical_margin_m * MM - sdf_mm) / 1.0)
        low_mm = torch.relu(self.min_contact_z - verts[..., 2]) * MM
        clinical = (near * low_mm**2).sum(dim=1)
        pip, dip = angles[:, self.pip, 0], angles[:, self.dip, 0]
        prior = (angles[..., 1:] ** 2).sum(dim=(1, 2)) + ((dip - 2.0 / 3.0 * pip) ** 2).sum(dim=1)
        return {
            "contact": contact, "penetration": penetration + forearm_pen, "self": self_pen,
            "clinical": clinical, "prior": prior,
            "_keypoints": keypoints, "_verts": verts, "_sdf_mm": sdf_mm, "_pad_dist_mm": pad_dist,
            "_overlap_mm": overlap_mm, "_forearm_sdf_mm": self.sdf(forearm) * MM,
        }

    def total(self, terms: dict, w_penetration: float) -> torch.Tensor:
        c = self.config
        return (c.w_contact * terms["contact"] + w_penetration * terms["penetration"] + c.w_self * terms["self"]
                + c.w_clinical * terms["clinical"] + c.w_prior * terms["prior"])


def _logit(unit: torch.Tensor) -> torch.Tensor:
    unit = unit.clamp(0.02, 0.98)
    return torch.log(unit) - torch.log1p(-unit)


def refine(energy: GraspEnergy, start: GraspBatch, iterations: int | None = None,
           record_every: int = 0) -> GraspBatch:
    """Minimise the grasp energy from a batch of starts.

    Args:
        energy: the energy (hand, probe, weights).
        start: starting grasps, probe frame; angles outside limits are clamped.
        iterations: overrides ``energy.config.iterations``.
        record_every: if > 0, append energy statistics to ``history`` every so many steps.

    Returns:
        The refined grasps (a new :class:`GraspBatch`) with their final energy.
    """
    config = energy.config
    iterations = config.iterations if iterations is None else iterations
    dtype = energy.dtype
    limits = energy.limits
    R0 = torch.as_tensor(start.R_global, dtype=dtype)
    angles0 = torch.as_tensor(start.angles, dtype=dtype)
    unit0 = (angles0 - limits[..., 0]) / (limits[..., 1] - limits[..., 0])
    rot = torch.zeros(len(start), 3, dtype=dtype, requires_grad=True)
    trans = torch.as_tensor(start.trans, dtype=dtype).clone().requires_grad_(True)
    logits = _logit(unit0).clone().requires_grad_(True)
    optimiser = torch.optim.Adam([
        {"params": [rot], "lr": config.lr_rotation},
        {"params": [trans], "lr": config.lr_translation},
        {"params": [logits], "lr": config.lr_joints},
    ])
    history = []

    def current():
        R = axis_angle_to_matrix(rot) @ R0
        angles = limits[..., 0] + torch.sigmoid(logits) * (limits[..., 1] - limits[..., 0])
        return R, angles

    ratio = config.w_penetration_end / max(config.w_penetration_start, 1e-12)
    for step in range(iterations):
        fraction = step / max(iterations - 1, 1)
        w_pen = config.w_penetration_start * ratio**fraction
        R, angles = current()
        terms = energy.terms(R, trans, angles)
        total = energy.total(terms, w_pen)
        optimiser.zero_grad(set_to_none=True)
        total.sum().backward()
        with torch.no_grad():
            for p in (rot, trans, logits):
                torch.nan_to_num_(p.grad, nan=0.0, posinf=0.0, neginf=0.0)
                norm = p.grad.flatten(1).norm(dim=1).clamp_min(1e-30)
                p.grad *= (config.clip_norm / norm).clamp(max=1.0).view(-1, *([1] * (p.grad.ndim - 1)))
        optimiser.step()
        if record_every and (step % record_every == 0 or step == iterations - 1):
            history.append({"step": step, "w_penetration": w_pen,
                            **{k: float(v.detach().median()) for k, v in terms.items() if not k.startswith("_")}})
    with torch.no_grad():
        R, angles = current()
        terms = energy.terms(R, trans, angles)
        final = energy.total(terms, config.w_penetration_end)
    out = GraspBatch(R.detach().double().numpy(), trans.detach().double().numpy(), angles.detach().double().numpy(),
                     energy=final.double().numpy())
    out.history = history
    return out


# --- starts --------------------------------------------------------------------------


def canonical_grip() -> tuple[np.ndarray, np.ndarray]:
    """The reference handle grip used to place random starts.

    Returns:
        R_global (3, 3): palm facing +y of the probe, fingers along -x, thumb towards the lens.
        trans (3,): metres, wrist position for that grip, probe frame.
    """
    R = aa_to_matrix_np(np.array([0.0, np.deg2rad(-20.0), 0.0])) @ np.diag([-1.0, -1.0, 1.0])
    return R, np.array([0.056, -0.031, 0.098])


def random_starts(n: int, rng: np.random.Generator, limits: np.ndarray, approach_azimuth: float = 0.0,
                  azimuth_spread: float = np.deg2rad(60.0)) -> GraspBatch:
    """Randomised starting grasps around the handle.

    The canonical grip is turned about the probe's long axis by the approach
    azimuth plus a uniform spread, tilted by a few degrees, shifted along the
    handle, and given random finger flexions.

    Args:
        n: number of starts.
        rng: numpy random generator.
        limits: (15, 3, 2) joint limits, radians.
        approach_azimuth: radians about +z of the probe, 0 = the canonical side.
        azimuth_spread: half-width of the uniform azimuth spread, radians.

    Returns:
        :class:`GraspBatch` of n starts, probe frame.
    """
    R_c, t_c = canonical_grip()
    R_out, t_out, angles = np.zeros((n, 3, 3)), np.zeros((n, 3)), np.zeros((n, 15, 3))
    for i in range(n):
        phi = approach_azimuth + rng.uniform(-azimuth_spread, azimuth_spread)
        Rz = aa_to_matrix_np(np.array([0.0, 0.0, phi]))
        tilt = aa_to_matrix_np(rng.normal(0.0, np.deg2rad(8.0), size=3))
        R_out[i] = Rz @ tilt @ R_c
        t = Rz @ t_c
        t_out[i] = t + np.array([*rng.normal(0.0, 0.006, size=2), rng.uniform(-0.015, 0.02)])
        flex = rng.uniform(0.25, 0.75, size=15)
        angles[i, :, 0] = limits[:, 0, 0] + flex * (limits[:, 0, 1] - limits[:, 0, 0])
        angles[i, :, 1:] = rng.uniform(0.35, 0.65, size=(15, 2)) * (limits[:, 1:, 1] - limits[:, 1:, 0]) \
            + limits[:, 1:, 0]
    return GraspBatch(R_out, t_out, angles)


def heuristic_starts(n: int, limits: np.ndarray, approach_azimuth: float = 0.0) -> GraspBatch:
    """n copies of one hand-made start: the canonical grip turned to the approach side, joints mid-range.

    The baseline a sampler must beat on diversity: refinement is deterministic, so
    identical starts give identical grasps.
    """
    R_c, t_c = canonical_grip()
    Rz = aa_to_matrix_np(np.array([0.0, 0.0, approach_azimuth]))
    angles = limits[..., 0] + 0.5 * (limits[..., 1] - limits[..., 0])
    return GraspBatch(np.repeat((Rz @ R_c)[None], n, 0), np.repeat((Rz @ t_c)[None], n, 0),
                      np.repeat(angles[None], n, 0))
