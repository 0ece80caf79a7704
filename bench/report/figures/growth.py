"""The regime study's two figures: the peak ratio against the keyframes held, and against how densely the map
grows, each with the paper's own point (``bench.report.growth``)."""

from __future__ import annotations

from pathlib import Path

import pandas as pd
from matplotlib.ticker import FuncFormatter

from bench.report.figures.output import save_figure
from bench.report.growth import keyframe_ratios, paper_density, paper_ratio, paper_run, run_table
from bench.report.style import apply_fonts, fig_title, key, legend_outside, new_figure, strategy_colour

PAPER_COLOUR = "#7F7F7F"
MARKERS = ("o", "s", "^", "D", "v", "P", "X")
LEGEND_IN_PER_CHAR = 0.065  # the legend's width per character of its longest label, at its font size


def _legend_in(labels: list[str]) -> float:
    """The width the legend beside the panels takes, in inches, so that long row labels (a budget, a memory
    policy, an input in braces) leave the panels their width."""
    return 0.8 + LEGEND_IN_PER_CHAR * max((len(label) for label in labels), default=0)


def _styles(labels: list[str], strategies: dict[str, str]) -> dict[str, tuple[str, str | tuple]]:
    """A colour per label (its strategy's) and a line style per label within one strategy."""
    dashes: list[str | tuple] = ["-", "--", ":", "-.", (0, (5, 1))]
    seen: dict[str, int] = {}
    out = {}
    for label in labels:
        strategy = strategies[label]
        n = seen.get(strategy, 0)
        seen[strategy] = n + 1
        out[label] = (strategy_colour(strategy), dashes[n % len(dashes)])
    return out


def plot_ratio_vs_keyframes(
    runs: pd.DataFrame, keyframes: dict[str, pd.DataFrame], out: Path, baseline: str = "none"
) -> Path | None:
    """The peak so far of each pruned run against its same-seed baseline's, keyframe by keyframe, over the
    keyframes held; one panel per cell; the paper's run as a point at its keyframe count."""
    curves = keyframe_ratios(runs, keyframes, baseline)
    if curves.empty:
        return None
    strategies = dict(zip(curves["label"], curves["strategy"], strict=False))
    cells = list(dict.fromkeys(curves["cell"]))
    styles = _styles(list(dict.fromkeys(curves["label"])), strategies)
    run = paper_run()["run"]
    fig = new_figure(4.2 * len(cells) + _legend_in([*styles, run["label"]]), 3.6)
    axes = fig.subplots(1, len(cells), squeeze=False)[0]
    for ax, cell in zip(axes, cells, strict=True):
        for (label, seed), c in curves[curves["cell"] == cell].groupby(["label", "seed"], sort=False):
            colour, ls = styles[label]
            ax.plot(c["n_kf_held"], c["ratio"], color=colour, ls=ls, lw=1.2, alpha=0.9 if seed == 0 else 0.55)
        ax.plot([run["keyframes"]], [paper_ratio(run)], "*", ms=11, color=PAPER_COLOUR)
        ax.axhline(1.0, color="black", lw=0.6)
        ax.set_ylim(0, 1.1)
        ax.set_xlabel("keyframes held")
        ax.set_ylabel(f"peak so far, x {baseline} (same seed)")
        ax.set_title(cell)
        apply_fonts(ax)
    handles = [key(label, colour, ls) for label, (colour, ls) in styles.items()]
    handles.append(key(run["label"], PAPER_COLOUR, "", marker="*"))
    legend_outside(fig, handles)
    fig_title(fig, "Peak so far by keyframes held (seed 0 dark)")
    return save_figure(fig, out / "regime_ratio_vs_keyframes.png")


def plot_ratio_vs_density(runs: pd.DataFrame, out: Path, baseline: str = "none") -> Path | None:
    """Each pruned run's peak ratio at its end against the growth density of its cell's baseline (Gaussians
    added per keyframe per megapixel), marker size by keyframes; the paper's run at its own density."""
    table = run_table(runs, baseline)
    base = table[(table["strategy"] == baseline) & (table["status"] == "ok")]
    density = base.groupby("cell")["gaussians_added_per_kf_mpx"].mean()
    points = table[(table["strategy"] != baseline) & table["peak_ratio"].notna() & table["cell"].isin(density.index)]
    if points.empty:
        return None
    strategies = dict(zip(table["label"], table["strategy"], strict=False))
    styles = _styles(list(dict.fromkeys(points["label"])), strategies)
    cells = list(dict.fromkeys(points["cell"]))
    run = paper_run()["run"]
    fig = new_figure(5.0 + _legend_in([*styles, *cells, run["label"]]), 4.2)
    ax = fig.subplots()
    for _, p in points.iterrows():
        colour, _ = styles[p["label"]]
        marker = MARKERS[cells.index(p["cell"]) % len(MARKERS)]
        filled = p["status"] == "ok"
        ax.plot(
            [density[p["cell"]]],
            [p["peak_ratio"]],
            marker,
            color=colour,
            mfc=colour if filled else "none",
            ms=5 + 6 * min(1.0, float(p["num_keyframes"] or 0) / 400),
        )
    ax.plot([paper_density(run)], [paper_ratio(run)], "*", ms=13, color=PAPER_COLOUR)
    ax.axhline(1.0, color="black", lw=0.6)
    ax.set_ylim(0, 1.1)
    ax.set_xlim(0, 1.15 * max([paper_density(run), *density[cells]]))
    ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v / 1000:g}k"))
    ax.set_xlabel(f"Gaussians added per keyframe per Mpx ({baseline}, the cell's mean)")
    ax.set_ylabel(f"peak, x {baseline}")
    apply_fonts(ax)
    handles = [key(label, colour, "", marker="o") for label, (colour, _) in styles.items()]
    handles += [key(cell, "black", "", marker=MARKERS[i % len(MARKERS)]) for i, cell in enumerate(cells)]
    handles.append(key(run["label"], PAPER_COLOUR, "", marker="*"))
    legend_outside(fig, handles)
    fig_title(fig, "Peak ratio by growth density (larger: more keyframes)")
    return save_figure(fig, out / "regime_ratio_vs_density.png")
