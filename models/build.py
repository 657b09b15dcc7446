"""Build models from plain config dicts and load checkpoints strictly (SAM 2's habit).

A model's ``config`` property is the dict it was built from, so a checkpoint
that stores ``model.config`` next to ``model.state_dict()`` rebuilds with
``build_model(config)`` and loads with :func:`load_checkpoint_state`, which
refuses any key or shape that does not match and names every one.
"""

from __future__ import annotations

import inspect
from collections.abc import Mapping
from typing import Any

import torch
from torch import nn

from models.baseline import ResNetRegressor
from models.heatmap import HUPNet
from models.hopenet import HOPENet

__all__ = ["MODEL_REGISTRY", "build_model", "load_checkpoint_state"]

#: config ``name`` -> model class; the remaining config keys are its constructor's arguments
MODEL_REGISTRY: dict[str, type[nn.Module]] = {
    "hopenet": HOPENet,
    "hupnet": HUPNet,
    "resnet_regressor": ResNetRegressor,
}

# how many names an error message lists before it summarises the rest
_MAX_LISTED = 20


def _listing(names: list[str]) -> str:
    shown = ", ".join(names[:_MAX_LISTED])
    if len(names) > _MAX_LISTED:
        shown += f", ... and {len(names) - _MAX_LISTED} more"
    return shown


def build_model(cfg: Mapping[str, Any]) -> nn.Module:
    """Build a registered model from a plain mapping.

    Args:
        cfg: ``{"name": <a key of MODEL_REGISTRY>, **constructor arguments}``, e.g.
            ``{"name": "hopenet", "backbone": "resnet10", "n_keypoints": 29}``. Any Mapping
            works (a dict, an OmegaConf DictConfig); omitted arguments take their defaults.

    Returns:
        The model, freshly initialised, in training mode, on the CPU.
    """
    if not isinstance(cfg, Mapping):
        raise TypeError(f"cfg must be a mapping with a 'name' key, got {type(cfg).__name__}")
    if "name" not in cfg:
        raise ValueError(f"cfg has no 'name'; expected one of: {', '.join(sorted(MODEL_REGISTRY))}")
    name = cfg["name"]
    if name not in MODEL_REGISTRY:
        raise ValueError(f"unknown model {name!r}; known: {', '.join(sorted(MODEL_REGISTRY))}")
    cls = MODEL_REGISTRY[name]
    kwargs = {key: value for key, value in cfg.items() if key != "name"}
    accepted = [p for p in inspect.signature(cls.__init__).parameters if p != "self"]
    unexpected = sorted(set(kwargs) - set(accepted))
    if unexpected:
        raise ValueError(
            f"model {name!r} does not take {', '.join(unexpected)}; it takes: {', '.join(accepted)}"
        )
    return cls(**kwargs)


def load_checkpoint_state(model: nn.Module, state_dict: Mapping[str, torch.Tensor]) -> nn.Module:
    """Load a state dict only when its keys and shapes match the model exactly.

    Args:
        model: the model to fill, e.g. from :func:`build_model` with the checkpoint's config.
        state_dict: parameter and buffer name -> tensor, as ``model.state_dict()`` writes it.

    Returns:
        ``model``, with every parameter and buffer replaced (values are cast to the model's
        dtype and device by ``load_state_dict``).
    """
    if not isinstance(model, nn.Module):
        raise TypeError(f"model must be a torch.nn.Module, got {type(model).__name__}")
    if not isinstance(state_dict, Mapping):
        raise TypeError(f"state_dict must be a mapping of name -> tensor, got {type(state_dict).__name__}")
    expected = model.state_dict()
    missing = sorted(set(expected) - set(state_dict))
    unexpected = sorted(set(state_dict) - set(expected))
    mismatched = []
    for key in sorted(set(expected) & set(state_dict)):
        value = state_dict[key]
        if not isinstance(value, torch.Tensor):
            mismatched.append(f"{key} (not a tensor: {type(value).__name__})")
        elif value.shape != expected[key].shape:
            mismatched.append(f"{key} (checkpoint {tuple(value.shape)}, model {tuple(expected[key].shape)})")
    if missing or unexpected or mismatched:
        problems = []
        if missing:
            problems.append(f"missing keys ({len(missing)}): {_listing(missing)}")
        if unexpected:
            problems.append(f"unexpected keys ({len(unexpected)}): {_listing(unexpected)}")
        if mismatched:
            problems.append(f"shape mismatches ({len(mismatched)}): {_listing(mismatched)}")
        raise ValueError(
            f"checkpoint does not match {type(model).__name__}: " + "; ".join(problems)
        )
    model.load_state_dict(dict(state_dict), strict=True)
    return model
