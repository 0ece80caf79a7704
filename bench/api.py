"""Everything a pruning-strategy plugin needs, in one place: ``from bench.api import ...``.

The contract is this module, not the backend's internals: the shipped strategies (``strategies/``)
import from here only (``tests/test_imports.py`` holds them to it), so ``bench.slam`` can change
its layout without breaking a plugin. What each name means: ``bench/slam/strategy.py`` (the hooks and
their contexts), ``bench/slam/gaussians.py`` (the map a context carries), ``bench/slam/raster.py``
(the render statistics).

A hyperparameter's rule sits on its field: ``budget_min: int = setting(5, "int", lo=0)`` (kinds int,
float, bool, str; ``lo``/``hi`` with ``lo_open``/``hi_open``, ``choices``, ``nullable``); the base
``Strategy.__post_init__`` checks them all as the strategy is built. ``check`` is for a rule between
two fields; ``check_choice`` and ``is_int`` stay for plugins written before ``setting``.
"""

from __future__ import annotations

from bench.config.settings import setting
from bench.errors import ConfigError, StrategyError
from bench.slam.gaussians import GaussianMap, ParamSpec
from bench.slam.raster import EXTRA_STATS, TILE_PX, RasterOutput
from bench.slam.strategy import (
    READS_MAPPING_GRAD2D,
    SCORE_VIEWS,
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
    "EXTRA_STATS",
    "READS_MAPPING_GRAD2D",
    "SCORE_VIEWS",
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
    "setting",
    "top_k_keep",
]
