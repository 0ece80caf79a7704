"""Figures in the style of the paper's Figs. 3a, 4 and 5, plus trajectory and Pareto views.

Built on ``matplotlib.figure.Figure`` rather than pyplot: no global backend switch (Agg is
used for PNG regardless) and no figure left open in a caller's session. Each plot reads only
the run dir files the harness writes; a missing or malformed file costs that line a warning,
never the report. Per-sequence figures take the whole dataset's runs plus a sequence, so labels,
colours and markers match the tables and each other. The visual language (a colour per strategy,
panels per preset, legends outside, seeds as bands) is ``bench.report.style``'s.
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from matplotlib.colors import LogNorm
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch
from matplotlib.ticker import FormatStrFormatter, NullFormatter

from bench import schema
from bench.errors import MetricError, ReportError
from bench.metrics.trajectory import (
    MAX_DIFF_S,
    Trajectory,
    aligned_positions,
    distance_along,
    drift_components,
    read_tum,
)
from bench.report.collect import is_missing, read_run_table
from bench.report.figures import pruned_run as viz
from bench.report.names import dataset_name, file_token, method_name, sequence_sort_key
from bench.report.style import (
    Panel,
    apply_fonts,
    band,
    fig_title,
    key,
    legend_outside,
    new_figure,
    panel_groups,
    ratio_style,
    series_label,
    strategy_colour,
    strategy_keys,
)  # fmt: skip
from bench.report.tables import Variant, variant_runs, variants

Warn = Callable[[str], None]
PRUNED_GLOB = viz.PRUNED_GLOB
DPI = 110
DODGE = 0.008  # keep-ratio offset between strategies run at one ratio, so their bars do not overlap
DENSITY_CELLS = 160  # heatmap cells along the longer image side (Fig. 4 is a coarse heatmap too)


FORMATS: tuple[str, ...] = ("png", "pdf", "svg")
# What the figure files are made as; ``make_plots`` sets it for the duration of one report.
_output: dict[str, Any] = {"formats": ("png",), "dpi": DPI, "keyframes": {}, "milestones": {}, "long_drives": False}
# keyframes.csv memory columns as a reader knows them
PROBE_NAMES: dict[str, str] = {
    "cuda_alloc_peak_mib": "CUDA allocator",
    "cuda_reserved_peak_mib": "CUDA reserved",
    "torch_live_peak_mib": "live torch tensors",
    "cpu_rss_peak_mib": "process RSS",
}


def _save(fig: Figure, path: Path) -> Path:
    """Write ``path`` in every requested format (same stem); returns the first one's path."""
    path.parent.mkdir(parents=True, exist_ok=True)
    written = [path.with_suffix(f".{ext}") for ext in _output["formats"]]
    for target in written:
        fig.savefig(target, dpi=_output["dpi"])
    return written[0]


def _style_key(label: str, **line: Any) -> Line2D:
    """A legend entry explaining a line style (black, so it reads as "this style means")."""
    return Line2D([], [], color="black", label=label, **line)


def representative(runs: pd.DataFrame) -> pd.Series | None:
    """The run a per-run figure shows for one variant: the lowest-seed ok run, else a lost one."""
    for status in ("ok", "lost"):
        pick = runs[runs["status"] == status]
        if len(pick):
            return pick.sort_values("seed", na_position="last").iloc[0]
    return None


def read_keyframes(run_dir: Path, warn: Warn) -> pd.DataFrame | None:
    stored = _output.get("keyframes", {}).get(str(run_dir))
    if stored is not None:
        return stored
    frame = read_run_table(Path(run_dir) / schema.KEYFRAMES_FILE, (("kf", "frame"), "state_mib"), warn, "in plots")
    if frame is None:
        return None
    distance = distance_driven(Path(run_dir), frame)
    return frame if distance is None else frame.assign(distance_m=distance)


def distance_driven(run_dir: Path, keyframes: pd.DataFrame) -> np.ndarray | None:
    """Ground-truth metres driven up to each keyframe (from traj_gt.txt), None without ground truth.

    traj_gt.txt has one line per tracked frame from the first, which is keyframe 0's frame.
    """
    path = run_dir / "traj_gt.txt"
    if "frame" not in keyframes.columns or keyframes.empty or not path.is_file():
        return None
    try:
        xyz = read_tum(path, allow_duplicates=True).positions_m  # [F, 3] m
    except MetricError:
        return None
    along = distance_along(xyz)  # [F] m
    pos = keyframes["frame"].to_numpy(dtype=int) - int(keyframes["frame"].iloc[0])
    if pos.min() < 0 or pos.max() >= len(along):
        return None
    return np.round(along[pos], 4)


def peak_column(run: pd.Series, keyframes: pd.DataFrame) -> str | None:
    """The keyframes.csv column behind the run's headline ``peak_mem_mib``: the one its
    ``peak_mem_source`` names (``bench.schema.PEAK_SOURCES``), if the file holds values there."""
    column = schema.peak_column(run.get(schema.PEAK_SOURCE_FIELD))
    return column if column in keyframes.columns and keyframes[column].notna().any() else None


def _runs_to_show(vr: pd.DataFrame) -> tuple[pd.DataFrame, bool]:
    """The seeds a per-keyframe line averages: the ok runs, or the lost ones where none is ok."""
    ok = vr[vr["status"] == "ok"]
    if len(ok):
        return ok, False
    return vr[vr["status"] == "lost"], True


KfValue = Callable[[pd.Series, pd.DataFrame], "pd.Series | None"]  # one run's per-keyframe quantity


def seed_band(
    vr: pd.DataFrame, value: KfValue, warn: Warn, cache: dict[str, pd.DataFrame | None], x_col: str = "frame"
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int, bool] | None:
    """(x, mean, std, n seeds, lost) of a per-keyframe quantity over a variant's seeds; x is ``x_col``
    of keyframes.csv (the frame, or ``distance_m``).

    Seeds may key-frame at different frames: each seed's series is interpolated onto the union of
    their frames, within its own range only, and the std needs two seeds at a frame (else NaN).
    """
    shown, lost = _runs_to_show(vr)
    series: list[tuple[np.ndarray, np.ndarray]] = []
    for _, run in shown.iterrows():
        path = str(run["path"])
        if path not in cache:
            cache[path] = read_keyframes(Path(path), warn)
        kf = cache[path]
        if kf is None or kf.empty:
            continue
        y = value(run, kf)
        if y is None:
            continue
        if x_col not in kf.columns and x_col != "frame":
            continue
        x = (kf[x_col] if x_col in kf.columns else kf["kf"]).to_numpy(dtype=float)
        series.append((x, np.asarray(y, dtype=float)))
    if not series:
        return None
    grid = np.unique(np.concatenate([x for x, _ in series]))
    table = np.full((len(series), len(grid)), np.nan)
    for row, (x, y) in zip(table, series, strict=True):
        inside = (grid >= x.min()) & (grid <= x.max())
        row[inside] = np.interp(grid[inside], x, y)
    counts = np.isfinite(table).sum(axis=0)
    mean = np.nanmean(table, axis=0)
    std = np.full(len(grid), np.nan)
    two = counts >= 2
    std[two] = np.nanstd(table[:, two], axis=0, ddof=1)
    return grid, mean, std, len(series), lost


def _peak(run: pd.Series, kf: pd.DataFrame) -> pd.Series | None:
    column = peak_column(run, kf)
    return None if column is None else kf[column]


X_LABELS = {"frame": "frame", "distance_m": "distance driven [m]", "path_length_m": "distance driven [m]"}
MEMORY_VS_DISTANCE: tuple[str, str, tuple[tuple[str, KfValue], ...]] = (
    "memory_vs_distance", "Memory against distance", (
        ("Gaussians in the map [thousands]",
         lambda _r, kf: kf["n_gaussians"] / 1e3 if "n_gaussians" in kf.columns else None),
        ("peak memory [MiB]", lambda r, kf: _peak(r, kf)),
    ))  # fmt: skip
# (file stem, figure title, rows: (y label, value of one run's keyframes.csv))
PER_KEYFRAME: tuple[tuple[str, str, tuple[tuple[str, KfValue], ...]], ...] = (
    ("memory_per_keyframe", "Memory per keyframe", (
        ("peak memory [MiB]", _peak),
        ("map state [MiB]\n(parameters, gradients, Adam)", lambda _r, kf: kf["state_mib"]),
    )),
    ("gaussians_per_keyframe", "Gaussians per keyframe", (
        ("Gaussians in the map [thousands]",
         lambda _r, kf: kf["n_gaussians"] / 1e3 if "n_gaussians" in kf.columns else None),
        ("Gaussians added since the start\n[thousands]",
         lambda _r, kf: kf["n_added"].cumsum() / 1e3 if "n_added" in kf.columns else None),
    )),
)  # fmt: skip


def _markevery(points: int) -> int | None:
    """A marker on every point up to a few dozen; beyond, about 30 per line, so a 400-frame drive's
    markers still tell the strategies apart instead of merging into a thick line."""
    return None if points <= 60 else max(1, points // 30)


def plot_per_keyframe(runs: pd.DataFrame, dataset: str, seq: str, out: Path, warn: Warn, stem: str, title: str,
                      rows: tuple[tuple[str, KfValue], ...], x_col: str = "frame",
                      cache: dict[str, pd.DataFrame | None] | None = None) -> Path | None:  # fmt: skip
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
            shown, _ = _runs_to_show(vr)
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
    handles = strategy_keys(panels, known)
    if most_seeds >= 2:
        handles.append(key(f"line: mean of {most_seeds} seeds", "grey"))
        handles.append(Patch(color="grey", alpha=0.25, label="band: ± 1 std over seeds"))
    if any_lost:
        handles.append(key("(every seed lost: lost runs shown)", "white"))
    legend_outside(fig, handles)
    fig_title(fig, f"{title}, {dataset_name(dataset)} {seq}")
    return _save(fig, out / f"{stem}_{file_token(dataset)}_{file_token(seq)}.png")


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
            ax.plot(xyz[:, axes_idx[0]], xyz[:, axes_idx[1]], ls=ls, lw=1.3, zorder=2,
                    color=strategy_colour(variant.strategy, known))  # fmt: skip
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
    return _save(fig, out / f"trajectory_{file_token(dataset)}_{file_token(seq)}.png")


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


def _image_axes(ax, colour: str) -> None:
    """An image panel framed in its strategy's colour (the figures' one key to who is who)."""
    ax.set_xticks([])
    ax.set_yticks([])
    for spine in ax.spines.values():
        spine.set_edgecolor(colour)
        spine.set_linewidth(2.5)


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
            _image_axes(ax, strategy_colour(variant.strategy, known))
            ax.set_title(f"{series_label(variant, panel)}\n{int(counts.sum()):,} centres in view", fontsize=8)
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
    fig_title(fig, f"Gaussian density at the last keyframe, {dataset_name(dataset)} {seq} (lowest seed; frame colour = "
                 "method)")  # fmt: skip
    return _save(fig, out / f"density_{file_token(dataset)}_{file_token(seq)}.png")


def _pruned_records(run_dir: Path, warn: Warn) -> dict[int, Path]:
    """keyframe -> pruned_kfNNN.npz written by a run with viz.pruning=true."""
    found: dict[int, Path] = {}
    for path in sorted(Path(run_dir).glob(PRUNED_GLOB)):
        try:
            found[int(path.stem.removeprefix("pruned_kf"))] = path
        except ValueError:
            warn(f"skipped {path} in plots: expected a name pruned_kfNNN.npz")
    return found


PRUNED_NOTE = (
    "One row per method (lowest seed; frame colour = method): its render of this keyframe\n"
    "before and after the prune, and the centres of the Gaussians it pruned, coloured\n"
    "by their coverage C_i (one log scale for all rows). Every map differs: each method\n"
    "pruned and re-seeded differently on the keyframes before this one."
)


def plot_pruned(runs: pd.DataFrame, dataset: str, seq: str, out: Path, warn: Warn) -> list[Path]:
    """What each strategy removed on one keyframe (runs with ``viz.pruning=true``): one figure per
    preset, one row per strategy (lowest seed): its render before and after the prune, and the
    pruned Gaussians' centres over the keyframe coloured by their coverage C_i on one log scale.
    The keyframe is the last one every shown run recorded."""
    known = sorted(set(runs["strategy"]))
    one = runs[runs["seq"] == seq]
    written: list[Path] = []
    for panel in panel_groups(variants(runs)):
        shown: list[tuple[Variant, dict[int, Path]]] = []
        for variant in panel.variants:
            run = representative(variant_runs(one, variant))
            records = {} if run is None else _pruned_records(Path(run["path"]), warn)
            if records:
                shown.append((variant, records))
        common = set.intersection(*(set(r) for _, r in shown)) if shown else set()
        if not common:
            continue
        kf = max(common)
        try:
            data = [(variant, viz.read(records[kf])) for variant, records in shown]
        except (OSError, ValueError, KeyError) as exc:
            warn(f"skipped the pruned-Gaussians figure of {dataset} {seq}: {exc}")
            continue
        h, w = data[0][1]["image"].shape[:2]
        norm = viz.coverage_norm([r["coverage"] for _, r in data])
        panel_w = 3.0
        fig = new_figure(1.4 + 3 * panel_w, 0.5 + (len(data) + 1) * (panel_w * h / w + 0.22))
        axes = fig.subplots(len(data) + 1, 3, squeeze=False)
        axes[0, 0].imshow(data[0][1]["image"])
        axes[0, 0].set_title(f"keyframe {kf} (frame {int(data[0][1]['frame'])})", fontsize=8)
        _image_axes(axes[0, 0], "0.5")
        for ax in axes[0, 1:]:
            ax.set_axis_off()
        note = axes[0, 1].text(0.0, 0.5, PRUNED_NOTE, transform=axes[0, 1].transAxes, va="center", ha="left",
                               fontsize=8)  # fmt: skip
        note.set_in_layout(False)  # the text may run over the empty panel beside it
        points = None
        for row, (variant, r) in enumerate(data, start=1):
            colour = strategy_colour(variant.strategy, known)
            name = series_label(variant, panel)
            for col, (image, when) in enumerate(((r["before"], "before"), (r["after"], "after"))):
                axes[row, col].imshow(image)
                axes[row, col].set_title(f"render {when} the prune ({viz.psnr_db(image, r['image']):.2f} dB)",
                                         fontsize=8)  # fmt: skip
                _image_axes(axes[row, col], colour)
            points = viz.draw_centres(axes[row, 2], r, norm, size=2.0)
            axes[row, 2].set_title(f"{int(r['n_pruned']):,} of {int(r['n_before']):,} Gaussians pruned", fontsize=8)
            axes[row, 0].set_ylabel(name.replace(" (", "\n("), fontsize=8)
            _image_axes(axes[row, 2], colour)
        if points is not None:
            fig.colorbar(points, ax=axes[1:, 2].tolist(), label="coverage $C_i$ [px]",
                         shrink=0.6)  # fmt: skip
        where = ", " + panel.title.replace("\n", " ") if panel.title else ""
        fig_title(fig, f"What each strategy pruned, {dataset_name(dataset)} {seq}{where} (PSNR against the keyframe)")
        token = f"_{file_token(panel.title)}" if panel.title else ""
        written.append(_save(fig, out / f"pruned_{file_token(dataset)}_{file_token(seq)}{token}_kf{kf:03d}.png"))
    return written


def plot_milestones(runs: pd.DataFrame, dataset: str, seq: str, out: Path, warn: Warn) -> Path | None:
    """ATE and PSNR at each ``eval.at_frames`` milestone against the distance driven by then: what
    drives of those lengths score, from the same runs."""
    from bench.report.route_scale import read_milestones

    one = runs[runs["seq"] == seq]
    cache: dict[str, pd.DataFrame | None] = {}
    for path in one["path"]:
        cache[str(path)] = _output["milestones"].get(str(path))
        if cache[str(path)] is None:
            cache[str(path)] = read_milestones(Path(path), warn)
    if not any(v is not None and len(v) for v in cache.values()):
        return None
    rows: tuple[tuple[str, KfValue], ...] = (
        ("ATE RMSE [m]\n(the trajectory so far)", lambda _r, ms: ms["ate_rmse_m"]),
        ("PSNR [dB]\n(the map then, frames so far)", lambda _r, ms: ms["psnr_db"]),
    )
    return plot_per_keyframe(runs, dataset, seq, out, warn, "accuracy_vs_distance", "Accuracy against distance",
                             rows, x_col="path_length_m", cache=cache)


def read_drift(run_dir: Path, warn: Warn) -> pd.DataFrame | None:
    """One run's per-frame unaligned error, in and off the plane of its ground-truth path
    (``drift_components``), or None without both trajectories."""
    est = read_trajectory(run_dir / "traj_est.txt", warn)
    gt = read_trajectory(run_dir / "traj_gt.txt", warn)
    if est is None or gt is None:
        return None
    try:
        return pd.DataFrame(drift_components(est, gt))
    except MetricError as exc:
        warn(f"skipped {run_dir} in the drift figure: {exc}")
        return None


def plot_drift(runs: pd.DataFrame, dataset: str, seq: str, out: Path, warn: Warn) -> Path | None:
    """The pose error the ATE's alignment hides, against the distance driven: a slow pitch lifts a
    drive off its plane, which the SE(3) fit tilts back, and a loss shows as the error running away."""
    one = runs[runs["seq"] == seq]
    cache: dict[str, pd.DataFrame | None] = {str(p): read_drift(Path(p), warn) for p in one["path"]}
    if not any(v is not None and len(v) for v in cache.values()):
        return None
    rows: tuple[tuple[str, KfValue], ...] = (
        ("position error in the drive's plane [m]\n(unaligned, from the first frame)",
         lambda _r, d: d["in_plane_err_m"]),
        ("error off the drive's plane [m]\n(height, for a flat drive)", lambda _r, d: d["off_plane_err_m"]),
    )
    return plot_per_keyframe(runs, dataset, seq, out, warn, "pose_error_vs_distance", "Unaligned pose error against "
                             "distance", rows, x_col="path_length_m", cache=cache)


def _dataset_average(runs: pd.DataFrame, metric: str) -> tuple[float | None, int]:
    """Mean over sequences of the seed means of ok runs (the tables' Avg), and how many
    sequences it covers."""
    ok = runs[(runs["status"] == "ok") & runs[metric].notna()] if metric in runs else runs.iloc[0:0]
    if ok.empty:
        return None, 0
    per_seq = ok.groupby("seq")[metric].mean()
    return float(statistics.fmean(per_seq)), len(per_seq)


def _per_seed_average(runs: pd.DataFrame, metric: str) -> pd.Series:
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
    swept = sorted({v.slam_preset for v in found if sum(u.strategy == v.strategy and u.slam_preset == v.slam_preset
                                                         for u in found) > 1})  # fmt: skip
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
                seeds = _per_seed_average(vr, metric)
                spread = float(seeds.std()) if len(seeds) > 1 else float("nan")
                by_strategy.setdefault(variant.strategy, []).append(
                    (variant.keep_ratio, _dataset_average(vr, metric)[0], spread, all_lost)
                )
            for strategy, points in by_strategy.items():
                colour = strategy_colour(strategy, known)
                numeric = sorted((k, v, e) for k, v, e, _ in points if k is not None and v is not None)
                if len(numeric) > 1:
                    x, y, e = (np.array(t, dtype=float) for t in zip(*numeric, strict=True))
                    band(ax, x, y, e, colour)
                elif numeric:
                    k, v, e = numeric[0]
                    k += DODGE * (sorted(by_strategy).index(strategy) - (len(by_strategy) - 1) / 2)
                    ax.errorbar([k], [v], yerr=None if math.isnan(e) else [e], fmt="s", color=colour, capsize=3, ms=5)
                elif len(points) == 1 and points[0][1] is not None:
                    _, v, e, _ = points[0]
                    ax.axhline(v, color=colour, ls=":", lw=1.3)
                    if not math.isnan(e):
                        ax.axhspan(v - e, v + e, color=colour, alpha=0.08, lw=0)
                lost = [k for k, _, _, is_lost in points if is_lost and k is not None]
                if lost:
                    any_lost = True
                    ax.plot(lost, [0.02] * len(lost), "x", ms=9, mew=2, color=colour,
                            transform=ax.get_xaxis_transform(), clip_on=False)  # fmt: skip
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
    return _save(fig, out / f"ratio_{file_token(dataset)}.png")


def _front(points: list[tuple[float, float]], lower_is_better: bool) -> list[tuple[float, float]]:
    """Non-dominated points, sorted by memory: none uses less memory and is more accurate."""
    front: list[tuple[float, float]] = []
    for mem, acc in sorted(points):
        if not front or (acc < front[-1][1] if lower_is_better else acc > front[-1][1]):
            front.append((mem, acc))
    return front


def plot_pareto(runs: pd.DataFrame, dataset: str, out: Path) -> Path | None:
    """Accuracy against peak memory per method (dataset averages), with the Pareto front of each
    panel: one column per preset (and keep-ratio sweep), ATE above PSNR, y shared along a row.

    A method measured on fewer sequences than the others is drawn hollow and kept off the
    front: its average is over easier or fewer sequences and would not be a fair point.
    """
    known = sorted(set(runs["strategy"]))
    n_seqs = runs["seq"].nunique()
    memory: dict[Variant, tuple[float, int]] = {}
    for variant in variants(runs):
        mem, covered = _dataset_average(variant_runs(runs, variant), "peak_mem_mib")
        if mem is not None:
            memory[variant] = (mem, covered)
    panels = [p for p in panel_groups(list(memory)) if p.variants]
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
                mem, mem_covered = memory[variant]
                vr = variant_runs(runs, variant)
                value, covered = _dataset_average(vr, metric)
                if value is None:
                    continue
                complete = min(covered, mem_covered) == n_seqs
                colour = strategy_colour(variant.strategy, known)
                _, marker = ratio_style(variant, panel)
                seeds = pd.concat([_per_seed_average(vr, "peak_mem_mib"), _per_seed_average(vr, metric)], axis=1,
                                  keys=["mem", "value"]).dropna()  # fmt: skip
                most_seeds = max(most_seeds, len(seeds))
                if len(seeds) >= 2:
                    ax.errorbar(mem, value, xerr=seeds["mem"].std(), yerr=seeds["value"].std(), fmt="none",
                                ecolor=colour, elinewidth=1.0, capsize=2, zorder=2)  # fmt: skip
                ax.scatter(mem, value, s=40, marker=marker, zorder=3, color=colour if complete else "white",
                           edgecolors=colour, linewidths=1.2)  # fmt: skip
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
    handles = strategy_keys(panels, known)
    if fronts:
        handles.append(key("dashed: Pareto front of the panel", "grey", "--"))
    if most_seeds >= 2:
        handles.append(key("bars: ± 1 std over seeds", "grey", "-", "|"))
    if hollow:
        handles.append(key("hollow: not measured on every sequence", "black", "none", "o", mfc="white"))
    legend_outside(fig, handles)
    seeds = f"mean of {most_seeds} seeds" if most_seeds >= 2 else "1 seed: no noise estimate"
    fig_title(fig, f"Accuracy vs peak memory, {dataset_name(dataset)} (mean over sequences, {seeds})")
    return _save(fig, out / f"pareto_{file_token(dataset)}.png")


def check_figure_options(formats: tuple[str, ...], dpi: int) -> None:
    """One ``ReportError`` line unless every format is one we draw and ``dpi`` is positive: checked
    before a report writes anything, so a refused one leaves its folder as it was."""
    bad = [f for f in formats if f not in FORMATS]
    if bad or not formats:
        raise ReportError(f"expected figure formats among {', '.join(FORMATS)}, found {', '.join(formats) or '(none)'}")
    if dpi <= 0:
        raise ReportError(f"expected a positive dpi, found {dpi}")


def make_plots(
    runs: pd.DataFrame, out: Path, warn: Warn, formats: tuple[str, ...] = ("png",), dpi: int = DPI,
    keyframes: dict[str, pd.DataFrame] | None = None, milestones: dict[str, pd.DataFrame] | None = None,
    long_drives: bool = False,
) -> list[Path]:
    """Every figure the runs support, in each of ``formats``; finished runs only. ``keyframes`` and
    ``milestones`` (run path -> its rows) stand in for run dirs that are gone (``redraw``).
    ``long_drives``: also memory against distance and accuracy at the milestones (``eval.at_frames``)."""
    check_figure_options(formats, dpi)
    previous = dict(_output)
    _output.update(formats=tuple(formats), dpi=int(dpi), keyframes=keyframes or {}, milestones=milestones or {},
                   long_drives=long_drives)
    try:
        first = _make_plots(runs, out, warn)
    finally:
        _output.update(previous)
    return [p.with_suffix(f".{ext}") for p in first for ext in formats]


def _make_plots(runs: pd.DataFrame, out: Path, warn: Warn) -> list[Path]:
    done = runs[runs["status"].isin(["ok", "lost"])]
    written: list[Path | None] = []
    for dataset in sorted(set(done["dataset"])):
        ds = done[done["dataset"] == dataset]
        for seq in sorted(set(ds["seq"]), key=lambda s: sequence_sort_key(dataset, s)):
            for stem, title, rows in PER_KEYFRAME:
                written.append(plot_per_keyframe(ds, dataset, seq, out, warn, stem, title, rows))
            if _output["long_drives"]:  # the scale study's figures (bench/report/route_scale.py)
                written.append(plot_per_keyframe(ds, dataset, seq, out, warn, *MEMORY_VS_DISTANCE, x_col="distance_m"))
                written.append(plot_milestones(ds, dataset, seq, out, warn))
                written.append(plot_drift(ds, dataset, seq, out, warn))
            written.append(plot_density(ds, dataset, seq, out, warn))
            written.append(plot_trajectory(ds, dataset, seq, out, warn))
            written += plot_pruned(ds, dataset, seq, out, warn)
        written.append(plot_ratio(ds, dataset, out))
        written.append(plot_pareto(ds, dataset, out))
    return [p for p in written if p is not None]
