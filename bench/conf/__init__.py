"""The Hydra configs, shipped inside the package so a wheel install finds them (``pkg://bench.conf``).

A user's own configs go in ``./conf/`` (the current directory's), which Hydra searches first
(``hydra_plugins/pocketbench_searchpath``): same layout, and a file named like a shipped one wins.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

CONF_DIR = Path(__file__).resolve().parent
USER_CONF = "conf"  # relative to the current directory


def user_conf_dir() -> Path | None:
    """``./conf`` as an absolute path when it is a directory (and not this package's own dir)."""
    path = (Path.cwd() / USER_CONF).resolve()
    return path if path.is_dir() and path != CONF_DIR else None


def group_files(group: str) -> dict[str, Path]:
    """Option name -> the file Hydra reads for ``group=NAME``: ``./conf`` first, then the package."""
    found = {p.stem: p for p in sorted((CONF_DIR / group).glob("*.yaml"))}
    user = user_conf_dir()
    if user is not None:
        found.update({p.stem: p for p in sorted((user / group).glob("*.yaml"))})
    return found


def config_files(choices: Mapping[str, str | None]) -> dict[str, str]:
    """``group -> file`` for the groups a run picked (Hydra's ``runtime.choices``), so the run records
    whether a user's ``./conf`` file or a shipped one was used; a choice with no file is a schema."""
    out = {}
    for group, name in sorted(choices.items()):
        if name is None or group.startswith("hydra/") or group == "hydra":
            continue
        path = group_files(group).get(str(name))
        out[group] = str(path) if path is not None else f"config store: {group}/{name}"
    return out
