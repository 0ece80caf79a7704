"""Figures in the style of the paper's Figs. 3a, 4 and 5, plus trajectory and Pareto views.

Built on ``matplotlib.figure.Figure`` rather than pyplot: no global backend switch (Agg is
used for PNG regardless) and no figure left open in a caller's session. Each plot reads only
the run dir files the harness writes; a missing or malformed file costs that line a warning,
never the report. Per-sequence figures take the whole dataset's runs plus a sequence, so labels,
colours and markers match the tables and each other; they show each method's lowest-seed run.
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Callable
from pathlib import Path
from typing import Any

import matplotlib
import numpy as np
import pandas as pd
from matplotlib.colors import LogNorm
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.ticker import FormatStrFormatter

from bench import schema
from bench.errors import MetricError, ReportError
from bench.metrics.trajectory import MAX_DIFF_S, Trajectory, aligned_positions, read_tum
from bench.report.collect import is_missing
from bench.report.names import STRATEGY_ORDER, dataset_name, file_token, method_name, sequence_sort_key
from bench.report.tables import Variant, variant_runs, variants

Warn = Callable[[str], None]
DPI = 110
DENSITY_CELLS = 160  # heatmap cells along the longer image side (Fig. 4 is a coarse heatmap too)


MARKERS: tuple[str, ...] = ("o", "s", "^", "D", "v", "P")
DASHES: tuple[str, ...] = ("-", "-.", ":", (0, (5, 1)))


class Looks:
    """A fixed colour per strategy (one method looks the same in every figure), and a marker and
    dash per keep ratio within a strategy."""

    def __init__(self, runs: pd.DataFrame) -> None:
        self._extra = sorted(s for s in set(runs["strategy"]) if s not in STRATEGY_ORDER)
        self._nth: dict[Variant, int] = {}
        for variant in variants(runs):
            self._nth[variant] = sum(v.strategy == variant.strategy for v in self._nth)

    def colour(self, strategy: str) -> tuple[float, ...]:
        palette = matplotlib.colormaps["tab10"].colors
        if strategy in STRATEGY_ORDER:
            index = STRATEGY_ORDER.index(strategy)
        else:
            index = len(STRATEGY_ORDER) + (self._extra.index(strategy) if strategy in self._extra else 0)
        return palette[index % len(palette)]

    def marker(self, variant: Variant) -> str:
        return MARKERS[self._nth.get(variant, 0) % len(MARKERS)]

    def dash(self, variant: Variant) -> str | tuple:
        return DASHES[self._nth.get(variant, 0) % len(DASHES)]


FORMATS: tuple[str, ...] = ("png", "pdf", "svg")
# What the figure files are made as; ``make_plots`` sets it for the duration of one report.
_output: dict[str, Any] = {"formats": ("png",), "dpi": DPI}
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
    path = Path(run_dir) / schema.KEYFRAMES_FILE
    if not path.is_file():
        return None
    try:
        frame = pd.read_csv(path)
    except (OSError, ValueError) as exc:
        warn(f"skipped {path} in plots: expected a csv table, found {exc}")
        return None
    if "state_mib" not in frame.columns or not ({"frame", "kf"} & set(frame.columns)):
        warn(f"skipped {path} in plots: expected columns kf/frame and state_mib, found {list(frame.columns)}")
        return None
    return frame


def peak_column(run: pd.Series, keyframes: pd.DataFrame) -> str | None:
    """The keyframes.csv column behind the run's headline ``peak_mem_mib``: the one its
    ``peak_mem_source`` names (``bench.schema.PEAK_SOURCES``), if the file holds values there."""
    column = schema.peak_column(run.get(schema.PEAK_SOURCE_FIELD))
    return column if column in keyframes.columns and keyframes[column].notna().any() else None


def plot_memory_per_keyframe(runs: pd.DataFrame, dataset: str, seq: str, out: Path, warn: Warn) -> Path | None:
    """Fig. 5: peak memory (solid, left axis) and map state (dashed, right axis) per keyframe, and
    beside it the churn panel: Gaussians in the map (solid) and added so far (dotted).

    The map state is orders of magnitude below the process peak, so it gets its own axis. The churn
    panel shows whether pruning shrank the map or only fed re-seeding: a pruned run whose dotted
    line climbs far above the baseline's re-adds what it prunes.
    """
    fig = Figure(figsize=(13.0, 4.2), layout="constrained")
    ax, churn_ax = fig.subplots(1, 2, width_ratios=(1.4, 1.0))
    state_ax = ax.twinx()
    looks = Looks(runs)
    probes: set[str] = set()
    drawn = other_seeds = 0
    one = runs[runs["seq"] == seq]
    for variant in variants(runs):  # dataset-wide, so labels match the tables
        run = representative(variant_runs(one, variant))
        if run is None:
            continue
        kf = read_keyframes(Path(run["path"]), warn)
        if kf is None or kf.empty:
            continue
        x = kf["frame"] if "frame" in kf.columns else kf["kf"]
        colour, marker = looks.colour(variant.strategy), looks.marker(variant)
        label = variant.label + (" (lost)" if run["status"] == "lost" else "")
        column = peak_column(run, kf)
        if column is not None:
            probes.add(column)
            ax.plot(x, kf[column], "-", marker=marker, ms=4, color=colour, label=label)
        state_ax.plot(x, kf["state_mib"], "--", marker=marker, ms=3, mfc="none", color=colour,
                      label=None if column else label)  # fmt: skip
        if "n_gaussians" in kf.columns:
            churn_ax.plot(x, kf["n_gaussians"], "-", marker=marker, ms=3, color=colour, label=label)
        if "n_added" in kf.columns:
            churn_ax.plot(x, kf["n_added"].cumsum(), ":", color=colour)
        drawn += 1
        # the other seeds' peaks, thin: how much of a gap between methods the seeds alone open
        for _, other in variant_runs(one, variant).iterrows():
            if other["path"] == run["path"] or other["status"] not in ("ok", "lost"):
                continue
            okf = read_keyframes(Path(other["path"]), warn)
            other_column = None if okf is None or okf.empty else peak_column(other, okf)
            if other_column is not None:
                ox = okf["frame"] if "frame" in okf.columns else okf["kf"]
                ax.plot(ox, okf[other_column], "-", lw=0.8, alpha=0.35, color=colour)
                other_seeds += 1
    if not drawn:
        return None
    probe_names = ", ".join(PROBE_NAMES.get(p, p) for p in sorted(probes)) or "n/a"
    ax.set_xlabel("frame")
    ax.set_ylabel(f"peak memory per keyframe window [MiB] ({probe_names})", fontsize="small")
    state_ax.set_ylabel("map state (Gaussian parameters, gradients, Adam) [MiB]", fontsize="small")
    ax.set_title(f"Memory per keyframe, {dataset_name(dataset)} {seq}")
    ax.grid(alpha=0.3)
    handles = ax.get_legend_handles_labels()[0] + state_ax.get_legend_handles_labels()[0]
    handles += [_style_key("solid: peak memory (left axis)", ls="-"),
                _style_key("dashed: map state (right axis)", ls="--")]  # fmt: skip
    if other_seeds:
        handles.append(_style_key("thin: the other seeds' peaks", ls="-", lw=0.8, alpha=0.35))
    ax.legend(handles=handles, fontsize="x-small", loc="best")
    churn_ax.set_xlabel("frame")
    churn_ax.set_ylabel("Gaussians [count]", fontsize="small")
    churn_ax.set_title("Churn")
    churn_ax.grid(alpha=0.3)
    churn_handles = churn_ax.get_legend_handles_labels()[0]
    churn_handles += [_style_key("solid: Gaussians in the map", ls="-"), _style_key("dotted: added so far", ls=":")]
    churn_ax.legend(handles=churn_handles, fontsize="x-small", loc="best")
    return _save(fig, out / f"memory_per_keyframe_{file_token(dataset)}_{file_token(seq)}.png")


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
    """Top view of estimated vs ground-truth paths on the two axes of largest extent."""
    looks = Looks(runs)
    gt: np.ndarray | None = None  # [M, 3] ground-truth positions
    paths: list[tuple[Variant, np.ndarray, bool]] = []
    one = runs[runs["seq"] == seq]
    for variant in variants(runs):  # dataset-wide, so labels match the tables
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
    if not paths:
        return None
    extent_source = gt if gt is not None else np.vstack([p for _, p, _ in paths])
    axes = sorted(np.argsort(np.ptp(extent_source, axis=0))[-2:])
    names = "xyz"
    fig = Figure(figsize=(6.0, 5.5), layout="constrained")
    ax = fig.add_subplot()
    if gt is not None:
        ax.plot(gt[:, axes[0]], gt[:, axes[1]], "k-", lw=2.0, alpha=0.6, label="ground truth")
    for variant, xyz, lost in paths:
        label = variant.label + (" (lost)" if lost else "")
        ax.plot(xyz[:, axes[0]], xyz[:, axes[1]], ls=looks.dash(variant), lw=1.2,
                color=looks.colour(variant.strategy), label=label)  # fmt: skip
    ax.set_xlabel(f"{names[axes[0]]} [m]")
    ax.set_ylabel(f"{names[axes[1]]} [m]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_title(f"Trajectory, {dataset_name(dataset)} {seq} (estimates aligned as for ATE)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize="x-small")
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


def plot_density(runs: pd.DataFrame, dataset: str, seq: str, out: Path, warn: Warn) -> Path | None:
    """Fig. 4: where each strategy's final Gaussians project, on one shared log colour scale."""
    panels: list[tuple[str, np.ndarray, np.ndarray | None]] = []
    one = runs[runs["seq"] == seq]
    for variant in variants(runs):  # dataset-wide, so labels match the tables
        run = representative(variant_runs(one, variant))
        if run is None:
            continue
        density = read_density(Path(run["path"]), warn)
        if density is not None:
            panels.append((variant.label, *density))
    if not panels:
        return None
    ncols = min(3, len(panels))
    nrows = math.ceil(len(panels) / ncols)
    h, w = panels[0][1].shape
    block = max(1, math.ceil(max(h, w) / DENSITY_CELLS))
    pooled = [pool_counts(counts, block) for _, counts, _ in panels]
    fig = Figure(figsize=(3.6 * ncols, 3.6 * nrows * h / w + 0.8), layout="constrained")
    axes = fig.subplots(nrows, ncols, squeeze=False)
    norm = LogNorm(vmin=1.0, vmax=max(2.0, max(float(p.max()) for p in pooled)))
    mappable = None
    for ax, (label, counts, image), cells in zip(axes.ravel(), panels, pooled, strict=False):
        if image is not None:
            ax.imshow(np.clip(image, 0.0, 1.0).mean(axis=2), cmap="gray", vmin=0.0, vmax=1.0)
        ph, pw = cells.shape
        extent = (-0.5, pw * block - 0.5, ph * block - 0.5, -0.5)
        mappable = ax.imshow(np.ma.masked_less(cells, 1.0), cmap="inferno", norm=norm, alpha=0.75, extent=extent)
        ax.set_xlim(-0.5, counts.shape[1] - 0.5)
        ax.set_ylim(counts.shape[0] - 0.5, -0.5)
        ax.set_title(f"{label}\n{int(counts.sum())} Gaussians in view", fontsize="small")
        ax.set_axis_off()
    for ax in axes.ravel()[len(panels) :]:
        ax.set_axis_off()
    if mappable is not None:
        unit = "pixel" if block == 1 else f"{block}x{block} px cell"
        bar = fig.colorbar(mappable, ax=axes.ravel().tolist(), label=f"Gaussian centres per {unit}", shrink=0.8)
        bar.ax.yaxis.set_major_formatter(FormatStrFormatter("%g"))
        bar.ax.yaxis.set_minor_formatter(FormatStrFormatter("%g"))
    fig.suptitle(f"Gaussian density, {dataset_name(dataset)} {seq}")
    return _save(fig, out / f"density_{file_token(dataset)}_{file_token(seq)}.png")


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
    strategy ran at two or more ratios. Strategies run at one ratio are a point at that ratio
    (pocket at 0.4 beside the area sweep); a baseline without one is a dashed reference."""
    found = variants(runs)
    swept = {v.slam_preset for v in found
             if sum(u.strategy == v.strategy and u.slam_preset == v.slam_preset for u in found) > 1}  # fmt: skip
    if not swept:
        return None  # no strategy ran at two keep ratios: nothing to plot against
    several_presets = len(swept) > 1
    looks = Looks(runs)
    fig = Figure(figsize=(9.0, 3.8), layout="constrained")
    axes = fig.subplots(1, 2)
    any_lost = False
    for ax, (metric, title) in zip(axes, (("ate_rmse_m", "ATE [m]"), ("psnr_db", "PSNR [dB]")), strict=True):
        lines: dict[tuple[str, str], list[tuple[float | None, float | None, float, bool]]] = {}
        for variant in (v for v in found if v.slam_preset in swept):
            vr = variant_runs(runs, variant)
            all_lost = bool(len(vr)) and not (vr["status"] == "ok").any() and (vr["status"] == "lost").any()
            seeds = _per_seed_average(vr, metric)
            spread = float(seeds.std()) if len(seeds) > 1 else 0.0
            lines.setdefault((variant.strategy, variant.slam_preset), []).append(
                (variant.keep_ratio, _dataset_average(vr, metric)[0], spread, all_lost)
            )
        for (strategy, preset), points in lines.items():
            colour = looks.colour(strategy)
            label = method_name(strategy) + (f" [{preset}]" if several_presets else "")
            numeric = sorted((k, v, e) for k, v, e, _ in points if k is not None and v is not None)
            dash = "--" if preset != sorted(swept)[0] else "-"
            if numeric:
                style = f"{dash}o" if len(numeric) > 1 else "s"
                ax.errorbar([k for k, _, _ in numeric], [v for _, v, _ in numeric], yerr=[e for _, _, e in numeric],
                            fmt=style, color=colour, capsize=3, ms=5, label=label)  # fmt: skip
            elif len(points) == 1 and points[0][1] is not None:
                ax.axhline(points[0][1], color=colour, ls=":", lw=1.2, label=f"{label} (no pruning)")
            lost = [k for k, _, _, is_lost in points if is_lost and k is not None]
            if lost:
                any_lost = True
                ax.plot(lost, [0.02] * len(lost), "x", ms=9, mew=2, color=colour,
                        transform=ax.get_xaxis_transform(), clip_on=False)  # fmt: skip
        ax.set_xlabel("keep ratio (fraction of candidates kept)")
        ax.set_ylabel(title)
        ax.grid(alpha=0.3)
    handles = axes[0].get_legend_handles_labels()[0]
    handles.append(_style_key("bars: ± std over seeds; square: one ratio", ls="none", marker="s"))
    if any_lost:
        handles.append(_style_key("x: all seeds lost", ls="none", marker="x", mew=2))
    axes[0].legend(handles=handles, fontsize="x-small")
    fig.suptitle(f"Accuracy vs keep ratio, {dataset_name(dataset)} (mean over sequences)")
    return _save(fig, out / f"ratio_{file_token(dataset)}.png")


def _front(points: list[tuple[float, float]], lower_is_better: bool) -> list[tuple[float, float]]:
    """Non-dominated points, sorted by memory: none uses less memory and is more accurate."""
    front: list[tuple[float, float]] = []
    for mem, acc in sorted(points):
        if not front or (acc < front[-1][1] if lower_is_better else acc > front[-1][1]):
            front.append((mem, acc))
    return front


def plot_pareto(runs: pd.DataFrame, dataset: str, out: Path) -> Path | None:
    """Accuracy against peak memory per method (dataset averages), with the Pareto front.

    A method measured on fewer sequences than the others is drawn hollow and kept off the
    front: its average is over easier or fewer sequences and would not be a fair point.
    """
    looks = Looks(runs)
    n_seqs = runs["seq"].nunique()
    points: list[tuple[Variant, float, int]] = []
    for variant in variants(runs):
        mem, covered = _dataset_average(variant_runs(runs, variant), "peak_mem_mib")
        if mem is not None:
            points.append((variant, mem, covered))
    if not points:
        return None
    fig = Figure(figsize=(9.5, 4.2), layout="constrained")
    axes = fig.subplots(1, 2)
    panels = (("ate_rmse_m", "ATE [m]", True), ("psnr_db", "PSNR [dB]", False))
    hollow = False
    most_seeds = 0
    for ax, (metric, title, lower) in zip(axes, panels, strict=True):
        full: list[tuple[float, float]] = []
        for variant, mem, mem_covered in points:
            vr = variant_runs(runs, variant)
            value, covered = _dataset_average(vr, metric)
            if value is None:
                continue
            complete = min(covered, mem_covered) == n_seqs
            colour = looks.colour(variant.strategy)
            ax.scatter(mem, value, s=45, marker=looks.marker(variant), zorder=3, label=variant.label,
                       color=colour if complete else "none", edgecolors=colour)  # fmt: skip
            # the seeds behind the mean: one small point each, and +-1 sample std bars
            seeds = pd.concat([_per_seed_average(vr, "peak_mem_mib"), _per_seed_average(vr, metric)], axis=1,
                              keys=["mem", "value"]).dropna()  # fmt: skip
            most_seeds = max(most_seeds, len(seeds))
            if len(seeds) >= 2:
                ax.scatter(seeds["mem"], seeds["value"], s=12, marker=looks.marker(variant), color=colour,
                           alpha=0.45, zorder=2)  # fmt: skip
                ax.errorbar(mem, value, xerr=seeds["mem"].std(), yerr=seeds["value"].std(), fmt="none", ecolor=colour,
                            elinewidth=0.8, capsize=2, zorder=2)  # fmt: skip
            if complete:
                full.append((mem, value))
            hollow = hollow or not complete
        front = _front(full, lower)
        if len(front) > 1:
            ax.plot(*zip(*front, strict=True), "--", color="grey", lw=1.0, drawstyle="steps-post", zorder=2,
                    label="dashed: Pareto front")  # fmt: skip
            ax.legend(fontsize="x-small", loc="best")
        ax.set_xlabel("peak memory [MiB]")
        ax.set_ylabel(title + (" (lower is better)" if lower else " (higher is better)"))
        ax.grid(alpha=0.3)
    handles = axes[0].get_legend_handles_labels()[0]
    if hollow:
        handles.append(_style_key("hollow: not measured on every sequence", ls="none", marker="o", mfc="none"))
    if most_seeds >= 2:
        handles.append(_style_key("small: one seed each; bars: ±1 std over seeds", ls="none", marker="o", ms=3))
    axes[0].legend(handles=handles, fontsize="x-small")
    seeds = "" if most_seeds >= 2 else "; 1 seed: no noise estimate"
    fig.suptitle(f"Accuracy vs peak memory, {dataset_name(dataset)} (mean over sequences{seeds})", fontsize="medium")
    return _save(fig, out / f"pareto_{file_token(dataset)}.png")


def make_plots(
    runs: pd.DataFrame, out: Path, warn: Warn, formats: tuple[str, ...] = ("png",), dpi: int = DPI
) -> list[Path]:
    """Every figure the runs support, in each of ``formats``; finished runs only."""
    bad = [f for f in formats if f not in FORMATS]
    if bad or not formats:
        raise ReportError(f"expected figure formats among {', '.join(FORMATS)}, found {', '.join(formats) or '(none)'}")
    if dpi <= 0:
        raise ReportError(f"expected a positive dpi, found {dpi}")
    previous = dict(_output)
    _output.update(formats=tuple(formats), dpi=int(dpi))
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
            written.append(plot_memory_per_keyframe(ds, dataset, seq, out, warn))
            written.append(plot_density(ds, dataset, seq, out, warn))
            written.append(plot_trajectory(ds, dataset, seq, out, warn))
        written.append(plot_ratio(ds, dataset, out))
        written.append(plot_pareto(ds, dataset, out))
    return [p for p in written if p is not None]
