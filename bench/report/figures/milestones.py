"""Accuracy at the milestones of a long drive (``eval.at_frames``): ATE and PSNR against distance."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from bench.report.figures.output import OUTPUT, Warn
from bench.report.figures.per_keyframe import plot_per_keyframe
from bench.report.figures.runs import KfValue


def plot_milestones(runs: pd.DataFrame, dataset: str, seq: str, out: Path, warn: Warn) -> Path | None:
    """ATE and PSNR at each ``eval.at_frames`` milestone against the distance driven by then: what
    drives of those lengths score, from the same runs."""
    from bench.report.route_scale import read_milestones

    one = runs[runs["seq"] == seq]
    cache: dict[str, pd.DataFrame | None] = {}
    for path in one["path"]:
        cache[str(path)] = OUTPUT["milestones"].get(str(path))
        if cache[str(path)] is None:
            cache[str(path)] = read_milestones(Path(path), warn)
    if not any(v is not None and len(v) for v in cache.values()):
        return None
    rows: tuple[tuple[str, KfValue], ...] = (
        ("ATE RMSE [m]\n(the trajectory so far)", lambda _r, ms: ms["ate_rmse_m"]),
        ("PSNR [dB]\n(the map then, frames so far)", lambda _r, ms: ms["psnr_db"]),
    )
    return plot_per_keyframe(
        runs,
        dataset,
        seq,
        out,
        warn,
        "accuracy_vs_distance",
        "Accuracy against distance",
        rows,
        x_col="path_length_m",
        cache=cache,
    )
