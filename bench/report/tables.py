"""The paper's table layouts (Tables I-IV) built from measured runs, independent of output format.

The accuracy and performance tables of each dataset (one pair per ``eval.protocol``), their metric
blocks and notes, and the selection of blocks by metric. The parts they are built from: the table model
(``cells.py``), the measured rows (``variants.py``), pooled cells (``pooling.py``), the paper's rows
(``paper_rows.py``), the baseline comparison (``baseline.py``) and the marks (``marks.py``).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import pandas as pd

from bench.metrics.protocol import is_masked
from bench.names import dataset_name
from bench.report.baseline import Baseline, mark_noise, pick_baseline, relative_block, seed_note
from bench.report.cells import AVG, Better, Block, Cell, Row, Table
from bench.report.collect import DEFAULT_PROTOCOL, is_missing
from bench.report.marks import MARKS_NOTE, mark_best, marks_note
from bench.report.paper_rows import PaperRows, ordered_rows, paper_overlaps, read_paper_rows
from bench.report.pooling import average_cell, seed_cell
from bench.report.variants import Variant, sequences, variant_runs, variants
from bench.schema import UNFINISHED


@dataclass(frozen=True)
class MetricSpec:
    key: str  # column of runs.csv
    title: str
    better: Better
    decimals: int


ACCURACY_METRICS: tuple[MetricSpec, ...] = (
    MetricSpec("ate_rmse_m", "ATE [m]", "lower", 3),
    MetricSpec("psnr_db", "PSNR [dB]", "higher", 2),
    MetricSpec("ssim", "SSIM", "higher", 3),
    MetricSpec("ms_ssim", "MS-SSIM", "higher", 3),
    MetricSpec("lpips", "LPIPS", "lower", 3),
)
# what each protocol scores, in a table's words (bench/metrics/protocol.py)
PROTOCOL_WORDS: dict[str, str] = {
    "full": "the whole image",
    "splatam": "SplaTAM's valid-depth mask (the paper's base system)",
    "released": "the rendered silhouette > 0.5 (the released Pocket-SLAM code's final evaluation)",
}
MEMORY = MetricSpec("peak_mem_mib", "Peak memory [MiB]", "lower", 1)
# churn: whether pruning shrank the map or only fed re-seeding
GAUSSIANS: tuple[MetricSpec, ...] = (
    MetricSpec("gaussians_final", "Gaussians at end", "lower", 0),
    MetricSpec("gaussians_peak", "Peak Gaussians", "lower", 0),
)
FPS = MetricSpec("fps", "FPS", "higher", 2)
# the paper's released code's FPS: 1 / (tracking + mapping s per frame); runs before it existed have no column
FPS_SLAM = MetricSpec("fps_slam", "FPS (tracking + mapping)", "higher", 2)


def _metric_block(
    spec: MetricSpec,
    runs: pd.DataFrame,
    seqs: list[str],
    rows_for: list[Variant],
    paper_rows: PaperRows | None,
) -> tuple[Block, dict[Variant, list[Cell]], dict[str, list[Cell]]]:
    measured: list[tuple[Variant, Row]] = []
    measured_cells: dict[Variant, list[Cell]] = {}
    for variant in rows_for:
        vr = variant_runs(runs, variant)
        cells = [seed_cell(vr[vr["seq"] == s], spec.key) for s in seqs]
        cells.append(average_cell(cells))
        measured_cells[variant] = cells
        measured.append((variant, Row(variant.label, cells, variant=variant)))
    paper_cells: dict[str, list[Cell]] = {}
    prow: list[tuple[str, Row]] = []
    if paper_rows is not None:
        for method, per_metric in paper_rows.by_method.items():
            if spec.key not in per_metric:
                continue  # a metric the paper does not print (our SSIM: its "SSIM" is MS-SSIM)
            paper_cells[method] = per_metric[spec.key]
            prow.append((method, Row(f"(paper) {method}", list(per_metric[spec.key]), paper=True)))
    block = Block(spec.title, spec.better, "value", spec.decimals, ordered_rows(measured, prow), key=spec.key)
    mark_best(block)
    return block, measured_cells, paper_cells


def protocol_note(protocol: str) -> str:
    """The line every table carries: which pixels its image metrics were scored on."""
    words = PROTOCOL_WORDS.get(protocol, "a protocol this version does not know")
    return f"Image metrics scored with eval.protocol={protocol}: {words}."


def accuracy_table(
    runs: pd.DataFrame,
    dataset: str,
    paper: pd.DataFrame | None = None,
    baseline: str = "none",
    protocol: str = DEFAULT_PROTOCOL,
) -> Table:
    """Table I/II layout: ATE, PSNR, SSIM, MS-SSIM, LPIPS blocks of method rows; sequences plus Avg.
    Each cell is tested against the baseline's (``mark_noise``).

    ``runs`` are all scored with ``protocol``. The paper's rows stand only beside runs scored with a
    masked protocol (``splatam`` or ``released``): its base system scores masked images, where the
    pixels without depth count as perfect, so beside whole-image scores its figures would read as a
    gap the harness does not have. Its "SSIM" is MS-SSIM (SplaTAM's ``eval``), so it sits in the
    MS-SSIM block. The MS-SSIM block is left out when no run has the metric and no paper row fills it.
    """
    seqs = sequences(runs, dataset)
    found = variants(runs)
    notes = [MARKS_NOTE, protocol_note(protocol)]
    prows = None
    if paper is not None and paper_overlaps(paper, "accuracy", dataset, seqs):
        if is_masked(protocol):
            prows = read_paper_rows(paper, "accuracy", dataset, seqs, [m.key for m in ACCURACY_METRICS])
            notes.append(
                f"(paper) rows: the figures printed in the Pocket-SLAM paper, not bold-ranked, beside runs "
                f"scored with eval.protocol={protocol}; which of the two masked protocols (splatam, "
                "released) produced the paper's table is not known. The paper's SSIM is MS-SSIM (its base "
                "system's evaluation) and stands in the MS-SSIM block."
            )
            if prows.recomputed_avg:
                notes.append("Paper Avg recomputed over the sequences shown.")
        else:
            notes.append(
                f"(paper) rows left out: these runs were scored with eval.protocol={protocol}, the paper "
                "with masked images (pixels without depth count as perfect); rerun with "
                "eval.protocol=splatam or released to set them beside it."
            )
    base, _ = pick_baseline(found, baseline)
    blocks = []
    has_ms_ssim = "ms_ssim" in runs and runs["ms_ssim"].notna().any()
    for spec in ACCURACY_METRICS:
        if spec.key == "ms_ssim" and not has_ms_ssim and prows is None:
            continue
        block, cells, _ = _metric_block(spec, runs, seqs, found, prows)
        mark_noise(block, cells, base)
        blocks.append(block)
    notes.append(seed_note(blocks))
    caption = f"Tracking and rendering accuracy on {dataset_name(dataset)} (eval.protocol={protocol})."
    return Table("accuracy", dataset, [*seqs, AVG], blocks, caption, notes, protocol)


def performance_table(
    runs: pd.DataFrame,
    dataset: str,
    paper: pd.DataFrame | None = None,
    baseline: str = "none",
    protocol: str = DEFAULT_PROTOCOL,
) -> tuple[Table, list[str]]:
    """Table III/IV layout: peak memory and FPS blocks, each followed by its change vs the baseline.

    Memory and speed are measured in the SLAM loop, before and apart from evaluation, so the paper's
    rows stand here whatever ``protocol`` scored the runs; the table still names it.
    """
    seqs = sequences(runs, dataset)
    found = variants(runs)
    warnings: list[str] = []
    notes = [
        MARKS_NOTE,
        f"Runs scored with eval.protocol={protocol}; memory and speed do not depend on it (the evaluation runs "
        "after the SLAM loop), so (paper) rows, where asked for, stand beside any protocol.",
        "Peak memory: the most memory held at once in any keyframe window, in MiB (the CUDA allocator peak "
        "on a GPU, the peak of live torch tensors on a CPU). Memory vs baseline: peak / baseline peak - 1; "
        "FPS vs baseline: FPS / baseline FPS; their Avg is the ratio of means over the sequences both have.",
    ]
    prows = None
    if paper is not None and paper_overlaps(paper, "performance", dataset, seqs):
        prows = read_paper_rows(paper, "performance", dataset, seqs, [MEMORY.key, FPS.key])
        notes.append(
            "(paper) rows: the figures printed in the Pocket-SLAM paper (memory in GB as printed), "
            "compared with the paper's own LSG-SLAM; not bold-ranked."
        )
        if prows.recomputed_avg:
            notes.append("Paper Avg recomputed over the sequences shown.")
    base, warning = pick_baseline(found, baseline)
    if warning:
        warnings.append(f"{dataset}: {warning}")
    mem, mem_cells, mem_paper = _metric_block(MEMORY, runs, seqs, found, prows)
    fps, fps_cells, fps_paper = _metric_block(FPS, runs, seqs, found, prows)
    mark_noise(mem, mem_cells, base)
    mark_noise(fps, fps_cells, base)
    churn = [_noise_marked(spec, runs, seqs, found, base) for spec in GAUSSIANS]
    notes.append(
        "Gaussians at end / Peak Gaussians: the map's count after the last keyframe and its largest count "
        "after any keyframe; fewer than the baseline's means pruning shrank the map, not only fed re-seeding."
    )
    blocks = [mem]
    if base is not None:
        blocks.append(relative_block("Memory vs baseline", "percent", mem, mem_cells, base, mem_paper))
    blocks.append(fps)
    if base is not None:
        blocks.append(relative_block("FPS vs baseline", "times", fps, fps_cells, base, fps_paper))
        several = len(base.by_keep) > 1
        if base.several_inputs:
            notes.append(
                "Baseline: the baseline row of the same input ({...}: image size, frame window); a row whose input "
                "the baseline never read has no relative cells."
            )
        else:
            notes.append(
                f"Baseline: {base.default.label}" + (" (or the baseline at the same keep ratio)." if several else ".")
            )
    else:
        warnings.append(f"{dataset}: no runs of baseline strategy '{baseline}', relative rows left out")
        notes.append(f"No runs of baseline strategy '{baseline}': relative rows left out.")
    if FPS_SLAM.key in runs and runs[FPS_SLAM.key].notna().any():
        blocks.append(_noise_marked(FPS_SLAM, runs, seqs, found, base))
        notes.append(
            "FPS (tracking + mapping): frames / (tracking + mapping + pruning s), the way the paper's released code "
            "counts FPS; FPS above is frames / the SLAM loop's wall time (frame loading and stereo depth included)."
        )
    blocks += churn
    notes.append(seed_note(blocks))
    caption = f"Peak memory and speed on {dataset_name(dataset)} (eval.protocol={protocol})."
    return Table("performance", dataset, [*seqs, AVG], blocks, caption, notes, protocol), warnings


def _noise_marked(
    spec: MetricSpec, runs: pd.DataFrame, seqs: list[str], found: list[Variant], base: Baseline | None
) -> Block:
    """A block of ``spec`` with no paper rows, its cells tested against the baseline's."""
    block, cells, _ = _metric_block(spec, runs, seqs, found, None)
    mark_noise(block, cells, base)
    return block


def run_protocols(runs: pd.DataFrame) -> pd.Series:
    """Each run's ``eval_protocol`` (``bench.report.collect``); None for a run that failed before it said
    which (it joins every protocol's table). A runs.csv from before protocols has no column: ``full``."""
    if "eval_protocol" not in runs:
        return pd.Series(DEFAULT_PROTOCOL, index=runs.index, dtype=object)
    return pd.Series([None if is_missing(p) else str(p) for p in runs["eval_protocol"]], index=runs.index, dtype=object)


def _protocol_rank(protocol: str) -> tuple[int, str]:
    order = tuple(PROTOCOL_WORDS)
    return (order.index(protocol) if protocol in order else len(order), protocol)


# block title -> the metric (runs.csv column) it shows, for ``--labels`` metric selection
BLOCK_METRIC: dict[str, str] = {
    **{spec.title: spec.key for spec in (*ACCURACY_METRICS, MEMORY, FPS, *GAUSSIANS)},
    "Memory vs baseline": MEMORY.key,
    "FPS vs baseline": FPS.key,
    FPS_SLAM.title: FPS_SLAM.key,
}
SELECTABLE_METRICS: tuple[str, ...] = tuple(dict.fromkeys(BLOCK_METRIC.values()))
# a note that explains blocks of these metrics goes when none of them is shown
_NOTE_METRICS: dict[str, tuple[str, ...]] = {
    "Peak memory:": (MEMORY.key, FPS.key),
    "Gaussians at end": tuple(spec.key for spec in GAUSSIANS),
    "FPS (tracking + mapping):": (FPS_SLAM.key,),
}


def select_metrics(table: Table, metrics: tuple[str, ...] | None) -> Table | None:
    """``table`` with only the blocks of ``metrics`` (None: all) and the notes that still apply,
    the marks note rebuilt from what occurs; None when no block is left."""
    blocks = [b for b in table.blocks if metrics is None or BLOCK_METRIC.get(b.title, b.title) in metrics]
    if not blocks:
        return None
    shown = {BLOCK_METRIC.get(b.title, b.title) for b in blocks}
    notes = [
        n
        for n in table.notes
        if n != MARKS_NOTE
        and all(not n.startswith(prefix) or shown & set(keys) for prefix, keys in _NOTE_METRICS.items())
    ]
    marks = marks_note(blocks)
    return replace(table, blocks=blocks, notes=[marks, *notes] if marks else notes)


def build_tables(
    runs: pd.DataFrame,
    paper: pd.DataFrame | None = None,
    baseline: str = "none",
    metrics: tuple[str, ...] | None = None,
) -> tuple[list[Table], list[str]]:
    """Accuracy and performance tables per dataset from finished runs (``running``/``interrupted`` left out).

    A dataset whose runs were scored with several ``eval.protocol`` values gets one pair of tables per
    protocol (named ``accuracy_kitti_splatam`` and so on), with a warning: a cell never pools runs
    scored two ways, and a table never holds two protocols.
    """
    done = runs[~runs["status"].isin(UNFINISHED)]
    tables: list[Table] = []
    warnings: list[str] = []
    protocols = run_protocols(done)
    for dataset in sorted(set(done["dataset"])):
        in_dataset = done["dataset"] == dataset
        found = sorted(
            {p for p in protocols[in_dataset] if not is_missing(p)} or {DEFAULT_PROTOCOL}, key=_protocol_rank
        )
        if len(found) > 1:
            warnings.append(
                f"{dataset}: runs scored with several eval.protocol values ({', '.join(found)}): "
                "one table per protocol; figures pool them"
            )
        for protocol in found:
            ds = done[in_dataset & ((protocols == protocol) | protocols.isna())]
            perf, warns = performance_table(ds, dataset, paper, baseline, protocol)
            for table in (accuracy_table(ds, dataset, paper, baseline, protocol), perf):
                kept = select_metrics(replace(table, split=len(found) > 1), metrics)
                if kept is not None:
                    tables.append(kept)
            warnings.extend(warns)
        if paper is not None and not paper_overlaps(paper, "accuracy", dataset, sequences(ds, dataset)):
            warnings.append(f"{dataset}: the paper has no figures for the sequences measured, no paper rows")
    return tables, warnings
