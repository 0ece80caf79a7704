"""What pruning removed, side by side on one keyframe per strategy (from the runs' ``viz.pruning`` records)."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from bench.names import dataset_name, file_token
from bench.report.figures.output import Warn, image_axes, save_figure
from bench.report.figures.runs import representative
from bench.report.style import (
    fig_title,
    new_figure,
    panel_groups,
    series_label,
    strategy_colour,
)
from bench.report.variants import Variant, variant_runs, variants
from bench.run.figures import pruned_run as viz

PRUNED_GLOB = viz.PRUNED_GLOB


def pruned_records(run_dir: Path, warn: Warn) -> dict[int, Path]:
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
            records = {} if run is None else pruned_records(Path(run["path"]), warn)
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
        image_axes(axes[0, 0], "0.5")
        for ax in axes[0, 1:]:
            ax.set_axis_off()
        note = axes[0, 1].text(
            0.0, 0.5, PRUNED_NOTE, transform=axes[0, 1].transAxes, va="center", ha="left", fontsize=8
        )
        note.set_in_layout(False)  # the text may run over the empty panel beside it
        points = None
        for row, (variant, r) in enumerate(data, start=1):
            colour = strategy_colour(variant.strategy, known)
            name = series_label(variant, panel)
            for col, (image, when) in enumerate(((r["before"], "before"), (r["after"], "after"))):
                axes[row, col].imshow(image)
                axes[row, col].set_title(
                    f"render {when} the prune ({viz.caption_psnr_db(image, r['image']):.2f} dB)", fontsize=8
                )
                image_axes(axes[row, col], colour)
            points = viz.draw_centres(axes[row, 2], r, norm, size=2.0)
            axes[row, 2].set_title(f"{int(r['n_pruned']):,} of {int(r['n_before']):,} Gaussians pruned", fontsize=8)
            axes[row, 0].set_ylabel(name.replace(" (", "\n("), fontsize=8)
            image_axes(axes[row, 2], colour)
        if points is not None:
            fig.colorbar(points, ax=axes[1:, 2].tolist(), label="coverage $C_i$ [px]", shrink=0.6)
        where = ", " + panel.title.replace("\n", " ") if panel.title else ""
        fig_title(fig, f"What each strategy pruned, {dataset_name(dataset)} {seq}{where} (PSNR against the keyframe)")
        token = f"_{file_token(panel.title)}" if panel.title else ""
        written.append(save_figure(fig, out / f"pruned_{file_token(dataset)}_{file_token(seq)}{token}_kf{kf:03d}.png"))
    return written
