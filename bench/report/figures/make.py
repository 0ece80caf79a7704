"""Every figure a report's runs support, drawn in one pass in each requested format (``make_plots``)."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pandas as pd

from bench.names import sequence_sort_key
from bench.report.figures.density import plot_density
from bench.report.figures.drift import plot_drift
from bench.report.figures.growth import plot_ratio_vs_density, plot_ratio_vs_keyframes
from bench.report.figures.milestones import plot_milestones
from bench.report.figures.output import DPI, OUTPUT, Warn, check_figure_options
from bench.report.figures.pareto import plot_pareto
from bench.report.figures.per_keyframe import MEMORY_VS_DISTANCE, PER_KEYFRAME, plot_per_keyframe
from bench.report.figures.pruned import plot_pruned
from bench.report.figures.ratio import plot_ratio
from bench.report.figures.trajectory import plot_trajectory


def make_plots(
    runs: pd.DataFrame,
    out: Path,
    warn: Warn,
    formats: tuple[str, ...] = ("png",),
    dpi: int = DPI,
    keyframes: dict[str, pd.DataFrame] | None = None,
    milestones: dict[str, pd.DataFrame] | None = None,
    long_drives: bool = False,
) -> list[Path]:
    """Every figure the runs support, in each of ``formats``; finished runs only. ``keyframes`` and
    ``milestones`` (run path -> its rows) stand in for run dirs that are gone (``redraw``).
    ``long_drives``: also memory against distance and accuracy at the milestones (``eval.at_frames``)."""
    with _drawing(formats, dpi, keyframes=keyframes or {}, milestones=milestones or {}, long_drives=long_drives):
        first = _make_plots(runs, out, warn)
    return [p.with_suffix(f".{ext}") for p in first for ext in formats]


@contextmanager
def _drawing(formats: tuple[str, ...], dpi: int, **extra: Any) -> Iterator[None]:
    """``OUTPUT`` set to these formats and dpi (and ``extra``) for one report's figures, then put back."""
    check_figure_options(formats, dpi)
    previous = dict(OUTPUT)
    OUTPUT.update(formats=tuple(formats), dpi=int(dpi), **extra)
    try:
        yield
    finally:
        OUTPUT.update(previous)


def _make_plots(runs: pd.DataFrame, out: Path, warn: Warn) -> list[Path]:
    done = runs[runs["status"].isin(["ok", "lost"])]
    written: list[Path | None] = []
    for dataset in sorted(set(done["dataset"])):
        ds = done[done["dataset"] == dataset]
        for seq in sorted(set(ds["seq"]), key=lambda s: sequence_sort_key(dataset, s)):
            for stem, title, rows in PER_KEYFRAME:
                written.append(plot_per_keyframe(ds, dataset, seq, out, warn, stem, title, rows))
            if OUTPUT["long_drives"]:  # the scale study's figures (bench/report/route_scale.py)
                written.append(plot_per_keyframe(ds, dataset, seq, out, warn, *MEMORY_VS_DISTANCE, x_col="distance_m"))
                written.append(plot_milestones(ds, dataset, seq, out, warn))
                written.append(plot_drift(ds, dataset, seq, out, warn))
                if ds["seq"].nunique() > 1:  # routes' baselines differ: a front per route, beside the pooled one
                    written.append(plot_pareto(ds, dataset, out, seq=seq))
            written.append(plot_density(ds, dataset, seq, out, warn))
            written.append(plot_trajectory(ds, dataset, seq, out, warn))
            written += plot_pruned(ds, dataset, seq, out, warn)
        written.append(plot_ratio(ds, dataset, out))
        written.append(plot_pareto(ds, dataset, out))
    return [p for p in written if p is not None]


def regime_plots(
    runs: pd.DataFrame,
    keyframes: dict[str, pd.DataFrame],
    out: Path,
    baseline: str = "none",
    formats: tuple[str, ...] = ("png",),
    dpi: int = DPI,
) -> list[Path]:
    """The regime study's figures (``bench.report.figures.growth``), in each of ``formats``."""
    with _drawing(formats, dpi):
        first = [
            plot_ratio_vs_keyframes(runs, keyframes, out, baseline),
            plot_ratio_vs_density(runs, out, baseline),
        ]
    return [p.with_suffix(f".{ext}") for p in first if p is not None for ext in formats]
