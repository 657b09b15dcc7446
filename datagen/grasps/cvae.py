"""The sampling stage of the grasp generator: a BPS-conditioned conditional VAE.

Like GrabNet's CoarseNet (Taheri et al., ECCV 2020; our own design and code,
no weights of theirs), a conditional VAE proposes grasps for the probe in a
given orientation. The condition is the probe's Basis Point Set encoding
(:mod:`hupbench.datagen.grasps.bps`) plus an *initial wrist* pose (the pose the
refinement stage would start from); the output is the 54-vector of
:mod:`hupbench.datagen.grasps.params`.

Design:
    Residual outputs. The decoder predicts the grasp relative to the
    initial wrist, so that an untrained (or collapsed) network already
    returns the initial pose and learning only has to model corrections:

    - rotation: ``R = R_init @ rot6d_to_matrix(I6 + d_rot)``, the residual
      rotation acts in the initial hand frame, ``I6`` the identity's 6D form;
    - translation: ``trans = init_trans + R_init @ d_trans * 0.05 m``, the
      offset expressed in the initial hand frame in units of 5 cm;
    - joints: ``joint_unit = 0.5 + d_joint``, centred on mid-range.

    :func:`grasp_to_residual` and :func:`residual_to_grasp` are this map and
    its inverse; the encoder sees the residual form of the target too.
    Network inputs are scaled to order one: BPS distances in centimetres,
    the initial translation in units of 5 cm.

Loss:
    L1 terms weighted so that typical errors weigh alike: rot6d L1 x 20
    (a 10 degree error is a mean |d rot6d| of about 0.06, so about 1.2),
    translation L1 in centimetres x 1, joint_unit L1 x 5 (0.1 of a range,
    about 10 degrees, gives 0.5), keypoints (mean Euclidean distance of the
    21 hand keypoints, millimetres) x 0.1 (10 mm gives 1), KL x 0.01.

Convention:
    Generator frame (probe at Theta_Vol, centred at its volume centroid),
    metres and radians; see :mod:`hupbench.datagen.grasps.frames`.
"""

from __future__ import annotations

import dataclasses
import json
import os
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np
import torch
from torch import nn

from hupbench.datagen.grasps.params import JOINTS, PARAM_DIM, ROT, TRANS, unit_to_angles
from hupbench.core.input_checks import check_int, check_number
from hupbench.core.rotations_torch import matrix_to_rot6d, rot6d_to_matrix
from hupbench.core.errors import BadTypeError, BadValueError, MissingFileError
from hupbench.core.io import save_npz

#: network input unit of the BPS distances (centimetres: features of 0..15 instead of 0..0.15)
BPS_UNIT_M = 0.01
#: network unit of translations (initial wrist and predicted offset): a typical wrist offset
NET_TRANS_UNIT_M = 0.05
#: loss unit of the translation term (centimetres)
LOSS_TRANS_UNIT_M = 0.01
#: loss unit of the keypoint term (millimetres)
LOSS_KEYPOINT_UNIT_M = 0.001
#: log-variance bounds of the posterior: exp() stays finite and the KL cannot blow up early in training
LOGVAR_MIN, LOGVAR_MAX = -12.0, 6.0

#: where the trained sampler ships with the package (written by the training command, not by tests)
SHIPPED_WEIGHTS = Path(__file__).parent / "weights" / "grasp_cvae.npz"
#: the command that trains the sampler and writes SHIPPED_WEIGHTS
RETRAIN_COMMAND = "hupbench train-grasp-sampler"

_FILE_FORMAT = "hupbench.grasp_cvae"
_FILE_VERSION = 1
#: the .npz entry holding the JSON header; state_dict keys never start with an underscore
_HEADER_KEY = "__header__"
CORPUS_KEYS = ("x", "bps", "init_rot6d", "init_trans")


@dataclass(frozen=True)
class CVAEConfig:
    """Architecture and training hyperparameters of :class:`GraspCVAE`.

    The defaults train on a corpus of 1-5k grasps in a few minutes on two
    CPU cores.

    Attributes:
        n_bps: number of basis points (length of the BPS feature).
        latent_dim: size of the latent z.
        hidden: width of the encoder and decoder MLPs.
        bps_embed: width of the BPS embedding.
        epochs: training epochs.
        batch_size: samples per optimiser step.
        lr: Adam learning rate (cosine-decayed to a tenth over training).
        kl_weight: weight of the KL divergence (nats) in the loss.
        keypoint_weight: weight of the keypoint term (mm); 0 skips the hand model.
        rot_weight: weight of the rot6d L1 term.
        trans_weight: weight of the translation L1 term (cm).
        joint_weight: weight of the joint_unit L1 term.
        val_fraction: share of the corpus held out for validation, in (0, 0.5].
        seed: seeds the initial weights, the split, the shuffling and the
            reparameterisation noise.
    """

    n_bps: int = 1024
    latent_dim: int = 16
    hidden: int = 256
    bps_embed: int = 128
    epochs: int = 100
    batch_size: int = 128
    lr: float = 1e-3
    kl_weight: float = 0.01
    keypoint_weight: float = 0.1
    rot_weight: float = 20.0
    trans_weight: float = 1.0
    joint_weight: float = 5.0
    val_fraction: float = 0.1
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("n_bps", "latent_dim", "hidden", "bps_embed", "epochs", "batch_size"):
            check_int(getattr(self, name), name, low=1, error=BadTypeError)
        check_int(self.seed, "seed", low=0)
        check_number(self.lr, "lr", 0, low_open=True)
        for name in ("kl_weight", "keypoint_weight", "rot_weight", "trans_weight", "joint_weight"):
            check_number(getattr(self, name), name, 0)
        check_number(self.val_fraction, "val_fraction", 0, 0.5, low_open=True)


class CVAEOutput(NamedTuple):
    """What :meth:`GraspCVAE.forward` returns.

    Attributes:
        x_hat: (B, 54) reconstructed grasp, generator frame (rot6d of a proper
            rotation, metres, joint_unit not clamped).
        mu: (B, latent_dim) posterior mean.
        logvar: (B, latent_dim) posterior log-variance (natural log), clamped
            to [LOGVAR_MIN, LOGVAR_MAX].
    """

    x_hat: torch.Tensor
    mu: torch.Tensor
    logvar: torch.Tensor


def _identity_rot6d(like: torch.Tensor) -> torch.Tensor:
    return torch.tensor([1.0, 0.0, 0.0, 0.0, 1.0, 0.0], dtype=like.dtype, device=like.device)


def grasp_to_residual(x: torch.Tensor, init_rot6d: torch.Tensor, init_trans: torch.Tensor) -> torch.Tensor:
    """Express grasps relative to their initial wrist pose (the decoder's output space).

    Args:
        x: (..., 54) grasps, generator frame (see :mod:`hupbench.datagen.grasps.params`);
            the rot6d part need not be orthonormal (Gram-Schmidt is applied).
        init_rot6d: (..., 6) initial hand rotation (hand -> generator frame), 6D.
        init_trans: (..., 3) initial wrist position, metres, generator frame.

    Returns:
        (..., 54) ``[rot6d(R_init^T R) - I6 | R_init^T (trans - init_trans) / 0.05 m | joint_unit - 0.5]``.
    """
    R_init = rot6d_to_matrix(init_rot6d)
    R_delta = R_init.transpose(-1, -2) @ rot6d_to_matrix(x[..., ROT])
    offset_init = (R_init.transpose(-1, -2) @ (x[..., TRANS] - init_trans).unsqueeze(-1)).squeeze(-1)
    return torch.cat(
        [matrix_to_rot6d(R_delta) - _identity_rot6d(x), offset_init / NET_TRANS_UNIT_M, x[..., JOINTS] - 0.5],
        dim=-1,
    )


def residual_to_grasp(residual: torch.Tensor, init_rot6d: torch.Tensor, init_trans: torch.Tensor) -> torch.Tensor:
    """Inverse of :func:`grasp_to_residual`.

    Args:
        residual: (..., 54) residual form.
        init_rot6d: (..., 6) initial hand rotation, 6D.
        init_trans: (..., 3) initial wrist position, metres, generator frame.

    Returns:
        (..., 54) grasps, generator frame; the rot6d part is orthonormal,
        joint_unit is not clamped.
    """
    R_init = rot6d_to_matrix(init_rot6d)
    R = R_init @ rot6d_to_matrix(residual[..., ROT] + _identity_rot6d(residual))
    offset_gen = (R_init @ (residual[..., TRANS] * NET_TRANS_UNIT_M).unsqueeze(-1)).squeeze(-1)
    return torch.cat([matrix_to_rot6d(R), init_trans + offset_gen, residual[..., JOINTS] + 0.5], dim=-1)


class _ResidualBlock(nn.Module):
    """x + Linear(SiLU(LayerNorm(x))): keeps gradients healthy in a deeper MLP."""

    def __init__(self, width: int):
        super().__init__()
        self.norm = nn.LayerNorm(width)
        self.linear = nn.Linear(width, width)

    def forward(self, h: torch.Tensor) -> torch.Tensor:
        return h + self.linear(nn.functional.silu(self.norm(h)))


class _MLP(nn.Module):
    def __init__(self, n_in: int, hidden: int, n_out: int, out_scale: float):
        super().__init__()
        self.inp = nn.Sequential(nn.Linear(n_in, hidden), nn.LayerNorm(hidden), nn.SiLU())
        self.blocks = nn.Sequential(_ResidualBlock(hidden), _ResidualBlock(hidden))
        self.norm = nn.LayerNorm(hidden)
        self.out = nn.Linear(hidden, n_out)
        with torch.no_grad():
            # small (not zero) last layer: outputs start near zero, yet every parameter gets a gradient at once
            self.out.weight.mul_(out_scale)
            self.out.bias.zero_()

    def forward(self, h: torch.Tensor) -> torch.Tensor:
        return self.out(nn.functional.silu(self.norm(self.blocks(self.inp(h)))))


class GraspCVAE(nn.Module):
    """Conditional VAE over grasps, conditioned on the probe's BPS and an initial wrist pose.

    Condition: ``[SiLU(LayerNorm(Linear(bps / 1 cm))) (bps_embed) | init_rot6d (6) |
    init_trans / 5 cm (3)]``. Encoder q(z | x, cond) and decoder p(x | z, cond)
    are MLPs (Linear + LayerNorm + SiLU, two pre-norm residual blocks). The
    decoder's output is the residual form of :func:`residual_to_grasp`.

    In training mode ``forward`` samples z from the posterior
    (reparameterisation); in eval mode it uses the posterior mean, so that
    validation reconstructions are deterministic. The model holds no device
    state: move it with ``.to(device)``.

    Args:
        config: the architecture (the training fields are not used here).

    Attributes:
        config: the :class:`CVAEConfig` it was built from.
    """

    def __init__(self, config: CVAEConfig = CVAEConfig()):
        super().__init__()
        self.config = config
        self.bps_encoder = nn.Sequential(nn.Linear(config.n_bps, config.bps_embed), nn.LayerNorm(config.bps_embed),
                                         nn.SiLU())
        cond_dim = config.bps_embed + 6 + 3
        self.encoder = _MLP(PARAM_DIM + cond_dim, config.hidden, 2 * config.latent_dim, out_scale=0.1)
        self.decoder = _MLP(config.latent_dim + cond_dim, config.hidden, PARAM_DIM, out_scale=0.1)

    def condition(self, bps: torch.Tensor, init_rot6d: torch.Tensor, init_trans: torch.Tensor) -> torch.Tensor:
        """(B, n_bps), (B, 6), (B, 3) -> (B, bps_embed + 9) condition vector."""
        init_rot6d = matrix_to_rot6d(rot6d_to_matrix(init_rot6d))  # orthonormalised, as the residuals use it
        return torch.cat([self.bps_encoder(bps / BPS_UNIT_M), init_rot6d, init_trans / NET_TRANS_UNIT_M], dim=-1)

    def forward(self, x: torch.Tensor, bps: torch.Tensor, init_rot6d: torch.Tensor, init_trans: torch.Tensor,
                generator: torch.Generator | None = None) -> CVAEOutput:
        """Encode a grasp, sample (training) or take (eval) its latent, decode it.

        Args:
            x: (B, 54) float grasps, generator frame.
            bps: (B, n_bps) float BPS features, metres.
            init_rot6d: (B, 6) initial hand rotation (hand -> generator frame), 6D.
            init_trans: (B, 3) initial wrist position, metres, generator frame.
            generator: optional torch.Generator for the reparameterisation
                noise (any device: the noise is drawn there and moved).

        Returns:
            :class:`CVAEOutput` ``(x_hat (B, 54), mu (B, latent_dim), logvar (B, latent_dim))``.
        """
        cond = self.condition(bps, init_rot6d, init_trans)
        stats = self.encoder(torch.cat([grasp_to_residual(x, init_rot6d, init_trans), cond], dim=-1))
        mu, logvar = stats.chunk(2, dim=-1)
        logvar = logvar.clamp(LOGVAR_MIN, LOGVAR_MAX)
        if self.training:
            z = mu + torch.exp(0.5 * logvar) * self._normal(mu.shape, mu, generator)
        else:
            z = mu
        residual = self.decoder(torch.cat([z, cond], dim=-1))
        return CVAEOutput(residual_to_grasp(residual, init_rot6d, init_trans), mu, logvar)

    def decode(self, z: torch.Tensor, bps: torch.Tensor, init_rot6d: torch.Tensor,
               init_trans: torch.Tensor) -> torch.Tensor:
        """Grasps for given latents.

        Args:
            z: (B, latent_dim) float latents.
            bps, init_rot6d, init_trans: the condition, as in :meth:`forward`.

        Returns:
            (B, 54) grasps, generator frame (joint_unit not clamped).
        """
        residual = self.decoder(torch.cat([z, self.condition(bps, init_rot6d, init_trans)], dim=-1))
        return residual_to_grasp(residual, init_rot6d, init_trans)

    @torch.no_grad()
    def sample(self, bps: torch.Tensor, init_rot6d: torch.Tensor, init_trans: torch.Tensor,
               generator: torch.Generator | None = None) -> torch.Tensor:
        """Draw one grasp per condition row with z ~ N(0, I) (no gradients).

        Args:
            bps: (B, n_bps) float BPS features, metres.
            init_rot6d: (B, 6) initial hand rotation, 6D.
            init_trans: (B, 3) initial wrist position, metres, generator frame.
            generator: seeds z; the same generator state gives the same grasps.
                Repeat the condition rows to draw several grasps for one.

        Returns:
            (B, 54) grasps, generator frame, on the inputs' device and dtype.
        """
        z = self._normal((bps.shape[0], self.config.latent_dim), bps, generator)
        return self.decode(z, bps, init_rot6d, init_trans)

    @staticmethod
    def _normal(shape, like: torch.Tensor, generator: torch.Generator | None) -> torch.Tensor:
        if generator is None:
            return torch.randn(shape, dtype=like.dtype, device=like.device)
        return torch.randn(shape, generator=generator, dtype=like.dtype, device=generator.device).to(like.device)


def cvae_loss(model_out: CVAEOutput, x: torch.Tensor, hand_model=None, *,
              kl_weight: float = CVAEConfig.kl_weight, keypoint_weight: float = CVAEConfig.keypoint_weight,
              rot_weight: float = CVAEConfig.rot_weight, trans_weight: float = CVAEConfig.trans_weight,
              joint_weight: float = CVAEConfig.joint_weight) -> dict[str, torch.Tensor]:
    """Reconstruction + KL loss of the grasp CVAE (see the module docstring for the weights).

    Args:
        model_out: :class:`CVAEOutput` of :meth:`GraspCVAE.forward`.
        x: (B, 54) target grasps, generator frame.
        hand_model: a :class:`hupbench.datagen.assets.hand.HandModel` for the keypoint term;
            None (or ``keypoint_weight == 0``) leaves it out. Joint units are
            clamped to [0, 1] before they become angles.
        kl_weight, keypoint_weight, rot_weight, trans_weight, joint_weight:
            non-negative weights (a :class:`CVAEConfig`'s, checked there).

    Returns:
        dict of scalar tensors: "rot" (mean |d rot6d|, target orthonormalised),
        "trans_cm" (mean |d trans| per axis, cm), "joint" (mean |d joint_unit|),
        "keypoint_mm" (mean distance of the 21 keypoints, mm; only with a hand
        model), "kl" (nats per sample), "recon" (weighted reconstruction terms)
        and "total" (recon + kl_weight * kl).
    """
    x_hat, mu, logvar = model_out
    assert x.shape == x_hat.shape, (x.shape, x_hat.shape)
    R_target = rot6d_to_matrix(x[..., ROT])
    parts = {
        "rot": (x_hat[..., ROT] - matrix_to_rot6d(R_target)).abs().mean(),
        "trans_cm": (x_hat[..., TRANS] - x[..., TRANS]).abs().mean() / LOSS_TRANS_UNIT_M,
        "joint": (x_hat[..., JOINTS] - x[..., JOINTS]).abs().mean(),
    }
    recon = rot_weight * parts["rot"] + trans_weight * parts["trans_cm"] + joint_weight * parts["joint"]
    if hand_model is not None and keypoint_weight > 0:
        limits = hand_model.buffers(x.dtype, x.device)["limits"]
        no_vertices = torch.zeros(0, dtype=torch.long, device=x.device)  # keypoints only: skip the skinning

        def keypoints(grasp: torch.Tensor) -> torch.Tensor:
            angles = unit_to_angles(grasp[..., JOINTS].reshape(-1, 15, 3).clamp(0.0, 1.0), limits)
            return hand_model.forward_torch(rot6d_to_matrix(grasp[..., ROT]), grasp[..., TRANS], angles,
                                            vertex_index=no_vertices)[0]

        with torch.no_grad():
            target = keypoints(x)
        parts["keypoint_mm"] = torch.linalg.norm(keypoints(x_hat) - target, dim=-1).mean() / LOSS_KEYPOINT_UNIT_M
        recon = recon + keypoint_weight * parts["keypoint_mm"]
    parts["kl"] = 0.5 * (mu.square() + logvar.exp() - 1.0 - logvar).sum(dim=-1).mean()
    parts["recon"] = recon
    parts["total"] = recon + kl_weight * parts["kl"]
    return parts


# --------------------------------------------------------------------------- weights I/O


def save_cvae(model: GraspCVAE, config: CVAEConfig, path: str | os.PathLike, metadata: dict | None = None) -> Path:
    """Write the weights and config to an ``.npz`` readable without pickle, atomically.

    Every state_dict tensor becomes a float32 array under its state_dict
    name; the entry ``__header__`` holds a JSON string with the format, the
    :class:`CVAEConfig` fields and ``metadata``. The file is written under a
    temporary name in the same folder and renamed, so a reader never sees a
    half-written file.

    Args:
        model: the trained :class:`GraspCVAE`.
        config: its config (must equal ``model.config``).
        path: destination file; its folder is created if missing.
        metadata: JSON-serialisable dict (e.g. corpus provenance, BPS seed
            and radius, training history summary).

    Returns:
        the path written.
    """
    assert config == model.config, (config, model.config)
    header = json.dumps({"format": _FILE_FORMAT, "version": _FILE_VERSION, "config": dataclasses.asdict(config),
                         "metadata": metadata or {}}, sort_keys=True)
    arrays = {name: tensor.detach().cpu().to(torch.float32).numpy() for name, tensor in model.state_dict().items()}
    arrays[_HEADER_KEY] = np.array(header)
    return save_npz(path, arrays)


def load_cvae(path: str | os.PathLike) -> tuple[GraspCVAE, CVAEConfig, dict]:
    """Rebuild a :class:`GraspCVAE` from a file written by :func:`save_cvae`.

    Args:
        path: the ``.npz`` file.

    Returns:
        (model in eval mode on the CPU, float32; its config; the metadata dict).

    Raises:
        FileNotFoundError: no file at ``path``.
        ValueError: not a grasp-CVAE file, an unknown format version or config
            field, missing or unexpected weight names (listed), a weight of the
            wrong shape (named with both shapes), or NaN / inf weights.
    """
    path = Path(path)
    if not path.is_file():
        raise MissingFileError(f"no grasp CVAE weights at {path}")
    entries, header, problem = _read_weights_file(path)
    if problem:
        raise BadValueError(f"{path}{problem}")
    fields = {f.name for f in dataclasses.fields(CVAEConfig)}
    saved = header.get("config", {})
    if set(saved) != fields:
        raise BadValueError(f"{path}: config fields differ from CVAEConfig: unknown {sorted(set(saved) - fields)}, "
                         f"missing {sorted(fields - set(saved))}")
    config = CVAEConfig(**saved)
    model = GraspCVAE(config)
    expected = model.state_dict()
    missing = sorted(set(expected) - set(entries))
    unexpected = sorted(set(entries) - set(expected))
    if missing or unexpected:
        raise BadValueError(f"{path}: weights do not match GraspCVAE({config}): missing keys {missing}, "
                         f"unexpected keys {unexpected}")
    for name, target in expected.items():
        if tuple(entries[name].shape) != tuple(target.shape):
            raise BadValueError(f"{path}: weight {name!r} has shape {tuple(entries[name].shape)}, "
                             f"expected {tuple(target.shape)}")
        if not np.all(np.isfinite(entries[name])):
            raise BadValueError(f"{path}: weight {name!r} contains NaN or inf")
    model.load_state_dict({name: torch.from_numpy(entries[name]).to(expected[name].dtype) for name in expected})
    model.eval()
    return model, config, header.get("metadata", {})


def _read_weights_file(path: Path) -> tuple[dict[str, np.ndarray], dict, str | None]:
    """(the entries but the header, the header, None) of a weights file, or what keeps it from being one as the
    rest of :func:`load_cvae`'s error line."""
    size = path.stat().st_size
    if size == 0:
        return {}, {}, " is empty (0 bytes): not a grasp CVAE weights file"
    if not zipfile.is_zipfile(path):
        # np.load reads any other bytes as a pickle and answers with a message about allow_pickle
        return {}, {}, (f" is not a grasp CVAE weights file: not a zip (.npz) archive ({size} bytes; damaged, "
                        "truncated or another kind of file)")
    try:
        with np.load(path, allow_pickle=False) as npz:
            entries = {name: npz[name] for name in npz.files}
    except (zipfile.BadZipFile, EOFError, ValueError, OSError, zlib.error) as exc:
        # a member whose bytes do not match its CRC, or cut short inside the archive
        return {}, {}, f": damaged grasp CVAE weights file ({type(exc).__name__}: {exc})"
    if _HEADER_KEY not in entries:
        return {}, {}, f" is not a grasp CVAE weights file: no {_HEADER_KEY!r} entry"
    try:
        header = json.loads(str(entries.pop(_HEADER_KEY)[()]))
    except json.JSONDecodeError as exc:
        return {}, {}, f": the {_HEADER_KEY!r} entry is not valid JSON: {exc}"
    if header.get("format") != _FILE_FORMAT or header.get("version") != _FILE_VERSION:
        return {}, {}, (f": expected format {_FILE_FORMAT!r} version {_FILE_VERSION}, got {header.get('format')!r} "
                        f"version {header.get('version')!r}")
    return entries, header, None


def load_shipped_cvae() -> tuple[GraspCVAE, CVAEConfig, dict]:
    """The sampler shipped with the package (:data:`SHIPPED_WEIGHTS`), as :func:`load_cvae`.

    Raises:
        FileNotFoundError: the weights were not trained yet; the message says
            how to train them.
    """
    if not SHIPPED_WEIGHTS.is_file():
        raise MissingFileError(f"the grasp sampler weights {SHIPPED_WEIGHTS} are missing; "
                                f"train them with `{RETRAIN_COMMAND}`")
    return load_cvae(SHIPPED_WEIGHTS)
