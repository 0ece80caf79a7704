"""Which runs a figure shows, and their per-keyframe tables: the representative run, seed bands, distance driven."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pandas as pd

from bench import schema
from bench.errors import MetricError
from bench.metrics.trajectory import (
    distance_along,
    read_tum,
)
from bench.report.collect import read_run_table
from bench.report.figures.output import OUTPUT, Warn


def representative(runs: pd.DataFrame) -> pd.Series | None:
    """The run a per-run figure shows for one variant: the lowest-seed ok run, else a lost one."""
    for status in ("ok", "lost"):
        pick = runs[runs["status"] == status]
        if len(pick):
            return pick.sort_values("seed", na_position="last").iloc[0]
    return None


def read_keyframes(run_dir: Path, warn: Warn) -> pd.DataFrame | None:
    stored = OUTPUT.get("keyframes", {}).get(str(run_dir))
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


def runs_to_show(vr: pd.DataFrame) -> tuple[pd.DataFrame, bool]:
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
    shown, lost = runs_to_show(vr)
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


def peak_series(run: pd.Series, kf: pd.DataFrame) -> pd.Series | None:
    column = peak_column(run, kf)
    return None if column is None else kf[column]
