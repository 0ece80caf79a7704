"""Lazy, type-checked plugin lookup over Python entry points.

Plugins are only imported when asked for by name, so a broken third-party plugin cannot
break runs that do not use it. Unknown names get a "did you mean" answer.
"""

from __future__ import annotations

import difflib
from importlib.metadata import EntryPoint, entry_points
from typing import Any

from bench.errors import BenchError


def _entry_points(group: str) -> dict[str, EntryPoint]:
    return {ep.name: ep for ep in entry_points(group=group)}


def available(group: str) -> list[str]:
    """Sorted names registered under ``group``."""
    return sorted(_entry_points(group))


def describe(group: str) -> list[tuple[str, str]]:
    """``(name, origin)`` for each plugin, origin being ``module:attr (distribution)``."""
    rows = []
    for name, ep in sorted(_entry_points(group).items()):
        dist = ep.dist.name if ep.dist is not None else "?"
        rows.append((name, f"{ep.value} ({dist})"))
    return rows


def unknown_name_message(kind: str, name: str, names: list[str]) -> str:
    close = difflib.get_close_matches(name, names, n=1, cutoff=0.5)
    hint = f"; did you mean '{close[0]}'?" if close else ";"
    return f"unknown {kind} '{name}'{hint} available: {', '.join(names) or '(none installed)'}"


def load(group: str, kind: str, name: str, error: type[BenchError]) -> Any:
    """Import the object registered as ``name`` in ``group``; one-line error if unknown."""
    eps = _entry_points(group)
    if name not in eps:
        raise error(unknown_name_message(kind, name, sorted(eps)))
    try:
        return eps[name].load()
    except Exception as exc:  # a third-party plugin failing to import is a known failure
        raise error(f"{kind} '{name}' failed to load from {eps[name].value}: {exc}") from exc
