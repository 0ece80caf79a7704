"""When does pruning pay? The regime study's table, its peak ratios, and the paper's run predicted from our bytes.

A pruned run's peak is read against the baseline's (``none``) of the same cell: the same dataset, sequence, preset,
resolution and frame spacing, at the same seed where there is one (else the cell's baseline mean). The descriptors
that place a run in its regime are metrics.json's (``bench.schema.REGIME_FIELDS``): how densely the map grows
(``gaussians_added_per_kf_mpx``), the bytes a Gaussian and a held keyframe cost, and the share of the peak that
follows the Gaussians. With those bytes the paper's own run (``paper_run.yaml``) is predicted from its counts.

``bench.report --regime`` (a study's ``report: {regime: true}``) writes ``regime.md`` and the two figures
(``bench.report.figures.growth``).
"""

from __future__ import annotations

import statistics
from importlib import resources
from typing import Any

import pandas as pd
import yaml

from bench import schema
from bench.names import dataset_name
from bench.report.stats import welch_p
from bench.report.variants import variant_runs, variants

PAPER_RUN_FILE = "paper_run.yaml"
FINISHED = ("ok", "lost")
# what makes two runs comparable: a pruned run is read against the baseline of its cell
CELL_KEYS: tuple[str, ...] = (
    "dataset", "seq", "slam_preset", "dataset.downscale", "dataset.width", "dataset.height", "dataset.stride",
    "max_frames",
)  # fmt: skip
GIB = 1024**3


def paper_run() -> dict[str, Any]:
    """The paper's run and table averages (``paper_run.yaml``)."""
    text = resources.files("bench.report").joinpath(PAPER_RUN_FILE).read_text(encoding="utf-8")
    return yaml.safe_load(text)


def paper_density(run: dict[str, Any]) -> float:
    """The paper's Gaussians added per keyframe per megapixel: its baseline's final map over its keyframes."""
    return run["gaussians_none"] / run["keyframes"] / (run["width"] * run["height"] / 1e6)


def paper_ratio(point: dict[str, Any]) -> float:
    """A paper figure's pruned peak over its unpruned one (``paper_run.yaml``'s run or a table average)."""
    return float(point["peak_pruned_gb"]) / float(point["peak_none_gb"])


def _cell(row: pd.Series) -> tuple:
    return tuple(None if pd.isna(row.get(k)) else row.get(k) for k in CELL_KEYS)


def cell_label(row: pd.Series) -> str:
    """``7-Scenes seq, 1/4, stride 3``: the cell a run belongs to, in words."""
    parts = [f"{dataset_name(str(row['dataset']))} {row['seq']}"]
    if not pd.isna(row.get("dataset.width")) and not pd.isna(row.get("dataset.height")):
        parts.append(f"{int(row['dataset.width'])}x{int(row['dataset.height'])}")
    if not pd.isna(row.get("dataset.downscale")) and int(row["dataset.downscale"]) != 1:
        parts.append(f"1/{int(row['dataset.downscale'])}")
    if not pd.isna(row.get("dataset.stride")) and int(row["dataset.stride"]) != 1:
        parts.append(f"stride {int(row['dataset.stride'])}")
    if not pd.isna(row.get("max_frames")):
        parts.append(f"{int(row['max_frames'])} frames")
    return ", ".join(parts)


def labelled(runs: pd.DataFrame) -> pd.DataFrame:
    """The finished runs (ok or lost), each with its table row's label (``bench.report.variants``, per dataset)."""
    done = runs[runs["status"].isin(FINISHED)].copy()
    done["label"] = ""
    for _, one in done.groupby(done["dataset"].astype(str), sort=False):  # per dataset, as the tables label rows
        for variant in variants(one):
            done.loc[variant_runs(one, variant).index, "label"] = variant.label
    return done


def _baseline_peak(done: pd.DataFrame, row: pd.Series, baseline: str) -> tuple[float | None, str | None]:
    """The baseline's peak for ``row`` (same cell, same seed where there is one; else the cell's mean) and the
    baseline run's path (None for a mean)."""
    cell = _cell(row)
    same = done[(done["strategy"] == baseline) & (done["status"] == "ok")]
    same = same[[_cell(r) == cell for _, r in same.iterrows()]]
    same = same[same["peak_mem_source"] == row["peak_mem_source"]]
    if same.empty:
        return None, None
    seeded = same[same["seed"] == row["seed"]]
    if len(seeded):
        return float(seeded["peak_mem_mib"].iloc[0]), str(seeded["path"].iloc[0])
    return float(same["peak_mem_mib"].mean()), None


def in_view_share(keyframes: pd.DataFrame | None) -> float | None:
    """The mean, over a run's prunes (keyframes after the first), of the share of the map a strategy may prune: the
    candidates (in view, not new) over the Gaussians older than this keyframe (after its densification, before its
    prune: ``n_gaussians + n_pruned - n_added``). None without those columns or rows.

    Why it is a regime descriptor: a prune reaches only what is in view, so where the camera keeps seeing the same
    place (a room) a per-view budget bounds the whole map, and where it leaves things behind (a drive) the map grows
    with the path whatever the budget."""
    need = ("kf", "n_gaussians", "n_pruned", "n_added", "n_candidates")
    if keyframes is None or any(c not in keyframes.columns for c in need):
        return None
    k = keyframes[keyframes["kf"] > 0]
    old = k["n_gaussians"] + k["n_pruned"] - k["n_added"]
    share = (k["n_candidates"] / old.where(old > 0)).dropna()
    return float(share.mean()) if len(share) else None


def run_table(
    runs: pd.DataFrame, baseline: str = "none", keyframes: dict[str, pd.DataFrame] | None = None
) -> pd.DataFrame:
    """One row per finished run: its cell, label, seed, descriptors, peak, ratio to the baseline, accuracy, FPS.
    ``keyframes`` (each run's keyframes.csv by its path), where given, adds ``in_view_share``."""
    done = labelled(runs)
    rows = []
    for _, row in done.iterrows():
        base, base_path = _baseline_peak(done, row, baseline)
        peak = row.get("peak_mem_mib")
        rows.append(
            {
                "cell": cell_label(row),
                "label": row["label"],
                "strategy": row["strategy"],
                "seed": row["seed"],
                "status": row["status"],
                "num_frames": row.get("num_frames"),
                "num_keyframes": row.get("num_keyframes"),
                **{k: row.get(k) for k in schema.REGIME_FIELDS},
                "in_view_share": in_view_share((keyframes or {}).get(str(row["path"]))),
                "gaussians_peak": row.get("gaussians_peak"),
                "gaussians_added_total": row.get("gaussians_added_total"),
                "peak_mem_mib": peak,
                # a lost run's peak is the peak up to where tracking was lost: no ratio to a whole run's
                "peak_ratio": None if base is None or pd.isna(peak) or row["status"] != "ok" else float(peak) / base,
                "baseline_path": base_path,
                "ate_rmse_m": row.get("ate_rmse_m"),
                "psnr_db": row.get("psnr_db"),
                "fps": row.get("fps"),
                "path": row["path"],
            }
        )
    table = pd.DataFrame(rows)
    if table.empty:
        return table
    # each cell's baseline first, then the other rows by label, seeds in order
    order = table.assign(_base=table["strategy"] != baseline).sort_values(
        ["cell", "_base", "label", "seed"], kind="stable"
    )
    return order.drop(columns="_base").reset_index(drop=True)


def _numbers(values: pd.Series) -> list[float]:
    return [float(v) for v in values if not pd.isna(v)]


def _mean_sd(values: list[float], decimals: int) -> str:
    if not values:
        return "—"
    if len(values) == 1:
        return f"{values[0]:.{decimals}f}"
    return f"{statistics.fmean(values):.{decimals}f} ± {statistics.stdev(values):.{decimals}f}"


def summary(table: pd.DataFrame, baseline: str = "none") -> pd.DataFrame:
    """Per cell and label: seeds, statuses, the peak ratio, ATE and PSNR (mean ± sd), FPS, and Welch's p of ATE,
    PSNR and peak against the baseline of the cell (where both sides have two seeds)."""
    rows = []
    for (cell, label), group in table.groupby(["cell", "label"], sort=False):
        base = table[(table["cell"] == cell) & (table["strategy"] == baseline) & (table["status"] == "ok")]
        ok = group[group["status"] == "ok"]
        row: dict[str, Any] = {
            "cell": cell,
            "label": label,
            "seeds": len(group),
            "lost": int((group["status"] == "lost").sum()),
            "peak_ratio": _mean_sd(_numbers(ok["peak_ratio"]), 3),
            "ate_rmse_m": _mean_sd(_numbers(ok["ate_rmse_m"]), 3),
            "psnr_db": _mean_sd(_numbers(ok["psnr_db"]), 2),
            "fps": _mean_sd(_numbers(ok["fps"]), 3),
        }
        is_base = bool(len(group)) and (group["strategy"] == baseline).all()
        for key in ("ate_rmse_m", "psnr_db", "peak_mem_mib"):
            p = None if is_base else welch_p(_numbers(ok[key]), _numbers(base[key]))
            row[f"p_{key}"] = "—" if p is None else f"{p:.3f}"
        rows.append(row)
    return pd.DataFrame(rows)


def prediction(table: pd.DataFrame, run: dict[str, Any], baseline: str = "none") -> dict[str, float] | None:
    """The paper's two peaks and their ratio predicted from its counts with the bytes measured here (medians over
    the baseline runs): a held keyframe's store per pixel, scaled to the paper's image, and a Gaussian's bytes
    counted two ways: its state alone (parameters, gradients, Adam moments: ``low``) and the whole part of the
    peak that follows the Gaussians, state plus every work buffer, per Gaussian at the peak (``high``). No fixed
    cost is counted, so each prediction is what the Gaussians and the keyframes alone explain."""
    base = table[(table["strategy"] == baseline) & (table["status"] == "ok")]
    need = ("gaussians_added_total", "num_keyframes", "gaussians_added_per_kf_mpx", "store_per_keyframe_bytes")
    rows = [r for _, r in base.iterrows() if all(not pd.isna(r[k]) and r[k] for k in need)]
    low = _numbers(base["state_per_gaussian_bytes"])
    if not rows or not low:
        return None
    # the run's megapixels, from its own descriptors: Gaussians added per keyframe over those per keyframe per Mpx
    per_px = [
        r["store_per_keyframe_bytes"]
        / (r["gaussians_added_total"] / r["num_keyframes"] / r["gaussians_added_per_kf_mpx"] * 1e6)
        for r in rows
    ]
    high = [
        r["gaussian_share_of_peak"] * r["peak_mem_mib"] * 2**20 / r["gaussians_peak"]
        for _, r in base.iterrows()
        if all(not pd.isna(r[k]) and r[k] for k in ("gaussian_share_of_peak", "peak_mem_mib", "gaussians_peak"))
    ]
    b_kf_px = statistics.median(per_px)
    kf_bytes = run["keyframes"] * b_kf_px * run["width"] * run["height"]
    out = {
        "keyframe_bytes_per_px": b_kf_px,
        "keyframes_gib": kf_bytes / GIB,
        "reported_ratio": paper_ratio(run),
    }
    for name, per_gaussian in (("low", low), ("high", high)):
        if not per_gaussian:
            continue
        b_g = statistics.median(per_gaussian)
        none_gib = (run["gaussians_none"] * b_g + kf_bytes) / GIB
        pruned_gib = (run["gaussians_pruned"] * b_g + kf_bytes) / GIB
        out |= {
            f"bytes_per_gaussian_{name}": b_g,
            f"none_gib_{name}": none_gib,
            f"pruned_gib_{name}": pruned_gib,
            f"ratio_{name}": pruned_gib / none_gib,
        }
    return out


def _cell_text(value: Any, decimals: int) -> str:
    if value is None or pd.isna(value):
        return "—"
    if isinstance(value, str):
        return value
    return f"{float(value):,.{decimals}f}"


RUN_COLUMNS: tuple[tuple[str, str, int], ...] = (
    ("seed", "seed", 0), ("status", "status", 0), ("num_keyframes", "keyframes", 0),
    ("gaussians_added_per_kf_mpx", "added / kf / Mpx", 0), ("state_per_gaussian_bytes", "B / Gaussian", 0),
    ("store_per_keyframe_bytes", "B / keyframe", 0), ("gaussian_share_of_peak", "Gaussians' share of peak", 3),
    ("in_view_share", "prunable share", 3),
    ("gaussians_peak", "Gaussians (peak)", 0), ("peak_mem_mib", "peak MiB", 1), ("peak_ratio", "x none", 3),
    ("ate_rmse_m", "ATE m", 3), ("psnr_db", "PSNR dB", 2), ("fps", "FPS", 3),
)  # fmt: skip


def regime_markdown(
    runs: pd.DataFrame, baseline: str = "none", keyframes: dict[str, pd.DataFrame] | None = None
) -> str:
    """``regime.md``: every run, the per-row summary with Welch's p against the baseline, the paper's points."""
    table = run_table(runs, baseline, keyframes)
    if table.empty:
        return "# Regime\n\nNo finished runs.\n"
    lines = ["# Regime: every run", ""]
    lines.append(
        "Each pruned run's peak against the baseline's (`" + baseline + "`) of the same cell (dataset, sequence, "
        "preset, resolution, frame spacing) at the same seed, else the cell's baseline mean. Descriptors from "
        "metrics.json (docs/run-directory.md); prunable share: the mean over the run's prunes of its candidates "
        "(in view, not new) over the Gaussians older than the keyframe, from keyframes.csv. A lost run keeps its "
        "figures up to where tracking was lost."
    )
    for cell, group in table.groupby("cell", sort=False):
        lines += ["", f"## {cell}", "", "| run | " + " | ".join(t for _, t, _ in RUN_COLUMNS) + " |"]
        lines.append("|---" * (len(RUN_COLUMNS) + 1) + "|")
        for _, row in group.iterrows():
            cells = [_cell_text(row[k], d) if k not in ("seed", "status") else str(row[k]) for k, _, d in RUN_COLUMNS]
            lines.append(f"| {row['label']} | " + " | ".join(cells) + " |")
    lines += ["", "## Per row, seeds pooled", ""]
    lines += [
        "Mean ± sd over the finished (`ok`) seeds; p: Welch's two-sided test against the cell's baseline, where "
        "both sides have two seeds.",
        "",
        "| cell | run | seeds | lost | x none | ATE m | PSNR dB | FPS | p (ATE) | p (PSNR) | p (peak) |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for _, r in summary(table, baseline).iterrows():
        lines.append(
            f"| {r['cell']} | {r['label']} | {r['seeds']} | {r['lost']} | {r['peak_ratio']} | {r['ate_rmse_m']} | "
            f"{r['psnr_db']} | {r['fps']} | {r['p_ate_rmse_m']} | {r['p_psnr_db']} | {r['p_peak_mem_mib']} |"
        )
    paper = paper_run()
    run = paper["run"]
    lines += ["", "## The paper's points", ""]
    lines.append(
        f"{run['label']}: {run['width']}x{run['height']}, {run['keyframes']} keyframes, "
        f"{run['gaussians_none']:,} Gaussians without pruning and {run['gaussians_pruned']:,} with, "
        f"{paper_density(run):,.0f} added per keyframe per Mpx; peak {run['peak_none_gb']} -> "
        f"{run['peak_pruned_gb']} GB as printed (x{paper_ratio(run):.3f}, "
        f"{run['memory_measure']})."
    )
    for point in paper.get("tables", []):
        lines.append(
            f"{point['label']}: {point['peak_none_gb']} -> {point['peak_pruned_gb']} GB (x{paper_ratio(point):.3f})."
        )
    lines += ["", "### The paper's run predicted from our bytes", ""]
    every = {cell: prediction(group, run, baseline) for cell, group in table.groupby("cell", sort=False)}
    preds = {cell: pred for cell, pred in every.items() if pred is not None}
    if not preds:
        lines.append("No baseline run records the bytes per Gaussian and per keyframe: no prediction.")
    else:
        lines += [
            f"Each cell's baseline runs give the bytes a held keyframe costs per pixel and a Gaussian costs, so the "
            f"paper's {run['keyframes']} keyframes at {run['width']}x{run['height']} and its counts give two peaks per "
            f"cell, with no fixed cost counted (paper: {run['peak_none_gb']} -> {run['peak_pruned_gb']} GB as "
            f"printed, x{paper_ratio(run):.3f}; the prediction's GiB and its GB are read "
            "as one unit, which moves each left-out figure by at most 7%). A Gaussian's bytes are counted two ways: "
            "its state alone (parameters, gradients, Adam moments) and the state with every work buffer at the peak "
            "(the Gaussians' share of it, per Gaussian).",
            "",
            "| cell | keyframe B / px | keyframes GiB | bytes per Gaussian | B | without pruning GiB | with GiB "
            "| ratio | left out of the peaks GB |",
            "|---|---|---|---|---|---|---|---|---|",
        ]
        words = {"low": "state", "high": "state + work buffers"}
        for cell, pred in preds.items():
            for name, what in words.items():
                if f"ratio_{name}" not in pred:
                    continue
                left = (
                    f"{run['peak_none_gb'] - pred[f'none_gib_{name}']:+.2f} / "
                    f"{run['peak_pruned_gb'] - pred[f'pruned_gib_{name}']:+.2f}"
                )
                lines.append(
                    f"| {cell} | {pred['keyframe_bytes_per_px']:.1f} | {pred['keyframes_gib']:.2f} | {what} | "
                    f"{pred[f'bytes_per_gaussian_{name}']:,.0f} | {pred[f'none_gib_{name}']:.2f} | "
                    f"{pred[f'pruned_gib_{name}']:.2f} | x{pred[f'ratio_{name}']:.3f} | {left} |"
                )
        lines += [
            "",
            "What is left out is the part of each peak that follows neither the Gaussians as measured here nor the "
            "keyframes: a CUDA rasterizer's per-pixel and per-intersection buffers, the allocator's rounding, the "
            "images and models in flight.",
        ]
    return "\n".join(lines) + "\n"


def keyframe_ratios(runs: pd.DataFrame, keyframes: dict[str, pd.DataFrame], baseline: str = "none") -> pd.DataFrame:
    """Per keyframe of each pruned run: the peak so far against its baseline run's peak so far at the same
    keyframe index (columns label, strategy, cell, seed, n_kf_held, ratio). Only runs with a same-seed baseline
    run."""
    table = run_table(runs, baseline)
    rows = []
    for _, row in table.iterrows():
        if row["strategy"] == baseline or row["baseline_path"] is None:
            continue
        mine, base = keyframes.get(str(row["path"])), keyframes.get(str(row["baseline_path"]))
        source = runs.loc[runs["path"] == row["path"], "peak_mem_source"].iloc[0]
        col = schema.peak_column(source)
        if mine is None or base is None or col is None or col not in mine or col not in base:
            continue
        joined = pd.merge(
            mine[["kf", "n_kf_held", col]].assign(so_far=mine[col].cummax()),
            base[["kf", col]].assign(base_so_far=base[col].cummax()),
            on="kf",
        )
        for _, k in joined.iterrows():
            rows.append(
                {
                    "label": row["label"],
                    "strategy": row["strategy"],
                    "cell": row["cell"],
                    "seed": row["seed"],
                    "n_kf_held": k["n_kf_held"],
                    "ratio": k["so_far"] / k["base_so_far"],
                }
            )
    return pd.DataFrame(rows, columns=["label", "strategy", "cell", "seed", "n_kf_held", "ratio"])
