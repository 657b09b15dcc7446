"""What produced an output: the resolved config, the git commit (and whether the package code differs from it),
the package versions, the machine; and run names, which name results files and exported models."""

from __future__ import annotations

import importlib.metadata
import platform
import re
import subprocess
import sys
import time
from pathlib import Path

from omegaconf import DictConfig, OmegaConf

from hupbench.core.errors import BadValueError, RunFailedError

#: the source tree this package runs from (an editable install's checkout)
SOURCE_TREE = Path(__file__).resolve().parents[1]
#: the folders of the installed packages in that tree (pyproject.toml's package-dir)
PACKAGE_DIRS = ("hupbench", "core", "datagen", "models", "conf")
#: changed files a refusal names, at most
SHOWN_FILES = 8
#: a run name is also a results file stem: no separators, no leading dot, nothing a shell would need quoted
RUN_NAME_PATTERN = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,127}$")
PACKAGES = ("hupbench", "numpy", "torch", "trimesh", "pyrender", "PyOpenGL", "opencv-python-headless",
            "hydra-core", "scikit-image", "kornia", "onnx", "onnxruntime")


def changed_package_files(repo_dir: Path | None = None) -> list[str] | None:
    """The files of the installed packages (:data:`PACKAGE_DIRS`) that differ from the checked-out commit: modified,
    staged, deleted or new and not ignored, as paths relative to the tree, sorted; None outside a git checkout.

    Args:
        repo_dir: the source tree (default: the one this package runs from, :data:`SOURCE_TREE`).
    """
    try:
        status = subprocess.run(["git", "status", "--porcelain", "--untracked-files=all", "--", *PACKAGE_DIRS],
                                cwd=repo_dir or SOURCE_TREE, capture_output=True, text=True, timeout=10, check=True)
    except (OSError, subprocess.SubprocessError):
        return None
    # "XY PATH" or "XY OLD -> NEW" (a rename): the path as it is now
    return sorted({line[3:].split(" -> ")[-1].strip('"') for line in status.stdout.splitlines() if line.strip()})


def git_commit(repo_dir: Path | None = None) -> str:
    """The commit of the source tree this package runs from, with "+dirty" if its package code differs from it
    (:func:`changed_package_files`); "unknown" outside git."""
    try:
        sha = subprocess.run(["git", "rev-parse", "HEAD"], cwd=repo_dir or SOURCE_TREE, capture_output=True, text=True,
                             timeout=10, check=True).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return sha + ("+dirty" if changed_package_files(repo_dir) else "")


def refuse_uncommitted_package(what: str, repo_dir: Path | None = None) -> None:
    """Refuse to write ``what`` (e.g. a leaderboard row) from a source tree whose package code has uncommitted
    changes: its ``git_commit`` would not reproduce it.

    Raises:
        RunFailedError: naming the changed files (the first :data:`SHOWN_FILES`) and the cure.
    """
    changed = changed_package_files(repo_dir)
    if changed:
        shown = ", ".join(changed[:SHOWN_FILES]) + (f" and {len(changed) - SHOWN_FILES} more"
                                                    if len(changed) > SHOWN_FILES else "")
        raise RunFailedError(f"{what} must be reproducible from its commit, but the package code has uncommitted "
                             f"changes in {repo_dir or SOURCE_TREE}: {shown}; commit them first, or write the "
                             f"results outside leaderboard/results/")


def check_run_name(name, what: str) -> str:
    """``name`` when it is a run name (:data:`RUN_NAME_PATTERN`), as eval and export check one where a user hands it
    in; ``what`` names it in the error (e.g. "--run-name")."""
    if not isinstance(name, str) or not RUN_NAME_PATTERN.match(name):
        raise BadValueError(f"{what} must be a run name: a file stem of letters, digits, '.', '_' and '-' that "
                            f"starts with a letter or digit, at most 128 characters, got {name!r:.80}")
    return name


def default_run_name(recorded, path: str | Path) -> str:
    """A run name from a recorded one (a training config's ``run_name``, an ONNX file's metadata; ignored when not
    a non-blank string), else the file stem of ``path``: characters outside ``[A-Za-z0-9._-]`` become "_", leading
    "._-" go, at most 128 characters, "model" when nothing is left."""
    name = recorded if isinstance(recorded, str) and recorded.strip() else Path(path).stem
    clean = "".join(c if c.isascii() and (c.isalnum() or c in "._-") else "_" for c in name).lstrip("._-")
    return clean[:128] or "model"


def package_versions(names=PACKAGES) -> dict[str, str]:
    """Installed versions of the packages that shape the results."""
    out = {}
    for name in names:
        try:
            out[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            out[name] = "not installed"
    return out


def run_provenance(**extra) -> dict:
    """Where and with what a run ran: the git commit, package versions, Python, platform and the time (UTC), with
    ``extra`` fields; the record a dataset's manifest and an export carry beside their own config."""
    return {
        "git_commit": git_commit(),
        "packages": package_versions(),
        "python": sys.version.split()[0],
        "platform": platform.platform(),
        "time_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        **extra,
    }


def run_info(cfg: DictConfig | dict, **extra) -> dict:
    """Provenance record for a run: its resolved config and :func:`run_provenance`."""
    resolved = OmegaConf.to_container(cfg, resolve=True) if isinstance(cfg, DictConfig) else cfg
    return {"config": resolved, **run_provenance(**extra)}


def hardware_description(device) -> str:
    """One line naming the machine a run used (the leaderboard's hardware column); ``device`` a torch.device."""
    import torch

    if device.type == "cuda":
        return f"{torch.cuda.get_device_name(device)} (CUDA {torch.version.cuda})"
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"CPU: {cpu}, {torch.get_num_threads()} threads"
