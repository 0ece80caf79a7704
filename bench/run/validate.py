"""Every setting checked before any work, and the run built once from what passed.

Why first: a value checked only where it is used (``eval.ate_align`` after the SLAM loop) lets a bad
setting cost a whole run, or become a result. The rules themselves live on the typed config classes
(``bench.config.settings.setting`` fields and ``__post_init__`` checks), so this module only composes them:
the keys no schema has, the one conversion to ``RunConfig`` (which runs every rule), the strategy
and a given LPIPS checkpoint. It returns what it built, for ``bench.run.lifecycle.run`` to use as it is.
It sits with the run's config, below both of its callers: the command line (``bench.cli.entry``, before
Hydra starts) and ``bench.run.lifecycle.run`` (a run called from Python is validated the same way).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from bench.config.settings import check_rules, plain, unknown_keys
from bench.errors import BenchError, ConfigError
from bench.run.checkpoint import CheckpointConfig
from bench.run.config import (
    EvalConfig,
    MemoryConfig,
    RunConfig,
    StrategyConfig,
    VizConfig,
    dataset_schemas,
    to_run_config,
)
from bench.slam.config import SlamConfig
from bench.slam.strategy import CheckedStrategy, PruneConfig, load_strategy, strategy_class, unknown_params


@dataclass
class ValidatedRun:
    """A validated run: its typed config, its resolved tree (what is hashed and stored), its parts."""

    config: RunConfig
    tree: dict[str, Any]
    strategy: CheckedStrategy
    lpips: Any = None  # bench.metrics.lpips.LPIPS from eval.lpips_weights; None: loaded at evaluation if at all


def validate(cfg: Any) -> ValidatedRun:
    """The run ``cfg`` describes, built; the first bad setting is one ``ConfigError`` line.

    Cheap by design (no dataset files are read, no SLAM state is built), so it runs before any work:
    a sweep job that fails here is recorded ``failed`` in seconds.
    """
    tree = {k: v for k, v in plain(cfg).items() if k != "hydra"}
    known = set(RunConfig.__dataclass_fields__)
    if set(tree) - known:
        raise ConfigError(
            f"unknown setting {', '.join(repr(u) for u in sorted(set(tree) - known))}; "
            f"expected one of: {', '.join(sorted(known))}"
        )
    check_rules(tree, "", RunConfig)  # the run's own settings first: a dataset setting may interpolate one
    for group, cls in (
        ("slam", SlamConfig),
        ("prune", PruneConfig),
        ("memory", MemoryConfig),
        ("eval", EvalConfig),
        ("viz", VizConfig),
        ("checkpoint", CheckpointConfig),
    ):
        if isinstance(tree.get(group), Mapping):  # +eval.evry=2 got past composition: say it in these words
            unknown_keys(group, cls, tree[group], deep=True)
    ds = tree.get("dataset")
    if not isinstance(ds, Mapping) or not ds.get("name"):
        raise ConfigError(
            f"dataset: expected a dataset group with a name (dataset=synthetic|kitti|euroc|tum), found {ds!r}"
        )
    ds_schema = dataset_schemas().get(str(ds["name"]))
    if ds_schema is not None:  # a plugin's plain dict has no schema to hold it to
        unknown_keys("dataset", ds_schema, ds, deep=True)
    strategy = tree.get("strategy")
    if strategy is not None and (not isinstance(strategy, Mapping) or not isinstance(strategy.get("name"), str)):
        raise ConfigError(f"strategy: expected a group with a name (+strategy=NAME), found {strategy!r}")
    if strategy is not None:
        unknown_keys("strategy", StrategyConfig, strategy)  # its params are the strategy's own: below
    name = strategy["name"] if strategy else "none"
    unknown_params(name, strategy_class(name), (strategy or {}).get("params") or {})
    conf = to_run_config(cfg)  # every rule of every group runs here, the strategy's own checks included
    params = conf.strategy.params if conf.strategy else None
    built = ValidatedRun(conf, tree, CheckedStrategy(load_strategy(name, params), name))
    if conf.eval.lpips and conf.eval.lpips_weights is not None:  # a broken file would fail after the whole run
        from bench.metrics.lpips import LPIPS

        try:
            built.lpips = LPIPS.from_weights(conf.eval.lpips_weights)
        except BenchError as exc:
            raise ConfigError(f"eval.lpips_weights: {exc}") from None
    return built
