"""Composing the packaged Hydra configs for the CLI verbs and the tests, and describing their keys for --help."""

from __future__ import annotations

import argparse
import re
import shutil
import textwrap
from collections.abc import Sequence
from importlib import resources
from pathlib import Path

from omegaconf import DictConfig, ListConfig, OmegaConf

from hupbench.core.errors import BadValueError, MissingFileError, UserError
from hupbench.core.input_checks import is_whole

HYDRA_VERSION_BASE = "1.3"


def _focal_px(focal_mm: float, sensor_mm: float, width: int, height: int) -> float:
    """``${focal_px:FOCAL_MM,SENSOR_MM,WIDTH,HEIGHT}``: the focal length in pixels of a lens on a sensor
    fitted to the larger image side (:meth:`hupbench.core.camera.Intrinsics.from_lens`); nan for a side that is
    not a whole number >= 1, which the config's own check then names."""
    from hupbench.core.camera import Intrinsics

    if not all(_is_side(v) for v in (width, height)):
        return float("nan")
    return Intrinsics.from_lens(float(focal_mm), float(sensor_mm), int(width), int(height)).fx


def _centre_px(side: int) -> float:
    """``${centre_px:SIDE}``: the principal point of an image side, pixels (its middle); nan as :func:`_focal_px`."""
    return int(side) / 2.0 if _is_side(side) else float("nan")


def _is_side(value) -> bool:
    return is_whole(value) and value > 0


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
    cfg = _hydra_compose(config_name, overrides)
    OmegaConf.set_readonly(cfg, True)
    return cfg


def _hydra_compose(config_name: str, overrides: Sequence[str], return_hydra_config: bool = False) -> DictConfig:
    from hydra import compose as hydra_compose
    from hydra import initialize_config_dir

    bad = [o for o in overrides if "=" not in o]
    if bad:
        raise BadValueError(f"overrides must look like key=value, got {bad}")
    with initialize_config_dir(config_dir=str(config_dir()), version_base=HYDRA_VERSION_BASE):
        return hydra_compose(config_name=config_name, overrides=list(overrides),
                             return_hydra_config=return_hydra_config)


def config_yaml(config_name: str, overrides: Sequence[str] = (), resolve: bool = False) -> str:
    """What a Hydra app's ``--cfg job`` prints: the composed config as YAML, interpolations kept unless
    ``resolve``."""
    return OmegaConf.to_yaml(compose(config_name, overrides), resolve=resolve)


def described_keys(config_name: str, overrides: Sequence[str] = ()) -> list[tuple[str, str, str]]:
    """Every key of the composed config, in its order, as ``(dotted key, default, meaning)``.

    The default is the composed value written as an override would write it (interpolations unresolved,
    ``???`` for a required value); a node of several keys appears as ``node.*`` with an empty default. The
    meaning is the YAML comment on the key's line or the comment lines right above it, from the first of the
    config files that were composed (in Hydra's order: the base before what overrides it) that has one;
    a block at the top of a file describes the file, not its first key. Hydra's private keys (``_target_``
    ...) are left out.
    """
    cfg = _hydra_compose(config_name, overrides, return_hydra_config=True)
    choices = {group: option for group, option in cfg.hydra.runtime.choices.items()
               if not group.startswith("hydra/") and option is not None}
    files = [(path, prefix, *_yaml_comments(path.read_text())) for path, prefix in _composed_files(config_name, choices)]
    # the chosen config of a group describes the group's node first, before a comment on the node
    meanings = {path.parent.relative_to(config_dir()).as_posix().replace("/", "."): description
                for path, _, description, _ in files
                if description and choices.get(path.parent.relative_to(config_dir()).as_posix()) == path.stem}
    for _, prefix, _, comments in files:
        for key, text in comments.items():
            meanings.setdefault(prefix + key, text)
    rows: list[tuple[str, str, str]] = []

    def walk(node: DictConfig, prefix: str) -> None:
        for key in node:
            if str(key).startswith("_") or (not prefix and key == "hydra"):
                continue
            dotted = f"{prefix}{key}"
            child = node._get_node(key)
            if isinstance(child, DictConfig) and not child._is_interpolation() and not child._is_missing():
                if dotted in meanings:
                    rows.append((f"{dotted}.*", "", meanings[dotted]))
                walk(child, f"{dotted}.")
            else:
                rows.append((dotted, _override_text(child._value()), meanings.get(dotted, "")))

    walk(cfg, "")
    return rows


def _override_text(value) -> str:
    """A composed value as a ``key=value`` override writes it: null, true, [a, b], {k: v}."""
    if isinstance(value, (DictConfig, ListConfig)):
        value = OmegaConf.to_container(value, resolve=False)
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k}: {_override_text(v)}" for k, v in value.items()) + "}"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_override_text(v) for v in value) + "]"
    if value is None:
        return "null"
    if isinstance(value, bool):
        return str(value).lower()
    return str(value)


_KEY_LINE = re.compile(r"^( *)([A-Za-z_][\w-]*)\s*:(?:\s+(.*))?$")


def _yaml_comments(text: str) -> tuple[str, dict[str, str]]:
    """The description of a YAML config file (the comment block that opens it) and ``{dotted key: comment}``:
    the comment lines right above a key (no blank line between) and the comment on its line."""
    meanings: dict[str, str] = {}
    description = ""
    stack: list[tuple[int, str]] = []
    block: list[str] = []
    seen_key = False
    for line in text.splitlines():
        stripped = line.strip()
        if stripped.startswith("# @package"):
            continue
        if stripped.startswith("#"):
            block.append(stripped.lstrip("#").strip())
            continue
        match = _KEY_LINE.match(line)
        if match is None:  # a blank line, a list item or a continued value
            block = []
            continue
        indent, key, rest = len(match.group(1)), match.group(2), match.group(3) or ""
        while stack and stack[-1][0] >= indent:
            stack.pop()
        stack.append((indent, key))
        on_line = re.search(r"(?:^|\s)#\s*(.*)$", rest)
        if not seen_key:
            description, block = " ".join(block), []
        texts = block + ([on_line.group(1)] if on_line else [])
        if texts:
            meanings[".".join(k for _, k in stack)] = _first_sentence(" ".join(t for t in texts if t))
        seen_key, block = True, []
    return _first_sentence(description), meanings


def _first_sentence(text: str) -> str:
    """A comment cut to its first sentence, when that says something (30 characters or more)."""
    end = re.search(r"(?<=.{30}[.;]) (?=[A-Z])", text)
    return text[: end.start()] if end else text


def _composed_files(config_name: str, choices: dict[str, str]) -> list[tuple[Path, str]]:
    """The YAML files Hydra composed for ``config_name`` with the group ``choices`` (``hydra.runtime.choices``),
    in its order (a file's ``defaults`` before the file unless it lists ``_self_``), each with the prefix
    its keys take (``data.`` for conf/data/*.yaml, none for ``# @package _global_``)."""
    import yaml

    root = config_dir()
    files: list[tuple[Path, str]] = []
    visited_groups: set[str] = set()

    def visit(group: str, name: str) -> None:
        path = root / group / f"{name}.yaml"
        if not path.is_file() or any(path == p for p, _ in files):
            return
        text = path.read_text()
        package = re.search(r"^# @package (\S+)", text, flags=re.MULTILINE)
        if package:
            prefix = "" if package.group(1) == "_global_" else package.group(1) + "."
        else:
            prefix = group.replace("/", ".") + "." if group else ""
        defaults = list((yaml.safe_load(text) or {}).get("defaults") or [])
        for entry in defaults if "_self_" in defaults else [*defaults, "_self_"]:
            if entry == "_self_":
                files.append((path, prefix))
            elif isinstance(entry, str):  # another config of the same group (or "/name": of the top level)
                visit("" if entry.startswith("/") else group, entry.lstrip("/"))
            elif isinstance(entry, dict) and len(entry) == 1:
                (key, option), = entry.items()
                key = str(key)
                if key.startswith("override "):
                    continue  # the group's choice, where the group was first listed
                key = key.removeprefix("optional ").split("@")[0]
                sub = key.lstrip("/") if key.startswith("/") or not group else f"{group}/{key}"
                visited_groups.add(sub)
                chosen = choices.get(sub, option)
                if chosen is not None:
                    visit(sub, str(chosen))

    visit("", config_name)
    for group, option in choices.items():  # groups added by +group=option, after the config's own
        if group not in visited_groups:
            visit(group, option)
    return files


def keys_help(config_name: str, overrides: Sequence[str] = ()) -> str:
    """The key table of a Hydra verb's ``--help``: each key of the composed config with its default and
    meaning (:func:`described_keys`), wrapped to the terminal."""
    width = _help_width()
    column = 34
    lines = []
    for key, default, meaning in described_keys(config_name, overrides):
        left = f"  {key}" if key.endswith(".*") else f"  {key}={_shortened(default, width - 4)}"
        wrapped = textwrap.wrap(meaning, width - column, break_on_hyphens=False) if meaning else []
        if len(left) <= column - 2 and wrapped:
            lines.append(left.ljust(column) + wrapped.pop(0))
        else:
            lines.append(left)
        lines.extend(" " * column + line for line in wrapped)
    return "\n".join(lines)


def _help_width() -> int:
    return min(max(shutil.get_terminal_size((100, 24)).columns, 80), 120)


def _shortened(text: str, limit: int) -> str:
    return text if len(text) <= limit else text[: limit - 4] + " ..."


def hydra_verb_parser(prog: str, config_name: str, description: str, examples: Sequence[str],
                      overrides: Sequence[str] | None = ()) -> argparse.ArgumentParser:
    """The command line of a verb over ``conf/<config_name>.yaml``: ``key=value`` overrides, ``--cfg job``
    and ``--resolve`` as Hydra apps have them, and a ``--help`` that lists the config's keys with their
    defaults (composed with ``overrides``, where a bad one is an error) and meanings, then ``examples``.
    ``overrides`` None: no key table (composing and reading the YAML files is for a help that was asked for)."""
    keys = "" if overrides is None else (
        f"config keys (conf/{config_name}.yaml composed{' with ' + ' '.join(overrides) if overrides else ''}; "
        f"key=default, then its meaning):\n{keys_help(config_name, overrides)}\n\n")
    epilog = keys + "examples:\n" + "\n".join(f"  {e}" for e in examples)
    width = _help_width() - 2
    parser = argparse.ArgumentParser(prog=prog, description=textwrap.fill(description, width), epilog=epilog,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("overrides", nargs="*", metavar="key=value",
                        help=f"Hydra overrides of conf/{config_name}.yaml: key=value sets a key, group=option picks "
                        "a config of a group, +key=value adds a key")
    parser.add_argument("--cfg", choices=("job",), help="print the composed config (overrides applied) as YAML "
                        "and exit without running")
    parser.add_argument("--resolve", action="store_true", help="with --cfg: resolve the ${...} interpolations")
    return parser


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
