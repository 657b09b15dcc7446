"""What produced an output: resolved config, git commit, package versions."""

from __future__ import annotations

import importlib.metadata
import platform
import subprocess
import sys
import time
from pathlib import Path

from omegaconf import DictConfig, OmegaConf

PACKAGES = ("hupbench", "numpy", "torch", "trimesh", "pyrender", "PyOpenGL", "opencv-python-headless",
            "hydra-core", "scikit-image", "kornia", "onnx", "onnxruntime")


def git_commit(repo_dir: Path | None = None) -> str:
    """The commit of the source tree this package runs from, with "+dirty" if modified; "unknown" outside git."""
    repo_dir = repo_dir or Path(__file__).resolve().parents[1]
    try:
        sha = subprocess.run(["git", "rev-parse", "HEAD"], cwd=repo_dir, capture_output=True, text=True,
                             timeout=10, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=repo_dir,
                               capture_output=True, text=True, timeout=10, check=True).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return sha + ("+dirty" if dirty else "")


def package_versions(names=PACKAGES) -> dict[str, str]:
    """Installed versions of the packages that shape the results."""
    out = {}
    for name in names:
        try:
            out[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            out[name] = "not installed"
    return out


def run_info(cfg: DictConfig | dict, **extra) -> dict:
    """Provenance record for a run."""
    resolved = OmegaConf.to_container(cfg, resolve=True) if isinstance(cfg, DictConfig) else cfg
    return {
        "config": resolved,
        "git_commit": git_commit(),
        "packages": package_versions(),
        "python": sys.version.split()[0],
        "platform": platform.platform(),
        "time_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        **extra,
    }


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
