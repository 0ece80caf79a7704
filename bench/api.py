"""Everything a pruning-strategy plugin needs, in one place: ``from bench.api import ...``.

The contract is this module, not the backend's internals: the shipped strategies (``strategies/``)
import from here only (``tests/test_imports.py`` holds them to it), so ``bench.slam`` can change
its layout without breaking a plugin. What each name means: ``bench/slam/strategy.py`` (the hooks and
their contexts), ``bench/slam/gaussians.py`` (the map a context carries), ``bench/slam/raster.py``
(the render statistics).
"""

from __future__ import annotations

from bench.errors import ConfigError, StrategyError
from bench.slam.gaussians import GaussianMap, ParamSpec
from bench.slam.raster import TILE_PX, RasterOutput
from bench.slam.strategy import (
    MappingContext,
    PruneConfig,
    PruneContext,
    Strategy,
    TrackingContext,
    check,
    check_choice,
    is_int,
    top_k_keep,
)

__all__ = [
    "TILE_PX",
    "ConfigError",
    "GaussianMap",
    "MappingContext",
    "ParamSpec",
    "PruneConfig",
    "PruneContext",
    "RasterOutput",
    "Strategy",
    "StrategyError",
    "TrackingContext",
    "check",
    "check_choice",
    "is_int",
    "top_k_keep",
]
