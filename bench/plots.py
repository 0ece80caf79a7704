"""Per-run figures written beside metrics.json (the report makes cross-run ones)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np


def memory_timeline(path: Path, windows: list[dict[str, Any]], title: str = "") -> None:
    """Gaussian count and peak-memory figures per keyframe window against frame index (paper Fig. 5)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 3.5))
    if windows:
        frames = [w["frame"] for w in windows]
        for key, style, label in (
            ("torch_live_peak_mib", "-o", "live torch tensors, peak"),
            ("cuda_alloc_peak_mib", "-s", "CUDA allocator, peak"),
            ("cpu_rss_peak_mib", "--", "process RSS, peak"),
            ("state_mib", "-^", "map state (exact bytes)"),
        ):
            vals = [w.get(key) for w in windows]
            if any(v is not None for v in vals):
                ax.plot(frames, [np.nan if v is None else v for v in vals], style, ms=3, label=label)
        ax2 = ax.twinx()
        ax2.plot(frames, [w["n_gaussians"] for w in windows], ":", color="gray", label="Gaussians (right axis)")
        ax2.set_ylabel("Gaussians [count]")
        ax2.legend(loc="lower right", fontsize=7)
    ax.set_xlabel("frame")
    ax.set_ylabel("memory per keyframe window [MiB]")
    ax.set_yscale("log")
    ax.legend(loc="upper left", fontsize=7)
    ax.set_title(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
