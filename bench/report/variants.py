"""A table's measured rows: which runs pool into one row (``Variant``), in paper order, and its columns."""

from __future__ import annotations

from dataclasses import dataclass

import pandas as pd

from bench.names import method_name, sequence_sort_key, strategy_rank
from bench.report.collect import is_missing


@dataclass(frozen=True)
class Variant:
    """A measured table row: one strategy at one keep ratio on one backend preset, seeds pooled.

    Runs of different ``slam_preset`` values are different rows (labelled ``[preset]``), never pooled:
    the presets re-seed differently, so their averages would mix two systems. So are runs of different
    memory policies (labelled ``+ policy``), and runs that read another input (image size or frame window:
    ``bench.report.settings.input_label``), labelled ``{...}`` with the input keys that differ among the table's runs.
    """

    strategy: str
    keep_ratio: float | None
    label: str
    slam_preset: str = "default"
    memory_policy: str = ""  # bench.report.settings.policy_label; "" = today's keyframe store, densification, residency
    pruning: str = ""  # bench.report.settings.pruning_label; "" = the keep ratio and the strategy's default parameters
    input: str = ""  # bench.report.settings.input_label; "" = not recorded (stored tables from before the column)


def _keep(value: object) -> float | None:
    return None if is_missing(value) else float(value)  # type: ignore[arg-type]


def _presets(runs: pd.DataFrame) -> pd.Series:
    return runs["slam_preset"] if "slam_preset" in runs else pd.Series("default", index=runs.index)


def _policies(runs: pd.DataFrame) -> pd.Series:
    """Each run's memory policy; "" for runs (or stored tables) from before the column existed."""
    if "memory_policy" not in runs:
        return pd.Series("", index=runs.index)
    return runs["memory_policy"].map(lambda v: "" if is_missing(v) else str(v))


def _prunings(runs: pd.DataFrame) -> pd.Series:
    """Each run's pruning label; "" for runs (or stored tables) from before the column existed."""
    if "pruning" not in runs:
        return pd.Series("", index=runs.index)
    return runs["pruning"].map(lambda v: "" if is_missing(v) else str(v))


def _inputs(runs: pd.DataFrame) -> pd.Series:
    """Each run's input label; "" for runs (or stored tables) from before the column existed."""
    if "input" not in runs:
        return pd.Series("", index=runs.index)
    return runs["input"].map(lambda v: "" if is_missing(v) else str(v))


def _pairs(label: str) -> dict[str, str]:
    """``dataset.downscale=2, max_frames=100`` as {key: value} (the values are numbers: no ", " inside)."""
    return dict(part.split("=", 1) for part in label.split(", ") if "=" in part)


def input_differences(labels: set[str]) -> dict[str, str]:
    """Per input label, the part that tells it from the others: its keys whose value differs among ``labels``
    (a key one label lacks differs too), short names, as ``downscale=2, max_frames=100``; "" where all agree."""
    parsed = {label: _pairs(label) for label in labels}
    keys = dict.fromkeys(k for pairs in parsed.values() for k in pairs)
    differ = [k for k in keys if len({pairs.get(k) for pairs in parsed.values()}) > 1]
    return {
        label: ", ".join(f"{k.rsplit('.', 1)[-1]}={pairs[k]}" for k in differ if k in pairs)
        for label, pairs in parsed.items()
    }


def variants(runs: pd.DataFrame) -> list[Variant]:
    """Measured rows in paper order; the keep ratio is named only where a strategy ran several,
    the backend preset only where the runs hold several, the memory policy wherever it is not today's, the
    pruning schedule (an absolute target, other strategy parameters) wherever it is not the usual one, the input
    (image size, frame window) wherever the runs read several."""
    presets, policies, prunings, inputs = _presets(runs), _policies(runs), _prunings(runs), _inputs(runs)
    found = {
        (s, _keep(k), str(p), m, g, i)
        for s, k, p, m, g, i in zip(
            runs["strategy"], runs["keep_ratio"], presets, policies, prunings, inputs, strict=True
        )
    }
    ratios: dict[tuple[str, str, str, str], int] = {}
    for strategy, _, preset, policy, _, inp in found:
        ratios[strategy, preset, policy, inp] = ratios.get((strategy, preset, policy, inp), 0) + 1
    several_presets = len({p for _, _, p, _, _, _ in found}) > 1
    shown = input_differences({i for *_, i in found})
    out = []

    def order(p: tuple[str, float | None, str, str, str, str]) -> tuple:
        return p[2] != "default", p[2], p[5], p[3], strategy_rank(p[0]), -1.0 if p[1] is None else p[1], p[4]

    for strategy, keep, preset, policy, pruning, inp in sorted(found, key=order):
        label = method_name(strategy)
        if pruning:
            label += f" ({pruning})"
        elif ratios[strategy, preset, policy, inp] > 1:
            label += f" (keep {keep:g})" if keep is not None else " (absolute target)"
        if policy:
            label += f" + {policy}"
        if shown[inp]:
            label += f" {{{shown[inp]}}}"
        if several_presets:
            label += f" [{preset}]"
        out.append(Variant(strategy, keep, label, preset, policy, pruning, inp))
    return out


def variant_runs(runs: pd.DataFrame, variant: Variant) -> pd.DataFrame:
    keep = runs["keep_ratio"]
    same_keep = keep.isna() if variant.keep_ratio is None else keep == variant.keep_ratio
    same = (runs["strategy"] == variant.strategy) & same_keep & (_presets(runs) == variant.slam_preset)
    same &= (_policies(runs) == variant.memory_policy) & (_prunings(runs) == variant.pruning)
    return runs[same & (_inputs(runs) == variant.input)]


def sequences(runs: pd.DataFrame, dataset: str) -> list[str]:
    return sorted(set(runs["seq"]), key=lambda s: sequence_sort_key(dataset, s))
