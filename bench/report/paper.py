"""The paper's published figures (Tables I-IV), shipped as package data.

``paper_tables.csv`` is a copy of ``shared/paper/pocket_slam_tables.csv``: the product must not
read outside its package at run time, so reports stay reproducible from an installed wheel.
"""

from __future__ import annotations

from importlib import resources

import pandas as pd

from bench.errors import ReportError

PAPER_CSV = "paper_tables.csv"
PAPER_COLUMNS: tuple[str, ...] = ("table", "dataset", "method", "metric", "sequence", "value")
LOST = "-"  # the paper's mark for lost tracking

# Paper method -> our strategy, to place "(paper) X" rows beside the measured row of X.
PAPER_STRATEGY: dict[str, str] = {
    "LSG-SLAM": "none",
    "LightGaussian": "opacity",
    "LP-3DGS": "gradient",
    "MaskGaussian": "mask",
    "Ours (w/o Tile Budget)": "area",
    "Ours (w/ Tile Budget)": "pocket",
    "Ours": "pocket",  # the performance tables name the full method just "Ours"
}
# Our column metric -> the paper's metric name. The paper's "SSIM" is MS-SSIM: its base system's
# evaluation (SplaTAM utils/eval_helpers.py, eval) calls pytorch_msssim's ms_ssim and names the result ssim.
PAPER_METRIC: dict[str, str] = {
    "ate_rmse_m": "ATE",
    "psnr_db": "PSNR",
    "ms_ssim": "SSIM",
    "lpips": "LPIPS",
    "peak_mem_mib": "Memory_GB",
    "fps": "FPS",
}
PAPER_UNIT: dict[str, str] = {"Memory_GB": " GB"}


def load_paper_tables() -> pd.DataFrame:
    """The tidy paper table, every column as text (values keep their printed precision)."""
    try:
        with resources.files("bench.report").joinpath(PAPER_CSV).open("r", encoding="utf-8") as handle:
            frame = pd.read_csv(handle, dtype=str, keep_default_na=False)
    except (OSError, pd.errors.ParserError) as exc:
        raise ReportError(f"cannot read packaged {PAPER_CSV}: {exc}") from exc
    missing = [c for c in PAPER_COLUMNS if c not in frame.columns]
    if missing:
        raise ReportError(f"expected columns {', '.join(PAPER_COLUMNS)} in {PAPER_CSV}, found {list(frame.columns)}")
    return frame


def paper_values(paper: pd.DataFrame, table: str, dataset: str) -> dict[str, dict[str, dict[str, str]]]:
    """``{method: {metric: {sequence: printed value}}}`` for one table and dataset, in paper order."""
    rows = paper[(paper["table"] == table) & (paper["dataset"] == dataset)]
    out: dict[str, dict[str, dict[str, str]]] = {}
    for rec in rows.itertuples(index=False):
        out.setdefault(rec.method, {}).setdefault(rec.metric, {})[rec.sequence] = rec.value.strip()
    return out
