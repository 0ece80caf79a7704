"""Per-run figures written beside metrics.json (the report makes cross-run ones)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure

# the report's probe names (bench/report/figures/per_keyframe.py:PROBE_NAMES), with "peak" said where it is one
SERIES: tuple[tuple[str, str, str], ...] = (
    ("torch_live_peak_mib", "-", "live torch tensors, peak"),
    ("cuda_alloc_peak_mib", "--", "CUDA allocator, peak"),
    ("cpu_rss_peak_mib", ":", "process RSS, peak"),
    ("state_mib", "-.", "map state (exact bytes)"),
)


def memory_timeline(path: Path, windows: list[dict[str, Any]], title: str = "") -> None:
    """Memory and Gaussian count per keyframe window against frame index (paper Fig. 5), one
    quantity per panel: memory probes in MiB on a log axis (they span 1-1000 MiB), Gaussians in
    thousands beside it."""
    fig = Figure(figsize=(9.0, 3.8), layout="constrained")
    mem_ax, count_ax = fig.subplots(1, 2, sharex=True)
    if windows:
        frames = [w["frame"] for w in windows]
        for key, style, label in SERIES:
            vals = [w.get(key) for w in windows]
            if any(v is not None for v in vals):
                mem_ax.plot(
                    frames,
                    [np.nan if v is None else v for v in vals],
                    style,
                    marker="o",
                    ms=3,
                    color="black",
                    label=label,
                )
        count_ax.plot(frames, [w["n_gaussians"] / 1e3 for w in windows], "-o", ms=3, color="black", label="in the map")
        if all("n_added" in w for w in windows):
            count_ax.plot(
                frames,
                np.cumsum([w["n_added"] for w in windows]) / 1e3,
                ":",
                color="black",
                label="added since the start",
            )
    mem_ax.set_yscale("log")
    mem_ax.set_ylabel("memory per keyframe window [MiB]")
    count_ax.set_ylabel("Gaussians [thousands]")
    for ax in (mem_ax, count_ax):
        ax.set_xlabel("frame")
        ax.grid(alpha=0.3, lw=0.6)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.2), ncol=2, frameon=False)  # below
    fig.suptitle(title, x=0.01, ha="left", fontsize=10)
    fig.savefig(path, dpi=110)
