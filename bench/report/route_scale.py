"""Long drives: how the map and the peak grow with distance, what that predicts for whole sequences, and
whether each strategy stays within seed noise of the unpruned baseline as the drive gets longer.

Read from runs made with ``eval.at_frames`` (``milestones.csv``: the run scored as if the drive ended
at each count) and from ``keyframes.csv`` with the ground-truth distance at each keyframe
(``bench.report.figures.runs.distance_driven``). The paper's claim is about whole sequences (KITTI 06:
1,101 frames), so growth slopes are extrapolated to the lengths in ``sequence_lengths.csv`` and set
beside the paper's memory figures; an extrapolation is a straight line through what was measured,
and ``scale.md`` says so.
"""

from __future__ import annotations

import re
import statistics
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pandas as pd

from bench import schema
from bench.names import method_name
from bench.report.collect import is_missing, read_run_table
from bench.report.paper import LOST, PAPER_STRATEGY, load_paper_tables
from bench.report.stats import welch_p, within_noise
from bench.report.tables import protocol_note, run_protocols
from bench.report.variants import Variant, variant_runs, variants

Warn = Callable[[str], None]
MILESTONES_FILE = schema.MILESTONES_FILE  # every run's rows, keyed by its runs.csv path, in a report folder
LENGTHS = Path(__file__).with_name("sequence_lengths.csv")
REFERENCE = ("kitti", "06")  # the paper's headline sequence: what a synthetic drive is extrapolated to
SLOPE_PER_M = 100.0  # slopes are given per 100 m


def read_milestones(run_dir: Path, warn: Warn) -> pd.DataFrame | None:
    return read_run_table(Path(run_dir) / MILESTONES_FILE, ("frames", "ate_rmse_m", "psnr_db", "path_length_m"), warn)


def sequence_lengths() -> pd.DataFrame:
    return pd.read_csv(LENGTHS, comment="#", dtype={"seq": str})


def run_slopes(keyframes: pd.DataFrame, peak_col: str | None) -> dict[str, float] | None:
    """Least-squares lines of Gaussians and peak MiB against distance over one run's keyframes
    (keyframe 0 left out: it is the first frame's seeding, before any growth)."""
    kf = keyframes.iloc[1:]
    if "distance_m" not in kf.columns or len(kf) < 3 or np.ptp(kf["distance_m"].to_numpy(float)) <= 0:
        return None
    d = kf["distance_m"].to_numpy(float)
    out = {"distance_m": float(d.max())}
    parts = (
        ("gaussians", "n_gaussians"),
        ("peak_mib", peak_col),
        ("state_mib", "mem_state_mib"),
        ("keyframes_mib", "mem_keyframes_mib"),
    )  # the last two: what pruning can bound, and what it cannot
    for name, col in parts:
        if col is None or col not in kf.columns or kf[col].isna().any():
            out[f"{name}_per_100m"] = out[f"{name}_at_0m"] = float("nan")
            continue
        slope, intercept = np.polyfit(d, kf[col].to_numpy(float), 1)
        out[f"{name}_per_100m"], out[f"{name}_at_0m"] = float(slope * SLOPE_PER_M), float(intercept)
    return out


def _mean_std(values: list[float]) -> tuple[float, float | None]:
    vals = [v for v in values if np.isfinite(v)]
    if not vals:
        return float("nan"), None
    return statistics.fmean(vals), (statistics.stdev(vals) if len(vals) > 1 else None)


def _fmt(mean: float, std: float | None, digits: int) -> str:
    if not np.isfinite(mean):
        return "n/a"
    return f"{mean:.{digits}f}" + ("" if std is None else f" ± {std:.{digits}f}")


def _reference_length(dataset: str, seq: str, lengths: pd.DataFrame) -> tuple[str, float]:
    """The whole sequence a drive stands for: its own KITTI/EuRoC sequence, else (synthetic) the
    KITTI track its route follows, else KITTI 06."""
    want = (dataset, seq)
    track = re.search(r"(\d{2})$", seq.split(" on ", 1)[1]) if " on " in seq else None
    if dataset == "synthetic" and track:  # a route_file drive along a KITTI track, e.g. '0 on kitti_06'
        want = ("kitti", track.group(1))
    elif dataset == "synthetic":
        want = REFERENCE
    hit = lengths[(lengths["dataset"] == want[0]) & (lengths["seq"] == want[1])]
    if hit.empty:
        want = REFERENCE
        hit = lengths[(lengths["dataset"] == want[0]) & (lengths["seq"] == want[1])]
    return f"{want[0].upper() if want[0] == 'kitti' else want[0]} {want[1]}", float(hit["path_length_m"].iloc[0])


def _paper_memory_gb(table: pd.DataFrame, strategy: str, seq: str) -> float | None:
    """The paper's KITTI peak memory (GB) of the method behind ``strategy`` on ``seq``; None if it has none."""
    rows = table[
        (table["table"] == "performance")
        & (table["dataset"] == "kitti")
        & (table["metric"] == "Memory_GB")
        & (table["sequence"] == seq)
    ]
    for method, value in zip(rows["method"], rows["value"], strict=True):
        if PAPER_STRATEGY.get(method) == strategy and value.strip() != LOST:
            return float(value)
    return None


def scale_markdown(
    runs: pd.DataFrame, keyframes: dict[str, pd.DataFrame], milestones: pd.DataFrame, baseline: str = "none"
) -> str:
    """The scale section: growth per 100 m with the extrapolation, accuracy at the milestones, the answer."""
    lengths, paper_table = sequence_lengths(), load_paper_tables()
    done = runs[runs["status"].isin(["ok", "lost"])]
    by_path = {str(p): g.sort_values("frames") for p, g in milestones.groupby("path")} if len(milestones) else {}
    lines = ["# Long drives: growth with distance, and accuracy at the milestones", ""]
    for dataset in sorted(set(done["dataset"])):
        ds = done[done["dataset"] == dataset]
        found = variants(ds)
        for seq in sorted(set(ds["seq"])):
            one = ds[ds["seq"] == seq]
            if not any(str(p) in by_path for p in one["path"]):
                continue
            ref_name, ref_m = _reference_length(dataset, seq, lengths)
            lines += [f"## {dataset} {seq}", "", _protocol_line(one), ""]
            lines += _growth_table(one, found, keyframes, ref_name, ref_m, baseline, paper_table)
            lines += _accuracy_table(one, found, by_path)
            lines += _answer(one, found, by_path, baseline)
    return "\n".join(lines) + "\n"


def _protocol_line(one: pd.DataFrame) -> str:
    """Which pixels the section's PSNR scored; several protocols are named as such (its cells pool runs)."""
    found = sorted({p for p in run_protocols(one) if not is_missing(p)}) or ["full"]
    if len(found) == 1:
        return protocol_note(found[0]) + " The paper's peak is memory, which no protocol changes."
    return (
        f"Image metrics scored with several eval.protocol values ({', '.join(found)}): the PSNR cells below "
        "pool them; report them apart to compare."
    )


def _variant_rows(one: pd.DataFrame, found: list[Variant]) -> list[tuple[Variant, pd.DataFrame]]:
    return [(v, vr) for v in found if len(vr := variant_runs(one, v))]


def _growth_table(
    one: pd.DataFrame,
    found: list[Variant],
    keyframes: dict[str, pd.DataFrame],
    ref_name: str,
    ref_m: float,
    baseline: str,
    paper_table: pd.DataFrame,
) -> list[str]:
    lines = [
        f"Growth: least-squares lines through every keyframe after the first (mean ± std over seeds); "
        f"'at {ref_name}' extends each line to that sequence's whole length ({ref_m:.0f} m), a straight-line "
        "extrapolation, beside the paper's peak (GB on its GPU).",
        "",
        "Of the peak's slope, 'state' is the Gaussian state (what pruning acts on) and 'keyframes' the keyframe "
        "store (every keyframe's colour, depth and pose, which no strategy prunes); keyframes.csv's memory parts.",
        "",
        "| method | seeds | driven m | Gaussians / 100 m | peak MiB / 100 m | state MiB / 100 m | "
        f"keyframes MiB / 100 m | slope vs baseline | Gaussians at {ref_name} | peak MiB at {ref_name} | paper GB |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    slopes: dict[Variant, list[dict[str, float]]] = {}
    for variant, vr in _variant_rows(one, found):
        got = []
        for _, run in vr[vr["status"] == "ok"].iterrows():
            kf = keyframes.get(str(run["path"]))
            if kf is None:
                continue
            s = run_slopes(kf, schema.peak_column(run.get(schema.PEAK_SOURCE_FIELD)))
            if s is not None:
                got.append(s)
        slopes[variant] = got
    seq = ref_name.split()[-1]
    for variant, got in slopes.items():
        if not got:
            lines.append(f"| {variant.label} | 0 |" + " - |" * 9)
            continue
        base = next(
            (s for v, s in slopes.items() if v.strategy == baseline and v.slam_preset == variant.slam_preset), []
        )
        base_peak, _ = _mean_std([s["peak_mib_per_100m"] for s in base])
        g = _mean_std([s["gaussians_per_100m"] for s in got])
        p = _mean_std([s["peak_mib_per_100m"] for s in got])
        ratio = p[0] / base_peak if np.isfinite(base_peak) and base_peak > 0 and np.isfinite(p[0]) else float("nan")
        at_g = _mean_std([s["gaussians_at_0m"] + s["gaussians_per_100m"] * ref_m / SLOPE_PER_M for s in got])
        at_p = _mean_std([s["peak_mib_at_0m"] + s["peak_mib_per_100m"] * ref_m / SLOPE_PER_M for s in got])
        paper = _paper_memory_gb(paper_table, variant.strategy, seq) if ref_name.startswith("KITTI") else None
        lines.append(
            f"| {variant.label} | {len(got)} | {statistics.fmean(s['distance_m'] for s in got):.0f} | "
            f"{_fmt(*g, 0)} | {_fmt(*p, 2)} | {_fmt(*_mean_std([s['state_mib_per_100m'] for s in got]), 2)} | "
            f"{_fmt(*_mean_std([s['keyframes_mib_per_100m'] for s in got]), 2)} | "
            f"{'n/a' if not np.isfinite(ratio) else f'x{ratio:.2f}'} | "
            f"{_fmt(*at_g, 0)} | {_fmt(*at_p, 1)} | {'-' if paper is None else f'{paper:g}'} |"
        )
    return lines + [""]


def _at(by_path: dict[str, pd.DataFrame], vr: pd.DataFrame, frames: int, col: str) -> list[float]:
    out = []
    for path in vr.loc[vr["status"] == "ok", "path"]:
        ms = by_path.get(str(path))
        if ms is not None:
            hit = ms[ms["frames"] == frames]
            if len(hit) and pd.notna(hit[col].iloc[0]):
                out.append(float(hit[col].iloc[0]))
    return out


def _milestone_frames(one: pd.DataFrame, by_path: dict[str, pd.DataFrame]) -> list[int]:
    frames = set()
    for path in one["path"]:
        if str(path) in by_path:
            frames |= set(int(f) for f in by_path[str(path)]["frames"])
    return sorted(frames)


def _accuracy_table(one: pd.DataFrame, found: list[Variant], by_path: dict[str, pd.DataFrame]) -> list[str]:
    frames = _milestone_frames(one, by_path)
    lines = [
        "Accuracy at the milestones: ATE m / PSNR dB of the drive so far, mean ± std over the ok seeds "
        "(lost seeds counted in the last column).",
        "",
        "| method | " + " | ".join(f"{n} frames" for n in frames) + " | lost |",
        "|---|" + "---|" * len(frames) + "---|",
    ]
    for variant, vr in _variant_rows(one, found):
        cells = []
        for n in frames:
            ate, psnr = _at(by_path, vr, n, "ate_rmse_m"), _at(by_path, vr, n, "psnr_db")
            cells.append(f"{_fmt(*_mean_std(ate), 3)} / {_fmt(*_mean_std(psnr), 2)}" if ate else "-")
        lines.append(f"| {variant.label} | " + " | ".join(cells) + f" | {int((vr['status'] == 'lost').sum())} |")
    return lines + [""]


def _verdict(ate: list[float], base_ate: list[float], psnr: list[float], base_psnr: list[float]) -> str:
    """'yes' within seed noise on both, 'better (ATE)' / 'better (PSNR)' / 'better (both)' outside it only on the
    good side, 'no' worse beyond it on either: a strategy that beats the baseline keeps its accuracy too."""
    p_ate, p_psnr = welch_p(ate, base_ate), welch_p(psnr, base_psnr)
    if p_ate is None or p_psnr is None:
        return "n/a (< 2 seeds)"
    ate_better = not within_noise(p_ate) and statistics.fmean(ate) < statistics.fmean(base_ate)
    psnr_better = not within_noise(p_psnr) and statistics.fmean(psnr) > statistics.fmean(base_psnr)
    if (not within_noise(p_ate) and not ate_better) or (not within_noise(p_psnr) and not psnr_better):
        return "no"
    if ate_better or psnr_better:
        return "better (" + ("both" if ate_better and psnr_better else "ATE" if ate_better else "PSNR") + ")"
    return "yes"


def _answer(one: pd.DataFrame, found: list[Variant], by_path: dict[str, pd.DataFrame], baseline: str) -> list[str]:
    """At the longest milestone every variant reached: which keep their preset's baseline accuracy (ATE and
    PSNR within seed noise by Welch, p >= 0.05, or better beyond it), and per preset the smallest peak of each
    strategy among those."""
    frames = _milestone_frames(one, by_path)
    rows = _variant_rows(one, found)
    bases = {v.slam_preset: vr for v, vr in rows if v.strategy == baseline and not v.memory_policy}
    if not frames or not bases:
        return ["No baseline runs at the milestones: no answer.", ""]
    last = frames[-1]
    lines = [
        f"The answer at {last} frames: within noise = Welch p >= 0.05 against {method_name(baseline)} of the "
        "same preset on both ATE and PSNR; 'better' = outside the noise on the good side of one (lower ATE or "
        "higher PSNR) and within it on the other, so accuracy is kept too; 'no' = worse beyond the noise on "
        "either; peak = the headline peak over the drive.",
        "",
        "| method | seeds ok | ATE m | PSNR dB | peak MiB | peak / baseline's | against baseline |",
        "|---|---|---|---|---|---|---|",
    ]
    best: dict[str, dict[str, tuple[float, str]]] = {}  # preset -> strategy -> (smallest peak keeping accuracy, label)
    for variant, vr in rows:
        ate, psnr = _at(by_path, vr, last, "ate_rmse_m"), _at(by_path, vr, last, "psnr_db")
        peak = _at(by_path, vr, last, "peak_mem_mib")
        base = bases.get(variant.slam_preset)
        base_peak = _at(by_path, base, last, "peak_mem_mib") if base is not None else []
        ratio = f"x{statistics.fmean(peak) / statistics.fmean(base_peak):.2f}" if peak and base_peak else "-"
        if variant.strategy == baseline and not variant.memory_policy:
            verdict = "(baseline)"
        elif base is None:
            verdict = "n/a (no baseline of this preset)"
        else:
            verdict = _verdict(ate, _at(by_path, base, last, "ate_rmse_m"), psnr, _at(by_path, base, last, "psnr_db"))
        mine = best.setdefault(variant.slam_preset, {})
        if (verdict in ("yes", "(baseline)") or verdict.startswith("better")) and peak:
            cand = (statistics.fmean(peak), variant.label)
            if variant.strategy not in mine or cand[0] < mine[variant.strategy][0]:
                mine[variant.strategy] = cand
        else:
            mine.setdefault(variant.strategy, (float("nan"), ""))
        lines.append(
            f"| {variant.label} | {len(ate)} | {_fmt(*_mean_std(ate), 3)} | {_fmt(*_mean_std(psnr), 2)} | "
            f"{_fmt(*_mean_std(peak), 1)} | {ratio} | {verdict} |"
        )
    lines += [
        "",
        f"Smallest peak at which each strategy keeps its preset's baseline accuracy (within noise, or "
        f"better) at {last} frames:",
        "",
    ]
    for preset, per in best.items():
        cells = [
            f"{method_name(s)}: {peak:.1f} MiB ({label})" if np.isfinite(peak) else f"{method_name(s)}: none"
            for s, (peak, label) in per.items()
        ]
        lines.append(f"- `slam={preset}`: " + "; ".join(cells) + ".")
    return lines + [""]
