"""``python -m bench.list_strategies``: installed pruning strategies, with description and origin."""

from __future__ import annotations

from bench.config import plugins as registry
from bench.errors import BenchError
from bench.slam.strategy import GROUP, load_strategy


def rows() -> list[tuple[str, str, str]]:
    """``(name, description, origin)`` per installed strategy; a broken plugin says why in its row."""
    out = []
    for name, origin in registry.describe(GROUP):
        try:
            desc = type(load_strategy(name)).description or "(no description)"
        except BenchError as exc:
            desc = f"(broken: {exc})"
        out.append((name, desc, origin))
    return out


def main() -> int:
    table = rows()
    width = max((len(n) for n, _, _ in table), default=4)
    for name, desc, origin in table:
        print(f"{name:<{width}}  {desc}\n{'':<{width}}  from {origin}")
    return 0
