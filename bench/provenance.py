"""Where a result came from: code version, packages, device, config hash."""

from __future__ import annotations

import hashlib
import json
import platform
import subprocess
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any

import torch

PACKAGES = ("pocketbench", "torch", "numpy", "evo", "torchmetrics", "hydra-core", "opencv-python-headless")
REPO = Path(__file__).resolve().parents[1]


def _git(*args: str) -> str | None:
    try:
        out = subprocess.run(["git", *args], cwd=REPO, capture_output=True, text=True, timeout=5)
    except (OSError, subprocess.TimeoutExpired):
        return None
    return out.stdout.strip() if out.returncode == 0 else None


def collect(device: torch.device) -> dict[str, Any]:
    versions = {}
    for name in PACKAGES:
        try:
            versions[name] = version(name)
        except PackageNotFoundError:
            versions[name] = None
    status = _git("status", "--porcelain", "--untracked-files=no")
    return {
        "git_commit": _git("rev-parse", "HEAD"),
        "git_dirty": bool(status) if status is not None else None,
        "versions": versions,
        "device": str(device),
        "device_name": torch.cuda.get_device_name(device) if device.type == "cuda" else platform.processor() or "cpu",
        "torch_threads": torch.get_num_threads(),
        "python": platform.python_version(),
        "hostname": platform.node(),
    }


# what a result depends on (the configs live in bench/conf)
CODE_PATHS = ("bench", "strategies", "hydra_plugins", "pyproject.toml")


def code_version() -> dict[str, Any]:
    """Commit, dirty flag and a hash of the uncommitted code diff (``None`` outside a git checkout).

    The diff hash makes two different uncommitted edits on one commit two code versions.
    """
    commit = _git("rev-parse", "HEAD")
    status = _git("status", "--porcelain", "--untracked-files=no", "--", *CODE_PATHS)
    dirty = bool(status) if status is not None else None
    diff = _git("diff", "HEAD", "--", *CODE_PATHS) if dirty else None
    try:
        package = version("pocketbench")
    except PackageNotFoundError:
        package = None
    return {
        "git_commit": commit,
        "git_dirty": dirty,
        "diff_sha": hashlib.sha256(diff.encode()).hexdigest()[:12] if diff else None,
        "package": package,
    }


def config_hash(cfg: dict[str, Any]) -> str:
    """Stable hash of the result-affecting config (what 'the same run' means for resume)."""
    blob = json.dumps(cfg, sort_keys=True, default=str)
    return hashlib.sha256(blob.encode()).hexdigest()[:12]
