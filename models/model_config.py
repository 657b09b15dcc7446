"""What every model's config shares: a frozen dataclass that checks its fields once, saved as a plain dict.

A model is built one way, ``Model(ModelConfig(**fields))`` (nanoGPT's ``GPT(GPTConfig(**args))``): training
gets the config from its Hydra node (``_target_: hupbench.models.hopenet.HOPENetConfig``), and a checkpoint, eval and
export rebuild it from the saved dict (:meth:`ModelConfig.saved`, :func:`hupbench.models.build.build_model`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, fields
from typing import Any, ClassVar

import torch

from hupbench.core import keypoints as kp
from hupbench.core.input_checks import (check_bool_fields, check_choice, check_finite_points, check_int,
                                        check_number)
from hupbench.models.resnet import check_backbone

#: what may run after a model's network on its output (:attr:`ModelConfig.probe_fit`, :attr:`ModelConfig.hand_fit`)
FITS = ("none", "depth")


def nested(value: Any) -> Any:
    """Lists (JSON, a Hydra list) as tuples all the way down, so that a frozen config is immutable."""
    return tuple(nested(v) for v in value) if isinstance(value, (list, tuple)) else value


def plain(value: Any) -> Any:
    """Tuples as lists all the way down: the saved form (JSON and a checkpoint hold lists)."""
    return [plain(v) for v in value] if isinstance(value, (list, tuple)) else value


def plain_tree(value: Any) -> Any:
    """A mapping (a Hydra node's too) as a dict and a sequence as a list, all the way down: a config field that
    holds a tree (:attr:`ModelConfig.fit_settings`) in the form a checkpoint and JSON hold."""
    if isinstance(value, Mapping):
        return {k: plain_tree(v) for k, v in value.items()}
    if isinstance(value, Sequence) and not isinstance(value, (str, bytes)):
        return [plain_tree(v) for v in value]
    return value


def check_camera(K_input: Any, input_size: Any, multiple: int = 1) -> None:
    """K_input a finite (3, 3) intrinsics matrix with fx, fy > 0 (pixels of the model input); input_size
    a positive multiple of ``multiple``."""
    K = torch.as_tensor(K_input, dtype=torch.float64)
    if K.shape != (3, 3) or not torch.isfinite(K).all() or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise ValueError(f"K_input must be a finite (3, 3) intrinsics matrix with fx, fy > 0, got {K.tolist()}")
    check_int(input_size, "input_size", 1)
    if input_size % multiple:
        raise ValueError(f"input_size must be a positive multiple of {multiple}, got {input_size!r}")


@dataclass(frozen=True)
class ModelConfig:
    """The fields every model has.

    Attributes:
        backbone: ResNet name: "resnet10", "resnet18", "resnet34" or "resnet50".
        n_keypoints: N, keypoints predicted (29 = 21 hand joints + 8 probe corners).
        zero_init_residual: zero the last BN of each residual branch of the backbone.
        points3d_mean: (N, 3) prior keypoint layout added to the 3D output (:mod:`hupbench.models.prior`), e.g. the
            training split's mean in metres; None for zeros.
        points3d_scale: target units per raw 3D output unit.
        input_channels: C, channels of the input image: 3 (RGB) or 4 (RGB and the depth channel of
            :func:`hupbench.input_geometry.depth_channel`); training sets it from ``data.reader.input_modalities``.
        probe_fit: what runs after the network on its output: "none", or "depth" (the probe's corners refined by
            fitting the probe's surface to the depth input, :mod:`hupbench.fits.probe_fit`; needs
            ``input_channels`` 4). Eval and predict run it; training and its validation curve do not.
        hand_fit: the same for the hand: "none", or "depth" (the 21 joints refined by fitting a capsule hand to
            the depth input, :mod:`hupbench.fits.hand_fit`, after the probe's fit where both are asked).
        fit_settings: the fits' settings this model changes from the defaults, chosen on its track's val split:
            ``{"hand": {"iterations": 16}}``: fields of :class:`hupbench.fits.HandFitSettings` /
            :class:`~hupbench.fits.ProbeFitSettings` of a fit the model runs, checked where a training config is
            built (:class:`hupbench.training.run_config.TrainRun`) and where the fits read them
            (:func:`hupbench.fits.model_fit_settings`); None or {}: the defaults. Saved with the config, so that
            eval, export and predict run them.
        hand_templates: (T, 21, 3) the training split's hands, metres, one per training grasp (:func:`hupbench.fits.
            hand_fit.training_hands`): where the model fits the hand (``hand_fit: depth``) the fit starts from the one
            nearest the network's joints (:attr:`hupbench.fits.HandFitSettings.templates`); training sets them. None:
            the fit starts from the network's joints (every model file before them).
    """

    #: the model's name in a saved config (:data:`hupbench.models.build.MODELS`)
    name: ClassVar[str]
    #: the fewest keypoints the model's layers can take
    min_keypoints: ClassVar[int] = 1

    backbone: str = "resnet18"
    n_keypoints: int = 29
    zero_init_residual: bool = False
    points3d_mean: tuple[tuple[float, float, float], ...] | None = None
    points3d_scale: float = 1.0
    input_channels: int = 3
    probe_fit: str = "none"
    hand_fit: str = "none"
    fit_settings: dict | None = None
    hand_templates: tuple[tuple[tuple[float, float, float], ...], ...] | None = None

    def __post_init__(self) -> None:
        for f in fields(self):
            object.__setattr__(self, f.name, nested(getattr(self, f.name)))
        check_backbone(self.backbone)
        check_int(self.n_keypoints, "n_keypoints", self.min_keypoints)
        check_choice(self.input_channels, "input_channels", (3, 4))  # RGB, or RGB and depth
        for name in ("probe_fit", "hand_fit"):
            check_choice(getattr(self, name), name, FITS)
        object.__setattr__(self, "fit_settings", plain_tree(self.fit_settings) or None)
        check_number(self.points3d_scale, "points3d_scale", 0.0, low_open=True)
        check_bool_fields(self)  # the subclasses' boolean fields too
        if self.points3d_mean is not None:
            mean = torch.as_tensor(self.points3d_mean, dtype=torch.float64)
            if mean.shape != (self.n_keypoints, 3) or not torch.isfinite(mean).all():
                raise ValueError(f"points3d_mean must be a finite ({self.n_keypoints}, 3) layout, got shape "
                                 f"{tuple(mean.shape)}")
            object.__setattr__(self, "points3d_mean", nested(mean.tolist()))
        if self.hand_templates is not None:
            hands = check_finite_points(self.hand_templates, ("T", kp.NUM_HAND, 3), "hand_templates")
            object.__setattr__(self, "hand_templates", nested(hands.tolist()))

    def saved(self) -> dict[str, Any]:
        """``{"name": ..., **fields}`` with lists: what a checkpoint stores and :func:`build_model` takes."""
        return {"name": self.name, **{f.name: plain(getattr(self, f.name)) for f in fields(self)}}
