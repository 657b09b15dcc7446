"""Rebuild a model from its saved config and load checkpoint weights strictly (SAM 2's habit).

A model's ``config`` is the frozen dataclass it was built from; a checkpoint stores ``config.saved()``
(its fields and its name) next to ``model.state_dict()``, rebuilds with :func:`build_model` and loads with
:func:`load_checkpoint_state`, which refuses any key or shape that does not match and names every one.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import fields
from typing import Any

import torch
from torch import nn

from hupbench.models.baseline import ResNetRegressor, ResNetRegressorConfig
from hupbench.models.heatmap import HUPNet, HUPNetConfig
from hupbench.models.hopenet import HOPENet, HOPENetConfig

__all__ = ["MODELS", "build_model", "load_checkpoint_state"]

#: a saved config's ``name`` -> (config class, model class)
MODELS: dict[str, tuple[type, type[nn.Module]]] = {
    config.name: (config, model)
    for config, model in ((HOPENetConfig, HOPENet), (HUPNetConfig, HUPNet), (ResNetRegressorConfig, ResNetRegressor))
}

# how many names an error message lists before it summarises the rest
_MAX_LISTED = 20


def _listing(names: list[str]) -> str:
    shown = ", ".join(names[:_MAX_LISTED])
    if len(names) > _MAX_LISTED:
        shown += f", ... and {len(names) - _MAX_LISTED} more"
    return shown


def build_model(saved: Mapping[str, Any]) -> nn.Module:
    """The model of a saved config, ``Model(ModelConfig(**fields))``, freshly initialised.

    Args:
        saved: ``{"name": <a key of MODELS>, **config fields}`` (:meth:`hupbench.models.model_config.ModelConfig.saved`,
            a checkpoint's ``model_config``), e.g. ``{"name": "hopenet", "backbone": "resnet10"}``;
            omitted fields take their defaults.

    Returns:
        The model, in training mode, on the CPU.
    """
    name = saved.get("name")
    if name not in MODELS:
        raise ValueError(f"unknown model {name!r}; known: {', '.join(sorted(MODELS))}")
    config, model = MODELS[name]
    known = [f.name for f in fields(config)]
    unexpected = sorted(set(saved) - set(known) - {"name"})
    if unexpected:
        raise ValueError(f"model {name!r} does not take {', '.join(unexpected)}; it takes: {', '.join(known)}")
    built = config(**{key: value for key, value in saved.items() if key != "name"})
    for name, part in (("probe_fit", "the probe"), ("hand_fit", "the hand")):
        if getattr(built, name) == "depth" and built.input_channels != 4:  # the channels are filled in after composition
            raise ValueError(f"{name} 'depth' fits {part} to the depth input: it needs "
                             "data.reader.input_modalities=rgb+depth")
    return model(built)


def load_checkpoint_state(model: nn.Module, state_dict: Mapping[str, torch.Tensor]) -> nn.Module:
    """Load a state dict only when its keys and shapes match the model exactly.

    Args:
        model: the model to fill, e.g. from :func:`build_model` with the checkpoint's config.
        state_dict: parameter and buffer name -> tensor, as ``model.state_dict()`` writes it.

    Returns:
        ``model``, with every parameter and buffer replaced (values are cast to the model's
        dtype and device by ``load_state_dict``).
    """
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
    problems = [f"{what} ({len(keys)}): {_listing(keys)}" for what, keys in
                (("missing keys", missing), ("unexpected keys", unexpected), ("shape mismatches", mismatched)) if keys]
    if problems:
        raise ValueError(f"checkpoint does not match {type(model).__name__}: " + "; ".join(problems))
    model.load_state_dict(dict(state_dict), strict=True)
    return model
