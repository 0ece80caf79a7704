"""Per-keyframe figures (the paper's Fig. 3a): memory and Gaussians per keyframe, memory against distance."""

from __future__ import annotations

from pathlib import Path

import pandas as pd
from matplotlib.artist import Artist
from matplotlib.patches import Patch

from bench.names import dataset_name, file_token
from bench.report.figures.output import Warn, save_figure
from bench.report.figures.runs import KfValue, peak_column, peak_series, runs_to_show, seed_band
from bench.report.style import (
    apply_fonts,
    band,
    fig_title,
    key,
    legend_outside,
    new_figure,
    panel_groups,
    ratio_style,
    strategy_colour,
    strategy_keys,
)
from bench.report.variants import variant_runs, variants

# keyframes.csv memory columns as a reader knows them
PROBE_NAMES: dict[str, str] = {
    "cuda_alloc_peak_mib": "CUDA allocator",
    "cuda_reserved_peak_mib": "CUDA reserved",
    "torch_live_peak_mib": "live torch tensors",
    "cpu_rss_peak_mib": "process RSS",
}
X_LABELS = {"frame": "frame", "distance_m": "distance driven [m]", "path_length_m": "distance driven [m]"}
MEMORY_VS_DISTANCE: tuple[str, str, tuple[tuple[str, KfValue], ...]] = (
    "memory_vs_distance",
    "Memory against distance",
    (
        (
            "Gaussians in the map [thousands]",
            lambda _r, kf: kf["n_gaussians"] / 1e3 if "n_gaussians" in kf.columns else None,
        ),
        ("peak memory [MiB]", lambda r, kf: peak_series(r, kf)),
    ),
)
# (file stem, figure title, rows: (y label, value of one run's keyframes.csv))
PER_KEYFRAME: tuple[tuple[str, str, tuple[tuple[str, KfValue], ...]], ...] = (
    (
        "memory_per_keyframe",
        "Memory per keyframe",
        (
            ("peak memory [MiB]", peak_series),
            ("map state [MiB]\n(parameters, gradients, Adam)", lambda _r, kf: kf["state_mib"]),
        ),
    ),
    (
        "gaussians_per_keyframe",
        "Gaussians per keyframe",
        (
            (
                "Gaussians in the map [thousands]",
                lambda _r, kf: kf["n_gaussians"] / 1e3 if "n_gaussians" in kf.columns else None,
            ),
            (
                "Gaussians added since the start\n[thousands]",
                lambda _r, kf: kf["n_added"].cumsum() / 1e3 if "n_added" in kf.columns else None,
            ),
        ),
    ),
)


def _markevery(points: int) -> int | None:
    """A marker on every point up to a few dozen; beyond, about 30 per line, so a 400-frame drive's
    markers still tell the strategies apart instead of merging into a thick line."""
    return None if points <= 60 else max(1, points // 30)


def plot_per_keyframe(
    runs: pd.DataFrame,
    dataset: str,
    seq: str,
    out: Path,
    warn: Warn,
    stem: str,
    title: str,
    rows: tuple[tuple[str, KfValue], ...],
    x_col: str = "frame",
    cache: dict[str, pd.DataFrame | None] | None = None,
) -> Path | None:
    """Small multiples of per-keyframe quantities (paper Fig. 5): one column of panels per preset
    (and per keep-ratio sweep), one row per quantity, y shared along a row; every seed of a
    variant pooled into a mean line with a ± std band. ``cache``: run path -> the table to read
    instead of its keyframes.csv (the milestone rows)."""
    one = runs[runs["seq"] == seq]
    found = variants(runs)  # dataset-wide, so labels match the tables
    panels = [p for p in panel_groups(found) if any(len(variant_runs(one, v)) for v in p.variants)]
    if not panels:
        return None
    known = sorted(set(runs["strategy"]))
    cache = {} if cache is None else cache
    fig = new_figure(2.0 + 3.3 * len(panels), 1.0 + 2.3 * len(rows))
    axes = fig.subplots(len(rows), len(panels), squeeze=False, sharex=True, sharey="row")
    drawn = most_seeds = 0
    any_lost = False
    probes: set[str] = set()
    for col, panel in enumerate(panels):
        for variant in panel.variants:
            vr = variant_runs(one, variant)
            ls, marker = ratio_style(variant, panel)
            colour = strategy_colour(variant.strategy, known)
            for row, (_, value) in enumerate(rows):
                got = seed_band(vr, value, warn, cache, x_col)
                if got is None:
                    continue
                x, mean, std, n, lost = got
                band(axes[row, col], x, mean, std, colour, ls=ls, marker=marker, markevery=_markevery(len(x)))
                drawn += 1
                most_seeds = max(most_seeds, n)
                any_lost = any_lost or lost
            shown, _ = runs_to_show(vr)
            for _, run in shown.iterrows():
                kf = cache.get(str(run["path"]))
                column = None if kf is None else peak_column(run, kf)
                if column:
                    probes.add(column)
        axes[0, col].set_title(panel.title or f"{dataset_name(dataset)} {seq}")
        axes[-1, col].set_xlabel(X_LABELS.get(x_col, x_col))
    if not drawn:
        return None
    for row, (label, _) in enumerate(rows):
        if label.startswith("peak memory") and probes:
            label += "\n(" + ", ".join(PROBE_NAMES.get(p, p) for p in sorted(probes)) + ")"
        axes[row, 0].set_ylabel(label)
    for ax in axes.ravel():
        apply_fonts(ax)
    handles: list[Artist] = list(strategy_keys(panels, known))  # line keys, then a Patch for the band
    if most_seeds >= 2:
        handles.append(key(f"line: mean of {most_seeds} seeds", "grey"))
        handles.append(Patch(color="grey", alpha=0.25, label="band: ± 1 std over seeds"))
    if any_lost:
        handles.append(key("(every seed lost: lost runs shown)", "white"))
    legend_outside(fig, handles)
    fig_title(fig, f"{title}, {dataset_name(dataset)} {seq}")
    return save_figure(fig, out / f"{stem}_{file_token(dataset)}_{file_token(seq)}.png")
