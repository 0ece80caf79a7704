"""No pruning: the paper's LSG-SLAM baseline row."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from bench.api import Strategy


@dataclass
class NoPruning(Strategy):
    """Every hook is the base no-op: the map keeps every Gaussian it ever adds."""

    description: ClassVar[str] = "no pruning (LSG-SLAM baseline)"
