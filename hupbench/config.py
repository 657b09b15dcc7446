"""Composing the packaged Hydra configs for the CLI verbs and the tests."""

from __future__ import annotations

from importlib import resources
from pathlib import Path
from typing import Sequence

from omegaconf import DictConfig, OmegaConf
from datagen.errors import BadValueError, MissingFileError, UserError

HYDRA_VERSION_BASE = "1.3"


def _focal_px(focal_mm: float, sensor_mm: float, width: int, height: int) -> float:
    """``${focal_px:FOCAL_MM,SENSOR_MM,WIDTH,HEIGHT}``: the focal length in pixels of a lens on a sensor
    fitted to the larger image side (:meth:`datagen.camera.Intrinsics.from_lens`)."""
    from datagen.camera import Intrinsics

    if not all(_is_positive_whole(v) for v in (width, height)):
        return float("nan")  # the config's own check names the bad width or height, which it checks first
    return Intrinsics.from_lens(float(focal_mm), float(sensor_mm), int(width), int(height)).fx


def _centre_px(side: int) -> float:
    """``${centre_px:SIDE}``: the principal point of an image side, pixels (its middle)."""
    return int(side) / 2.0 if _is_positive_whole(side) else float("nan")


def _is_positive_whole(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value > 0


# the camera configs derive fx, fy, cx, cy from the lens and the image size, so that changing the image
# size keeps the field of view
OmegaConf.register_new_resolver("focal_px", _focal_px, replace=True)
OmegaConf.register_new_resolver("centre_px", _centre_px, replace=True)


def config_dir() -> Path:
    """Directory holding the Hydra configs (``conf/`` of the source tree, shipped as ``hupbench.conf``).

    A source checkout's own ``conf/`` (beside this package) wins over the installed mapping, so that
    code imported from a checkout (``PYTHONPATH``, a git worktree) composes that checkout's configs.
    """
    beside = Path(__file__).resolve().parents[1] / "conf"
    if (beside / "quickstart.yaml").is_file():
        return beside
    path = Path(str(resources.files("hupbench.conf")))
    if not (path / "quickstart.yaml").is_file():
        raise MissingFileError(f"hupbench configs not found in {path}: is the package installed completely?")
    return path


def compose(config_name: str, overrides: Sequence[str] = ()) -> DictConfig:
    """The config ``conf/<config_name>.yaml`` with Hydra's ``key=value`` overrides, as the CLI composes it,
    read-only."""
    from hydra import compose as hydra_compose
    from hydra import initialize_config_dir

    bad = [o for o in overrides if "=" not in o]
    if bad:
        raise BadValueError(f"overrides must look like key=value, got {bad}")
    with initialize_config_dir(config_dir=str(config_dir()), version_base=HYDRA_VERSION_BASE):
        cfg = hydra_compose(config_name=config_name, overrides=list(overrides))
    OmegaConf.set_readonly(cfg, True)
    return cfg


def build(node):
    """``hydra.utils.instantiate`` with plain containers, re-raising the constructor's own error.

    Hydra wraps a ValueError raised by a config dataclass in InstantiationException; the
    verbs and their tests want the original, which names the bad field (a constructor outside
    datagen and hupbench refusing a value becomes a :class:`BadValueError` with its message).
    """
    from hydra.errors import InstantiationException
    from hydra.utils import instantiate

    try:
        return instantiate(node, _convert_="all")
    except InstantiationException as exc:
        cause = exc.__cause__
        if isinstance(cause, UserError):
            raise cause from None
        if isinstance(cause, (ValueError, TypeError)):  # a constructor of models/ or torch refusing a value
            raise BadValueError(str(cause)) from None
        raise


def build_group(node, group: str):
    """One group of a run node that builds its own groups (``_recursive_: false``, so that the run checks
    its fields first): ``node`` built by its ``_target_``, or passed through when given built. Its error
    names the group, as the class names only its field."""
    if not isinstance(node, (dict, DictConfig)):
        return node
    try:
        return build(node)
    except ValueError as exc:
        raise BadValueError(f"{group}: {exc}") from None
