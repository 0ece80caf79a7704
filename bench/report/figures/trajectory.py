"""Trajectory figures: each strategy's estimate beside the ground truth, aligned as the ATE aligns it."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd

from bench.errors import MetricError
from bench.metrics.trajectory import (
    MAX_DIFF_S,
    Trajectory,
    aligned_positions,
    read_tum,
)
from bench.names import dataset_name, file_token
from bench.report.collect import is_missing
from bench.report.figures.output import Warn, save_figure
from bench.report.figures.runs import representative
from bench.report.style import (
    Panel,
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


def read_trajectory(path: Path, warn: Warn) -> Trajectory | None:
    """A run's TUM trajectory, or None (warned when the file exists but is unusable)."""
    if not path.is_file():
        return None
    try:
        return read_tum(path)
    except MetricError as exc:
        warn(f"skipped {path} in plots: {exc}")
        return None


def _aligned(est: Trajectory, gt: Trajectory | None, alignment: str, max_dt: float, warn: Warn) -> np.ndarray:
    """[N, 3] estimate positions aligned as for the ATE; unaligned (warned) where that fails."""
    try:
        return aligned_positions(est, gt, alignment, max_dt)
    except MetricError as exc:
        warn(f"trajectory shown unaligned: {exc}")
        return est.positions_m


def plot_trajectory(runs: pd.DataFrame, dataset: str, seq: str, out: Path, warn: Warn) -> Path | None:
    """Top view of estimated vs ground-truth paths on the two axes of largest extent: one panel per
    preset (and keep-ratio sweep), the lowest seed of each variant, the ground truth in every panel."""
    known = sorted(set(runs["strategy"]))
    gt: np.ndarray | None = None  # [M, 3] ground-truth positions
    one = runs[runs["seq"] == seq]
    drawn: list[tuple[Panel, list[tuple[Variant, np.ndarray, bool]]]] = []
    seeds_shown: set[int] = set()
    for panel in panel_groups(variants(runs)):  # dataset-wide, so labels match the tables
        paths: list[tuple[Variant, np.ndarray, bool]] = []
        for variant in panel.variants:
            run = representative(variant_runs(one, variant))
            if run is None:
                continue
            run_dir = Path(run["path"])
            est = read_trajectory(run_dir / "traj_est.txt", warn)
            if est is None:
                continue
            run_gt = read_trajectory(run_dir / "traj_gt.txt", warn)
            gt = run_gt.positions_m if gt is None and run_gt is not None else gt
            alignment = run.get("ate_alignment")
            alignment = "se3" if is_missing(alignment) else str(alignment)
            max_dt = run.get("ate_max_diff_s")
            max_dt = MAX_DIFF_S if is_missing(max_dt) else float(max_dt)
            paths.append((variant, _aligned(est, run_gt, alignment, max_dt, warn), run["status"] == "lost"))
            if not is_missing(run.get("seed")):
                seeds_shown.add(int(run["seed"]))
        if paths:
            drawn.append((panel, paths))
    if not drawn:
        return None
    extent_source = gt if gt is not None else np.vstack([p for _, paths in drawn for _, p, _ in paths])
    axes_idx = sorted(np.argsort(np.ptp(extent_source, axis=0))[-2:])
    names = "xyz"
    span = np.ptp(extent_source[:, axes_idx], axis=0) + 1e-9
    to_scale = 0.25 <= span[1] / span[0] <= 4.0  # a near-straight drive at one scale is a line
    aspect = float(np.clip(span[1] / span[0], 0.35, 2.5)) if to_scale else 1.0
    ncols = min(4, len(drawn))
    nrows = math.ceil(len(drawn) / ncols)
    fig = new_figure(2.2 + 3.3 * ncols, 0.9 + nrows * 3.3 * aspect + 0.3)
    axes = fig.subplots(nrows, ncols, squeeze=False, sharex=True, sharey=True)
    any_lost = False
    for ax, (panel, paths) in zip(axes.ravel(), drawn, strict=False):
        if gt is not None:
            ax.plot(gt[:, axes_idx[0]], gt[:, axes_idx[1]], "-", color="0.6", lw=3.0, zorder=1)
        for variant, xyz, lost in paths:
            ls, _ = ratio_style(variant, panel)
            ax.plot(
                xyz[:, axes_idx[0]],
                xyz[:, axes_idx[1]],
                ls=ls,
                lw=1.3,
                zorder=2,
                color=strategy_colour(variant.strategy, known),
            )
            if lost:
                any_lost = True
                ax.plot(*xyz[-1, axes_idx], "x", ms=7, mew=2, color=strategy_colour(variant.strategy, known))
        ax.set_title(panel.title or f"{dataset_name(dataset)} {seq}")
        apply_fonts(ax)
    everything = np.vstack([p for _, paths in drawn for _, p, _ in paths] + ([gt] if gt is not None else []))
    lo, hi = everything[:, axes_idx].min(axis=0), everything[:, axes_idx].max(axis=0)
    pad = 0.05 * (np.full(2, float(max(hi - lo))) if to_scale else hi - lo) + 1e-6
    axes[0, 0].set_xlim(lo[0] - pad[0], hi[0] + pad[0])  # shared by every panel
    axes[0, 0].set_ylim(lo[1] - pad[1], hi[1] + pad[1])
    for ax in axes.ravel()[: len(drawn)]:
        ax.set_aspect("equal" if to_scale else "auto", adjustable="box")
    for ax in axes[-1, :]:
        ax.set_xlabel(f"{names[axes_idx[0]]} [m]")
    for ax in axes[:, 0]:
        ax.set_ylabel(f"{names[axes_idx[1]]} [m]")
    for ax in axes.ravel()[len(drawn) :]:
        ax.set_axis_off()
    handles = [key("ground truth", "0.6", lw=3.0)] if gt is not None else []
    handles += strategy_keys([p for p, _ in drawn], known)
    if any_lost:
        handles.append(key("x: where tracking was lost", "black", "none", "x"))
    legend_outside(fig, handles)
    seed = f"seed {min(seeds_shown)}" if len(seeds_shown) == 1 else "lowest seed of each method"
    scale = "" if to_scale else "; x and y not to one scale"
    fig_title(fig, f"Trajectory, {dataset_name(dataset)} {seq} (top view, {seed}, aligned as for ATE{scale})")
    return save_figure(fig, out / f"trajectory_{file_token(dataset)}_{file_token(seq)}.png")
