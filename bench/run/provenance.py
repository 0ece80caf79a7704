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

PACKAGES = (
    "pocketbench",
    "torch",
    "numpy",
    "evo",
    "torchmetrics",
    "hydra-core",
    "opencv-python-headless",
    "numba",
    "llvmlite",
)
REPO = Path(__file__).resolve().parents[2]


def _git(*args: str) -> str | None:
    try:
        out = subprocess.run(["git", *args], cwd=REPO, capture_output=True, text=True, timeout=5)
    except (OSError, subprocess.TimeoutExpired):
        return None
    return out.stdout.strip() if out.returncode == 0 else None


def cpu_target() -> dict[str, str | None]:
    """The instruction sets the compiled kernels were built for.

    numba compiles for the host CPU (or ``NUMBA_CPU_NAME``) and torch dispatches its CPU kernels by
    capability, so one commit and seed can give different floats on two machines (an AVX-512 host
    and an AVX2 one); a figure that does not repeat elsewhere is read against these.
    """
    try:
        import llvmlite.binding as llvm
        import numba

        # numba.config sets its settings through globals() at import, out of a type checker's sight
        numba_cpu = numba.config.CPU_NAME or llvm.get_host_cpu_name()  # type: ignore[attr-defined]
        features = numba.config.CPU_FEATURES or llvm.get_host_cpu_features().flatten()  # type: ignore[attr-defined]
        features_sha = hashlib.sha256(features.encode()).hexdigest()[:12]
    except ImportError:
        numba_cpu = features_sha = None
    return {
        "numba_cpu": numba_cpu,
        # two processors can share a target name (numba_cpu) and still differ in the features the
        # kernels are compiled with, or in the chip: the same code and seed can then part late in a
        # long run (reports/known_limits.md)
        "numba_cpu_features_sha": features_sha,
        "cpu_model": cpu_model(),
        "torch_cpu_capability": torch.backends.cpu.get_cpu_capability(),
    }


def cpu_model() -> str | None:
    """The processor as vendor, family, model and stepping (Linux's /proc/cpuinfo), else platform's word."""
    try:
        first = Path("/proc/cpuinfo").read_text().split("\n\n", 1)[0]
    except OSError:
        return platform.processor() or None
    fields = {k.strip(): v.strip() for k, v in (line.split(":", 1) for line in first.splitlines() if ":" in line)}
    keys = ("vendor_id", "cpu family", "model", "stepping")
    if not all(k in fields for k in keys):
        return platform.processor() or None
    return f"{fields['vendor_id']} family {fields['cpu family']} model {fields['model']} stepping {fields['stepping']}"


def collect(device: torch.device) -> dict[str, Any]:
    versions: dict[str, str | None] = {}
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
        **cpu_target(),
        "python": platform.python_version(),
        "hostname": platform.node(),
    }


# what a result depends on (the configs live in bench/conf); the report code only reads results
# (the figures a run draws into its own dir are the run's: bench/run/figures/)
CODE_PATHS = ("bench", "strategies", "hydra_plugins", "pyproject.toml")
READ_ONLY_PATHS = ("bench/report/",)


def _is_code(path: str) -> bool:
    return not path.startswith(READ_ONLY_PATHS)


def code_version() -> dict[str, Any]:
    """Commit, the code tree's hash, dirty flag and a hash of the uncommitted code diff (``None``
    outside a git checkout).

    ``code_tree`` hashes the committed files under ``CODE_PATHS`` (report code left out), so that a
    commit that touches only docs, tests or reports leaves it, and a finished sweep, as they were.
    The diff hash makes two different uncommitted edits on one commit two code versions.
    """
    paths = [*CODE_PATHS, *(f":(exclude){p}" for p in READ_ONLY_PATHS)]
    commit = _git("rev-parse", "HEAD")
    listing = _git("ls-tree", "-r", "HEAD", "--", *CODE_PATHS)  # ls-tree takes no exclude pathspecs
    tree = (
        None
        if listing is None
        else "\n".join(line for line in listing.splitlines() if _is_code(line.split("\t", 1)[-1]))
    )
    status = _git("status", "--porcelain", "--untracked-files=no", "--", *paths)
    dirty = bool(status) if status is not None else None
    diff = None
    if dirty:
        diff = _git("diff", "HEAD", "--", *paths) or ""
    try:
        package = version("pocketbench")
    except PackageNotFoundError:
        package = None
    return {
        "git_commit": commit,
        "code_tree": hashlib.sha256(tree.encode()).hexdigest()[:12] if tree else None,
        "git_dirty": dirty,
        "diff_sha": hashlib.sha256(diff.encode()).hexdigest()[:12] if diff else None,
        "package": package,
    }


def config_hash(cfg: dict[str, Any]) -> str:
    """Stable hash of the result-affecting config (what 'the same run' means for resume)."""
    blob = json.dumps(cfg, sort_keys=True, default=str)
    return hashlib.sha256(blob.encode()).hexdigest()[:12]
