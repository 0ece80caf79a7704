"""The harness settings behind a report's numbers, read from each run's ``config.yaml``.

Where the harness differs from the paper or its base system, the difference is a config key
(preset, rasterizer, final refinement, pruning schedule, resolution). A table without them cannot
say which setting produced it, so every report carries them: as columns of ``runs.csv`` and as the
"Harness settings" section of ``tables.md``.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import pandas as pd
import yaml

CONFIG_FILE = "config.yaml"  # written by bench.run.lifecycle next to metrics.json, resolved
# Config keys that decide a comparison, in the order the settings table shows them. The column
# name in runs.csv is the dotted key itself, so a reader can paste it back as an override.
SETTING_KEYS: tuple[str, ...] = (
    "slam.raster_backend", "slam.gsplat_stats", "slam.raster_antialias", "slam.isotropic", "slam.tracking_iters",
    "slam.mapping_iters",
    "slam.mapping_fit_psnr_db", "slam.mapping_schedule", "slam.mapping_draw", "slam.kf_every", "slam.refine_iters",
    "slam.refine_lr_final", "slam.densify_silhouette", "slam.densify_stride", "slam.init_opacity",
    "prune.target", "prune.n_target", "prune.n_target_per_mpx", "prune.n_target_floor_per_px", "prune.every",
    "prune.grad_source",
    "dataset.downscale", "dataset.width", "dataset.height", "dataset.n_frames", "dataset.first", "dataset.last",
    "dataset.stride", "dataset.route", "dataset.route_file", "max_frames",
    "threads", "determinism", "eval.protocol",
)  # fmt: skip


def _lookup(cfg: dict[str, Any], dotted: str) -> Any:
    node: Any = cfg
    for part in dotted.split("."):
        if not isinstance(node, dict) or part not in node:
            return None
        node = node[part]
    return node


# What a run read: the image size and the frame window. Runs that differ here measured another input, so they
# are other table rows (``input_label``), never seeds of one.
INPUT_KEYS: tuple[str, ...] = (
    "dataset.downscale", "dataset.width", "dataset.height", "dataset.first", "dataset.last", "dataset.n_frames",
    "dataset.stride", "max_frames",
)  # fmt: skip


def input_label(cfg: dict[str, Any]) -> str:
    """The ``INPUT_KEYS`` a run's config sets, as ``key=value`` joined by ", " (``dataset.downscale=2,
    dataset.stride=3, max_frames=100``); "" where it sets none. A label of the run alone, so that any subset of a
    table's runs selects by it alike; ``bench.report.variants`` names in a row's label only the parts that differ."""
    parts = []
    for key in INPUT_KEYS:
        value = _lookup(cfg, key)
        if value is not None:
            parts.append(f"{key}={_short(value)}")
    return ", ".join(parts)


# Config groups of the memory policies (issue 44): a run whose values there differ from SlamConfig's
# defaults measured another system than today's, so its rows never pool with today's runs.
POLICY_SECTIONS: tuple[str, ...] = ("keyframes", "densify", "residency")


def _flat(prefix: str, node: Any) -> dict[str, Any]:
    if isinstance(node, dict):
        out: dict[str, Any] = {}
        for key, value in node.items():
            out.update(_flat(f"{prefix}.{key}", value))
        return out
    return {prefix: node}


def policy_label(slam: Any) -> str:
    """The memory policy a run's ``slam`` config names: every key of ``POLICY_SECTIONS`` whose value
    differs from ``SlamConfig``'s default, as ``section.key=value`` joined by ", "; "" for today's
    policy (every key at its default, or a config from before the sections existed)."""

    from bench.slam.config import SlamConfig

    defaults = SlamConfig()
    if not isinstance(slam, dict):
        return ""
    changed = []
    for section in POLICY_SECTIONS:
        default = getattr(defaults, section, None)
        if section not in slam or not dataclasses.is_dataclass(default) or isinstance(default, type):
            continue
        base = _flat(section, dataclasses.asdict(default))
        for key, value in _flat(section, slam[section]).items():
            if key not in base or value != base[key]:
                changed.append(f"{key}={value}")
    return ", ".join(changed)


def _short(value: Any) -> str:
    return f"{value:g}" if isinstance(value, float) else str(value)


def _section(node: dict[str, Any], key: str) -> dict[str, Any]:
    value = node.get(key)
    return value if isinstance(value, dict) else {}


def pruning_label(cfg: dict[str, Any]) -> str:
    """How a run pruned where it differs from the studies' usual schedule (a keep ratio of the candidates after
    each keyframe, the strategy's default parameters): an absolute N_tar (``N_tar 80000``, ``N_tar 166223/Mpx``,
    ``floor 1/px``), ``prune.every`` and ``prune.grad_source`` where set otherwise, and each strategy parameter that
    differs from its default (``rank=random``), joined by ", "; "" for the usual schedule, for ``none`` (which
    prunes nothing whatever ``prune`` says), and for a strategy that is no longer installed (its defaults are
    unknown; its parameters are then named in full).

    Why: two runs of one strategy at two budgets, or with two parameter sets, are two table rows, never seeds of
    one; the keep ratio has its own column and is not repeated here."""
    from bench.slam.strategy import PruneConfig, StrategyError, strategy_class

    strategy = _section(cfg, "strategy")
    name = str(strategy.get("name") or "")
    if name in ("", "none"):
        return ""
    prune = _section(cfg, "prune")
    parts = []
    if prune.get("target") == "absolute":
        if prune.get("n_target") is not None:
            parts.append(f"N_tar {_short(prune['n_target'])}")
        if prune.get("n_target_per_mpx") is not None:
            parts.append(f"N_tar {_short(prune['n_target_per_mpx'])}/Mpx")
        if prune.get("n_target_floor_per_px") is not None:
            parts.append(f"floor {_short(prune['n_target_floor_per_px'])}/px")
    usual = PruneConfig()
    for key in ("every", "grad_source"):
        if key in prune and prune[key] != getattr(usual, key):
            parts.append(f"{key}={_short(prune[key])}")
    params = _section(strategy, "params")
    try:
        defaults = dataclasses.asdict(strategy_class(name)())
    except (StrategyError, TypeError):
        defaults = {}
    parts += [f"{k}={_short(v)}" for k, v in params.items() if k not in defaults or defaults[k] != v]
    return ", ".join(parts)


def read_settings(run_dir: Path, device: str | None) -> dict[str, Any]:
    """The ``SETTING_KEYS`` of one run (None where its config lacks a key or has no config), and its
    ``memory_policy`` (``policy_label``), ``pruning`` (``pruning_label``) and ``input`` (``input_label``).

    ``slam.raster_backend=auto`` is written as the backend it chose on the run's device, because
    ``auto`` means different kernels on CPU and CUDA.
    """
    try:
        cfg = yaml.safe_load((Path(run_dir) / CONFIG_FILE).read_text(encoding="utf-8"))
    except (OSError, yaml.YAMLError):
        cfg = None
    if not isinstance(cfg, dict):
        return {**dict.fromkeys(SETTING_KEYS), "memory_policy": None, "pruning": None, "input": None}
    row = {key: _lookup(cfg, key) for key in SETTING_KEYS}
    row["memory_policy"] = policy_label(cfg.get("slam"))
    row["pruning"] = pruning_label(cfg)
    row["input"] = input_label(cfg)
    if row["slam.raster_backend"] == "auto" and device:
        chosen = "fused" if str(device).startswith("cpu") else "torch"
        row["slam.raster_backend"] = f"auto ({chosen})"
    return row


def _values(column: pd.Series) -> str:
    seen = [v for v in dict.fromkeys(column.tolist()) if not pd.isna(v)]  # None, NaN and pd.NA alike
    return ", ".join(str(v) for v in seen) if seen else "—"


def settings_markdown(runs: pd.DataFrame) -> str:
    """One row per (dataset, preset): each setting's values over its runs; columns every run lacks
    are left out."""
    keys = [k for k in SETTING_KEYS if k in runs and runs[k].notna().any()]
    if runs.empty or not keys:
        return ""
    lines = [
        "## Harness settings",
        "",
        "The config keys that decide a comparison, as the runs of each preset used them "
        "(several values: the runs differ; `—`: not set).",
        "",
        "| dataset | preset | runs | " + " | ".join(f"`{k}`" for k in keys) + " |",
        "|" + "---|" * (3 + len(keys)),
    ]
    for (dataset, preset), group in runs.groupby(["dataset", "slam_preset"], sort=True):
        cells = [_values(group[k]) for k in keys]
        lines.append(f"| {dataset} | {preset} | {len(group)} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


# what one table cell pools (a table holds one eval.protocol: bench.report.tables.build_tables)
POOL_KEYS: tuple[str, ...] = (
    "dataset", "seq", "strategy", "keep_ratio", "slam_preset", "memory_policy", "pruning", "input", "eval_protocol",
)  # fmt: skip


def mixed_settings(runs: pd.DataFrame) -> list[str]:
    """A warning per table cell whose runs differ in a setting: a cell pools seeds of one
    (dataset, sequence, strategy, keep ratio, preset), so runs at two resolutions (say) would be
    averaged as if they were seeds. Report such sweeps into separate folders."""
    keys = [k for k in SETTING_KEYS if k in runs]
    if runs.empty or not keys:
        return []
    warnings = []
    for cell, group in runs.groupby([k for k in POOL_KEYS if k in runs], dropna=False, sort=True):
        differ = [f"{k} ({_values(group[k])})" for k in keys if len({str(v) for v in group[k]}) > 1]
        if differ:
            name = "/".join("-" if pd.isna(v) else str(v) for v in cell)
            warnings.append(f"{name}: {len(group)} runs pooled as seeds differ in {', '.join(differ)}")
    return warnings
