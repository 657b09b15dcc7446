"""Print the package -> package import counts of the source tree: how the packages lean on each other.

    python3 scripts/import_graph.py            # this checkout
    python3 scripts/import_graph.py --root DIR # another checkout, e.g. an older commit's `git worktree`

Read statically from the code (every ``import`` and ``from ... import`` with an absolute module name, at module
level or inside functions). A package is a subpackage of the installed ``hupbench`` (``hupbench.datagen.render``,
``hupbench.training``); the modules at the top of ``hupbench/`` count as ``hupbench``. Folders are mapped to their
installed names as pyproject.toml's ``package-dir`` maps them (``core/`` -> ``hupbench.core``).
"""

from __future__ import annotations

import argparse
import ast
import tomllib
from collections import Counter
from pathlib import Path


def folders(root: Path) -> dict[str, str]:
    """Repository folder -> installed package name: ``hupbench`` and the checkout's pyproject.toml ``package-dir``."""
    package_dir = tomllib.loads((root / "pyproject.toml").read_text())["tool"]["setuptools"].get("package-dir", {})
    return {"hupbench": "hupbench", **{folder: name for name, folder in package_dir.items()}}


def module_name(root: Path, path: Path, installed: dict[str, str]) -> str:
    """The installed name of the module at ``path`` (``installed``: :func:`folders`)."""
    parts = path.relative_to(root).with_suffix("").parts
    names = [installed[parts[0]], *parts[1:]]
    return ".".join(names[:-1] if names[-1] == "__init__" else names)


def package_of(module: str, packages: set[str]) -> str | None:
    """The deepest package of ``packages`` that holds ``module`` (None: not a project module)."""
    parts = module.split(".")
    return next((".".join(parts[:n]) for n in range(len(parts), 0, -1) if ".".join(parts[:n]) in packages), None)


def import_counts(root: Path) -> Counter:
    """{(package, package it imports): number of import statements}, self-imports left out."""
    installed = folders(root)
    files = [p for folder in installed if (root / folder).is_dir() for p in sorted((root / folder).rglob("*.py"))]
    packages = {module_name(root, p, installed) for p in files if p.name == "__init__.py"}
    counts: Counter = Counter()
    for path in files:
        source = package_of(module_name(root, path, installed), packages)
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module and not node.level:
                targets = [node.module]
            elif isinstance(node, ast.Import):
                targets = [alias.name for alias in node.names]
            else:
                continue
            for target in targets:
                package = package_of(target, packages)
                if package and package != source:
                    counts[source, package] += 1
    return counts


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--root", type=Path, default=Path(__file__).resolve().parents[1], help="the checkout")
    args = parser.parse_args(argv)
    for (source, target), n in sorted(import_counts(args.root).items()):
        print(f"{source:26s} -> {target:26s} {n:4d}")


if __name__ == "__main__":
    main()
