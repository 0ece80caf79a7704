"""Density figures (the paper's Fig. 4): where the final map's Gaussians project at the last keyframe."""

from __future__ import annotations

import math
import textwrap
from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.colors import LogNorm
from matplotlib.ticker import FormatStrFormatter, NullFormatter

from bench.names import dataset_name, file_token
from bench.report.figures.output import Warn, image_axes, save_figure
from bench.report.figures.runs import representative
from bench.report.style import (
    Panel,
    fig_title,
    new_figure,
    panel_groups,
    series_label,
    strategy_colour,
)
from bench.report.variants import Variant, variant_runs, variants

DENSITY_CELLS = 160  # heatmap cells along the longer image side (Fig. 4 is a coarse heatmap too)


def read_density(run_dir: Path, warn: Warn) -> tuple[np.ndarray, np.ndarray | None] | None:
    path = Path(run_dir) / "density.npz"
    if not path.is_file():
        return None
    try:
        with np.load(path) as data:
            counts = np.asarray(data["counts"], dtype=float)
            image = np.asarray(data["image"], dtype=float) if "image" in data.files else None
    except (OSError, ValueError, KeyError) as exc:
        warn(f"skipped {path} in plots: expected npz with 'counts' [H, W] and 'image' [H, W, 3], found {exc}")
        return None
    if counts.ndim != 2:
        warn(f"skipped {path} in plots: expected 'counts' of shape [H, W], found {counts.shape}")
        return None
    if image is not None and image.shape[:2] != counts.shape:
        warn(f"ignored the image in {path}: expected shape {counts.shape + (3,)}, found {image.shape}")
        image = None
    return counts, image


def pool_counts(counts: np.ndarray, block: int) -> np.ndarray:
    """Sum per-pixel counts over ``block`` x ``block`` cells: a full-resolution histogram shown
    downscaled would average single-pixel hits away."""
    if block <= 1:
        return counts
    h, w = counts.shape
    padded = np.zeros((math.ceil(h / block) * block, math.ceil(w / block) * block))
    padded[:h, :w] = counts
    return padded.reshape(padded.shape[0] // block, block, padded.shape[1] // block, block).sum(axis=(1, 3))


def plot_density(runs: pd.DataFrame, dataset: str, seq: str, out: Path, warn: Warn) -> Path | None:
    """Fig. 4: where each strategy's final Gaussians project, on one shared log colour scale; one
    row per preset (and keep-ratio sweep), the lowest seed of each variant."""
    known = sorted(set(runs["strategy"]))
    one = runs[runs["seq"] == seq]
    rows: list[tuple[Panel, list[tuple[Variant, np.ndarray, np.ndarray | None]]]] = []
    for panel in panel_groups(variants(runs)):  # dataset-wide, so labels match the tables
        cells = []
        for variant in panel.variants:
            run = representative(variant_runs(one, variant))
            density = None if run is None else read_density(Path(run["path"]), warn)
            if density is not None:
                cells.append((variant, *density))
        if cells:
            rows.append((panel, cells))
    if not rows:
        return None
    h, w = rows[0][1][0][1].shape
    # wide images (KITTI is 3.3:1) wrap a panel's methods onto lines of 3, others of 4
    ncols = min(3 if w > 2 * h else 4, max(len(cells) for _, cells in rows))
    lines = [(panel, cells[i : i + ncols], i == 0) for panel, cells in rows for i in range(0, len(cells), ncols)]
    block = max(1, math.ceil(max(h, w) / DENSITY_CELLS))
    pooled = {id(c): pool_counts(c[1], block) for _, cells in rows for c in cells}
    panel_w = 3.0 if w > 2 * h else 2.6
    fig = new_figure(1.2 + panel_w * ncols, 0.7 + len(lines) * (panel_w * h / w + 0.5))
    axes = fig.subplots(len(lines), ncols, squeeze=False)
    norm = LogNorm(vmin=1.0, vmax=max(2.0, max(float(p.max()) for p in pooled.values())))
    mappable = None
    for r, (panel, cells, first) in enumerate(lines):
        for c, (variant, counts, image) in enumerate(cells):
            ax = axes[r, c]
            if image is not None:
                ax.imshow(np.clip(image, 0.0, 1.0).mean(axis=2), cmap="gray", vmin=0.0, vmax=1.0)
            cell = pooled[id(cells[c])]
            ph, pw = cell.shape
            extent = (-0.5, pw * block - 0.5, ph * block - 0.5, -0.5)
            mappable = ax.imshow(np.ma.masked_less(cell, 1.0), cmap="inferno", norm=norm, alpha=0.8, extent=extent)
            ax.set_xlim(-0.5, counts.shape[1] - 0.5)
            ax.set_ylim(counts.shape[0] - 0.5, -0.5)
            image_axes(ax, strategy_colour(variant.strategy, known))
            name = textwrap.fill(series_label(variant, panel), int(panel_w * 13))  # 8 pt: about 13 characters an inch
            ax.set_title(f"{name}\n{int(counts.sum()):,} centres in view", fontsize=8)
        if panel.title and first:
            axes[r, 0].set_ylabel(panel.title, fontsize=8)
        for ax in axes[r, len(cells) :]:
            ax.set_axis_off()
    if mappable is not None:
        unit = "pixel" if block == 1 else f"{block}x{block} px cell"
        bar = fig.colorbar(mappable, ax=axes.ravel().tolist(), shrink=0.9, aspect=12)
        bar.set_label(f"centres per {unit}", fontsize=8)
        bar.ax.yaxis.set_major_formatter(FormatStrFormatter("%g"))
        bar.ax.yaxis.set_minor_formatter(NullFormatter())  # log minor labels collide on a short bar
        bar.ax.tick_params(labelsize=8)
    fig_title(
        fig,
        f"Gaussian density at the last keyframe, {dataset_name(dataset)} {seq} (lowest seed; frame colour = method)",
    )
    return save_figure(fig, out / f"density_{file_token(dataset)}_{file_token(seq)}.png")
