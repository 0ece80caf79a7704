"""Accuracy against peak memory, with each strategy's Pareto front, over a dataset's sequences."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from bench.names import dataset_name, file_token
from bench.report.figures.output import save_figure
from bench.report.figures.ratio import dataset_average, per_seed_average
from bench.report.style import (
    apply_fonts,
    fig_title,
    key,
    legend_outside,
    new_figure,
    panel_groups,
    ratio_style,
    strategy_colour,
    strategy_keys,
)
from bench.report.variants import Variant, variant_runs, variants


def _front(points: list[tuple[float, float]], lower_is_better: bool) -> list[tuple[float, float]]:
    """Non-dominated points, sorted by memory: none uses less memory and is more accurate."""
    front: list[tuple[float, float]] = []
    for mem, acc in sorted(points):
        if not front or (acc < front[-1][1] if lower_is_better else acc > front[-1][1]):
            front.append((mem, acc))
    return front


def plot_pareto(runs: pd.DataFrame, dataset: str, out: Path, seq: str | None = None) -> Path | None:
    """Accuracy against peak memory per method (dataset averages), with the Pareto front of each
    panel: one column per preset (and keep-ratio sweep), ATE above PSNR, y shared along a row.

    A method measured on fewer sequences than the others is drawn hollow and kept off the
    front: its average is over easier or fewer sequences and would not be a fair point.
    With `seq`, one sequence's runs alone: long drives on different routes have baselines
    whose peaks differ by a third, and their mean would be nobody's point.
    """
    if seq is not None:
        runs = runs[runs["seq"] == seq]
    known = sorted(set(runs["strategy"]))
    n_seqs = runs["seq"].nunique()
    memory: dict[Variant, tuple[float, int]] = {}
    for variant in variants(runs):
        mem, covered = dataset_average(variant_runs(runs, variant), "peak_mem_mib")
        if mem is not None:
            memory[variant] = (mem, covered)
    # the panels of every variant, so that a variant keeps the style and legend name it has in the report's other
    # figures; those without a measured peak (every run lost) are not drawn
    panels = [p for p in panel_groups(variants(runs)) if any(v in memory for v in p.variants)]
    if not panels:
        return None
    metrics = (("ate_rmse_m", "ATE [m]\n(lower is better)", True), ("psnr_db", "PSNR [dB]\n(higher is better)", False))
    fig = new_figure(2.2 + 3.2 * len(panels), 0.9 + 2.6 * len(metrics))
    axes = fig.subplots(len(metrics), len(panels), squeeze=False, sharey="row")
    hollow = fronts = False
    most_seeds = 0
    for c, panel in enumerate(panels):
        for r, (metric, title, lower) in enumerate(metrics):
            ax = axes[r, c]
            full: list[tuple[float, float]] = []
            for variant in panel.variants:
                if variant not in memory:
                    continue
                mem, mem_covered = memory[variant]
                vr = variant_runs(runs, variant)
                value, covered = dataset_average(vr, metric)
                if value is None:
                    continue
                complete = min(covered, mem_covered) == n_seqs
                colour = strategy_colour(variant.strategy, known)
                _, marker = ratio_style(variant, panel)
                seeds = pd.concat(
                    [per_seed_average(vr, "peak_mem_mib"), per_seed_average(vr, metric)],
                    axis=1,
                    keys=["mem", "value"],
                ).dropna()
                most_seeds = max(most_seeds, len(seeds))
                if len(seeds) >= 2:
                    ax.errorbar(
                        mem,
                        value,
                        xerr=seeds["mem"].std(),
                        yerr=seeds["value"].std(),
                        fmt="none",
                        ecolor=colour,
                        elinewidth=1.0,
                        capsize=2,
                        zorder=2,
                    )
                ax.scatter(
                    mem,
                    value,
                    s=40,
                    marker=marker,
                    zorder=3,
                    color=colour if complete else "white",
                    edgecolors=colour,
                    linewidths=1.2,
                )
                if complete:
                    full.append((mem, value))
                hollow = hollow or not complete
            front = _front(full, lower)
            if len(front) > 1:
                fronts = True
                ax.plot(*zip(*front, strict=True), "--", color="grey", lw=1.0, drawstyle="steps-post", zorder=1)
            apply_fonts(ax)
            if c == 0:
                ax.set_ylabel(title)
        axes[0, c].set_title(panel.title or dataset_name(dataset))
        axes[-1, c].set_xlabel("peak memory [MiB]")
    handles = strategy_keys(panels, known, shown=set(memory))
    if fronts:
        handles.append(key("dashed: Pareto front of the panel", "grey", "--"))
    if most_seeds >= 2:
        handles.append(key("bars: ± 1 std over seeds", "grey", "-", "|"))
    if hollow:
        handles.append(key("hollow: not measured on every sequence", "black", "none", "o", mfc="white"))
    legend_outside(fig, handles)
    seeds = f"mean of {most_seeds} seeds" if most_seeds >= 2 else "1 seed: no noise estimate"
    if seq is None:
        fig_title(fig, f"Accuracy vs peak memory, {dataset_name(dataset)} (mean over sequences, {seeds})")
        return save_figure(fig, out / f"pareto_{file_token(dataset)}.png")
    fig_title(fig, f"Accuracy vs peak memory, {dataset_name(dataset)} {seq} ({seeds})")
    return save_figure(fig, out / f"pareto_{file_token(dataset)}_{file_token(seq)}.png")
