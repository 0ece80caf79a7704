"""Pose error against distance: the unaligned position error within the ground-truth path's plane and off it."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from bench.errors import MetricError
from bench.metrics.trajectory import (
    drift_components,
)
from bench.report.figures.output import Warn
from bench.report.figures.per_keyframe import plot_per_keyframe
from bench.report.figures.runs import KfValue
from bench.report.figures.trajectory import read_trajectory


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
        (
            "position error in the drive's plane [m]\n(unaligned, from the first frame)",
            lambda _r, d: d["in_plane_err_m"],
        ),
        ("error off the drive's plane [m]\n(height, for a flat drive)", lambda _r, d: d["off_plane_err_m"]),
    )
    return plot_per_keyframe(
        runs,
        dataset,
        seq,
        out,
        warn,
        "pose_error_vs_distance",
        "Unaligned pose error against distance",
        rows,
        x_col="path_length_m",
        cache=cache,
    )
