"""Metrics against the keep ratio (the paper's Fig. 5), averaged per seed and over a dataset's sequences."""

from __future__ import annotations

import math
import statistics
from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.patches import Patch

from bench.names import dataset_name, file_token, method_name
from bench.report.figures.output import save_figure
from bench.report.style import (
    apply_fonts,
    band,
    fig_title,
    key,
    legend_outside,
    new_figure,
    strategy_colour,
)
from bench.report.variants import variant_runs, variants

DODGE = 0.008  # keep-ratio offset between strategies run at one ratio, so their bars do not overlap


def dataset_average(runs: pd.DataFrame, metric: str) -> tuple[float | None, int]:
    """Mean over sequences of the seed means of ok runs (the tables' Avg), and how many
    sequences it covers."""
    ok = runs[(runs["status"] == "ok") & runs[metric].notna()] if metric in runs else runs.iloc[0:0]
    if ok.empty:
        return None, 0
    per_seq = ok.groupby("seq")[metric].mean()
    return float(statistics.fmean(per_seq)), len(per_seq)


def per_seed_average(runs: pd.DataFrame, metric: str) -> pd.Series:
    """Per seed, the mean over sequences of its ok runs; only seeds that ran every sequence the
    variant has a value on, so each point averages the same sequences as the mean does."""
    if metric not in runs:
        return pd.Series(dtype=float)
    ok = runs[(runs["status"] == "ok") & runs[metric].notna() & runs["seed"].notna()]
    if ok.empty:
        return pd.Series(dtype=float)
    table = ok.pivot_table(index="seed", columns="seq", values=metric, aggfunc="mean")
    return table.dropna().astype(float).mean(axis=1)


def plot_ratio(runs: pd.DataFrame, dataset: str, out: Path) -> Path | None:
    """Fig. 3a: ATE and PSNR against keep ratio, mean ± seed std, for each preset in which some
    strategy ran at two or more ratios (one row of panels per such preset). A strategy swept over
    ratios is a line with a band, one run at a single ratio a point with a bar, the unpruned
    baseline a horizontal line with its band."""
    found = variants(runs)
    swept = sorted(
        {
            v.slam_preset
            for v in found
            if sum(u.strategy == v.strategy and u.slam_preset == v.slam_preset for u in found) > 1
        }
    )
    if not swept:
        return None  # no strategy ran at two keep ratios: nothing to plot against
    known = sorted(set(runs["strategy"]))
    metrics = (("ate_rmse_m", "ATE [m] (lower is better)"), ("psnr_db", "PSNR [dB] (higher is better)"))
    fig = new_figure(2.4 + 3.6 * len(metrics), 0.8 + 2.9 * len(swept))
    axes = fig.subplots(len(swept), len(metrics), squeeze=False, sharex=True)
    any_lost = False
    handles: list = []
    for r, preset in enumerate(swept):
        mine = [v for v in found if v.slam_preset == preset]
        for c, (metric, title) in enumerate(metrics):
            ax = axes[r, c]
            by_strategy: dict[str, list[tuple[float | None, float | None, float, bool]]] = {}
            for variant in mine:
                vr = variant_runs(runs, variant)
                all_lost = bool(len(vr)) and not (vr["status"] == "ok").any() and (vr["status"] == "lost").any()
                seeds = per_seed_average(vr, metric)
                spread = float(seeds.std()) if len(seeds) > 1 else float("nan")
                by_strategy.setdefault(variant.strategy, []).append(
                    (variant.keep_ratio, dataset_average(vr, metric)[0], spread, all_lost)
                )
            for strategy, points in by_strategy.items():
                colour = strategy_colour(strategy, known)
                numeric = sorted((k, v, e) for k, v, e, _ in points if k is not None and v is not None)
                if len(numeric) > 1:
                    xs, ys, es = (np.array(t, dtype=float) for t in zip(*numeric, strict=True))
                    band(ax, xs, ys, es, colour)
                elif numeric:
                    k, v, e = numeric[0]
                    k += DODGE * (sorted(by_strategy).index(strategy) - (len(by_strategy) - 1) / 2)
                    ax.errorbar([k], [v], yerr=None if math.isnan(e) else [e], fmt="s", color=colour, capsize=3, ms=5)
                elif len(points) == 1 and (level := points[0][1]) is not None:
                    spread = points[0][2]
                    ax.axhline(level, color=colour, ls=":", lw=1.3)
                    if not math.isnan(spread):
                        ax.axhspan(level - spread, level + spread, color=colour, alpha=0.08, lw=0)
                lost = [k for k, _, _, is_lost in points if is_lost and k is not None]
                if lost:
                    any_lost = True
                    ax.plot(
                        lost,
                        [0.02] * len(lost),
                        "x",
                        ms=9,
                        mew=2,
                        color=colour,
                        transform=ax.get_xaxis_transform(),
                        clip_on=False,
                    )
                style = ("-", "o") if len(numeric) > 1 else ("none", "s") if numeric else (":", "")
                name = method_name(strategy) + ("" if numeric else " (no pruning)")
                handles.append(key(name, colour, style[0], style[1]))
            ax.set_ylabel(title)
            ax.set_title(f"slam={preset}" if len(swept) > 1 or len({v.slam_preset for v in found}) > 1 else "")
            apply_fonts(ax)
        for ax in axes[-1, :]:
            ax.set_xlabel("keep ratio (fraction of the candidates kept)")
    handles.append(Patch(color="grey", alpha=0.25, label="band / bar: ± 1 std over seeds"))
    if any_lost:
        handles.append(key("x: all seeds lost", "black", "none", "x", mew=2))
    legend_outside(fig, handles)
    fig_title(fig, f"Accuracy vs keep ratio, {dataset_name(dataset)} (mean over sequences and seeds)")
    return save_figure(fig, out / f"ratio_{file_token(dataset)}.png")
