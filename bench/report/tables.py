"""The paper's table layouts (Tables I-IV) built from measured runs, independent of output format.

A table is method rows grouped in metric blocks, sequences as columns plus ``Avg``; the
renderers in ``render.py`` only format these cells. Keeping the numbers here lets tests check
values (best, relative figures) without parsing LaTeX.
"""

from __future__ import annotations

import statistics
from dataclasses import dataclass, field, replace
from typing import Literal

import pandas as pd

from bench.metrics.protocol import is_masked
from bench.names import dataset_name, file_token, method_name, paper_sequence, sequence_sort_key, strategy_rank
from bench.report.collect import DEFAULT_PROTOCOL, is_missing
from bench.report.paper import LOST, PAPER_METRIC, PAPER_STRATEGY, PAPER_UNIT, paper_values
from bench.report.stats import ALPHA, welch_p, within_noise
from bench.schema import UNFINISHED

CellKind = Literal["num", "lost", "na", "failed", "empty", "ref"]
Better = Literal["lower", "higher"]
Style = Literal["value", "percent", "times"]
AVG = "Avg"


@dataclass(frozen=True)
class Cell:
    """One table entry: a mean (± std over seeds) or a mark saying why there is no number."""

    kind: CellKind
    mean: float | None = None
    std: float | None = None
    decimals: int | None = None  # overrides the block's; paper figures keep their printed precision
    unit: str = ""
    note: str = ""  # e.g. "1/3 lost": seeds left out of the mean
    bold: bool = False
    partial: bool = False  # an Avg over fewer sequences than shown: not ranked against full ones
    values: tuple[float, ...] = ()  # the per-seed values behind mean and std (an Avg: per-seed averages)
    seeds: tuple[int | None, ...] = ()  # their seeds, in the same order
    p_value: float | None = None  # Welch's t-test against the baseline's cell in the same column
    noise: bool = False  # the difference from the baseline is within seed noise (p >= ALPHA)


EMPTY = Cell("empty")


def _num(cell: Cell) -> float:
    """The mean of a "num" cell: every one has a mean (the other kinds are marks without a number)."""
    assert cell.mean is not None, cell
    return cell.mean


@dataclass
class Row:
    label: str
    cells: list[Cell]
    paper: bool = False
    variant: Variant | None = None  # the measured row's strategy/keep/preset; None for paper rows


@dataclass
class Block:
    """Rows for one metric; ``better`` decides the bold cell, ``style`` how numbers print."""

    title: str
    better: Better | None
    style: Style
    decimals: int
    rows: list[Row] = field(default_factory=list)
    key: str = ""  # the runs.csv metric behind the block (relative blocks: the source block's)


@dataclass
class Table:
    kind: Literal["accuracy", "performance"]
    dataset: str
    columns: list[str]  # sequence names, then "Avg"
    blocks: list[Block]
    caption: str
    notes: list[str]
    protocol: str = DEFAULT_PROTOCOL  # eval.protocol of every run in the table (one per table, never mixed)
    split: bool = False  # the dataset's runs hold several protocols: one table each, named by protocol

    @property
    def name(self) -> str:
        suffix = f"_{self.protocol}" if self.split else ""
        return f"{self.kind}_{file_token(self.dataset)}{suffix}"


@dataclass(frozen=True)
class Variant:
    """A measured table row: one strategy at one keep ratio on one backend preset, seeds pooled.

    Runs of different ``slam_preset`` values are different rows (labelled ``[preset]``), never pooled:
    the presets re-seed differently, so their averages would mix two systems. So are runs of different
    memory policies (labelled ``+ policy``).
    """

    strategy: str
    keep_ratio: float | None
    label: str
    slam_preset: str = "default"
    memory_policy: str = ""  # bench.report.settings.policy_label; "" = today's keyframe store, densification, residency
    pruning: str = ""  # bench.report.settings.pruning_label; "" = the keep ratio and the strategy's default parameters


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

MARKS_NOTE = (
    "'-': tracking lost; 'n/a': metric unavailable; 'failed': run crashed; empty: not run. "
    "Several seeds: mean ± sample std (n-1); 'k/n lost' counts seeds left out of the mean. "
    "Avg: over the sequences with a value (the paper's convention), 'k/n seqs' where not all have one. "
    "Bold: best measured value (full averages only)."
)


def _keep(value: object) -> float | None:
    return None if is_missing(value) else float(value)  # type: ignore[arg-type]


def _presets(runs: pd.DataFrame) -> pd.Series:
    return runs["slam_preset"] if "slam_preset" in runs else pd.Series("default", index=runs.index)


def _policies(runs: pd.DataFrame) -> pd.Series:
    """Each run's memory policy; "" for runs (or stored tables) from before the column existed."""
    if "memory_policy" not in runs:
        return pd.Series("", index=runs.index)
    return runs["memory_policy"].map(lambda v: "" if is_missing(v) else str(v))


def _prunings(runs: pd.DataFrame) -> pd.Series:
    """Each run's pruning label; "" for runs (or stored tables) from before the column existed."""
    if "pruning" not in runs:
        return pd.Series("", index=runs.index)
    return runs["pruning"].map(lambda v: "" if is_missing(v) else str(v))


def variants(runs: pd.DataFrame) -> list[Variant]:
    """Measured rows in paper order; the keep ratio is named only where a strategy ran several,
    the backend preset only where the runs hold several, the memory policy wherever it is not today's, the
    pruning schedule (an absolute target, other strategy parameters) wherever it is not the usual one."""
    presets, policies, prunings = _presets(runs), _policies(runs), _prunings(runs)
    found = {
        (s, _keep(k), str(p), m, g)
        for s, k, p, m, g in zip(runs["strategy"], runs["keep_ratio"], presets, policies, prunings, strict=True)
    }
    ratios: dict[tuple[str, str, str], int] = {}
    for strategy, _, preset, policy, _ in found:
        ratios[strategy, preset, policy] = ratios.get((strategy, preset, policy), 0) + 1
    several_presets = len({p for _, _, p, _, _ in found}) > 1
    out = []

    def order(p: tuple[str, float | None, str, str, str]) -> tuple:
        return p[2] != "default", p[2], p[3], strategy_rank(p[0]), -1.0 if p[1] is None else p[1], p[4]

    for strategy, keep, preset, policy, pruning in sorted(found, key=order):
        label = method_name(strategy)
        if pruning:
            label += f" ({pruning})"
        elif ratios[strategy, preset, policy] > 1:
            label += f" (keep {keep:g})" if keep is not None else " (absolute target)"
        if policy:
            label += f" + {policy}"
        if several_presets:
            label += f" [{preset}]"
        out.append(Variant(strategy, keep, label, preset, policy, pruning))
    return out


def variant_runs(runs: pd.DataFrame, variant: Variant) -> pd.DataFrame:
    keep = runs["keep_ratio"]
    same_keep = keep.isna() if variant.keep_ratio is None else keep == variant.keep_ratio
    same = (runs["strategy"] == variant.strategy) & same_keep & (_presets(runs) == variant.slam_preset)
    return runs[same & (_policies(runs) == variant.memory_policy) & (_prunings(runs) == variant.pruning)]


def sequences(runs: pd.DataFrame, dataset: str) -> list[str]:
    return sorted(set(runs["seq"]), key=lambda s: sequence_sort_key(dataset, s))


def seed_cell(runs: pd.DataFrame, metric: str) -> Cell:
    """Pool the seeds of one (variant, sequence): lost seeds are counted, not averaged."""
    if runs.empty:
        return EMPTY
    status = runs["status"]
    n_lost, n_failed = int((status == "lost").sum()), int((status == "failed").sum())
    ok = runs[status == "ok"]
    if ok.empty:
        return Cell("lost") if n_lost else Cell("failed") if n_failed else EMPTY
    pairs = (
        [
            (float(v), None if is_missing(s) else int(s))
            for v, s in zip(ok[metric], ok["seed"], strict=True)
            if not is_missing(v)
        ]
        if metric in ok
        else []
    )
    if not pairs:
        return Cell("na")
    values = [v for v, _ in pairs]
    total = len(runs)
    notes = [f"{n}/{total} {what}" for n, what in ((n_lost, "lost"), (n_failed, "failed")) if n]
    std = statistics.stdev(values) if len(values) > 1 else None
    return Cell(
        "num",
        mean=statistics.fmean(values),
        std=std,
        note=", ".join(notes),
        values=tuple(values),
        seeds=tuple(s for _, s in pairs),
    )


def average_cell(cells: list[Cell]) -> Cell:
    """Mean over sequences with a number; with none, the most telling mark among them."""
    numbers = [c for c in cells if c.kind == "num" and c.mean is not None]
    if numbers:
        decimals = max((c.decimals for c in numbers if c.decimals is not None), default=None)
        partial = len(numbers) < len(cells)
        note = f"{len(numbers)}/{len(cells)} seqs" if partial else ""
        seeds, values = ((), ()) if partial else _per_seed_averages(numbers)
        # printed without ± as in the paper; the per-seed averages feed the noise test and stats.csv
        return Cell(
            "num",
            mean=statistics.fmean(_num(c) for c in numbers),
            decimals=decimals,
            unit=numbers[0].unit,
            note=note,
            partial=partial,
            values=values,
            seeds=seeds,
        )
    for kind in ("lost", "failed", "na"):
        if any(c.kind == kind for c in cells):
            return Cell(kind)
    return EMPTY


def _per_seed_averages(cells: list[Cell]) -> tuple[tuple[int, ...], tuple[float, ...]]:
    """Per seed, the mean over the sequences: the sample an Avg's noise is judged on. Only seeds
    that every sequence ran once each count; otherwise there is no sample."""
    by_seed: list[dict[int, float]] = []
    for cell in cells:
        if len(cell.seeds) != len(set(cell.seeds)) or None in cell.seeds:
            return (), ()
        by_seed.append(dict(zip(cell.seeds, cell.values, strict=True)))  # type: ignore[arg-type]
    common = sorted(set.intersection(*(set(d) for d in by_seed))) if by_seed else []
    return tuple(common), tuple(statistics.fmean(d[s] for d in by_seed) for s in common)


def _decimals(text: str) -> int:
    return len(text.split(".", 1)[1]) if "." in text else 0


def paper_cell(text: str | None, unit: str = "") -> Cell:
    if text is None or text == "":
        return EMPTY
    if text == LOST:
        return Cell("lost")
    try:
        return Cell("num", mean=float(text), decimals=_decimals(text), unit=unit)
    except ValueError:
        return Cell("na")


@dataclass
class _PaperRows:
    """Paper rows of one table, keyed by paper method, with per-sequence cells."""

    by_method: dict[str, dict[str, list[Cell]]]  # method -> metric key -> cells (columns order)
    recomputed_avg: bool


def _paper_rows(paper: pd.DataFrame, table: str, dataset: str, seqs: list[str], metrics: list[str]) -> _PaperRows:
    values = paper_values(paper, table, dataset)
    by_method: dict[str, dict[str, list[Cell]]] = {}
    recomputed = False
    for method, per_metric in values.items():
        by_method[method] = {}
        for key in (k for k in metrics if k in PAPER_METRIC):
            printed = per_metric.get(PAPER_METRIC[key], {})
            unit = PAPER_UNIT.get(PAPER_METRIC[key], "")
            cells = [paper_cell(printed.get(paper_sequence(dataset, s)), unit) for s in seqs]
            paper_seqs = {s for s in printed if s != AVG}
            shown = {paper_sequence(dataset, s) for s in seqs}
            if paper_seqs <= shown and AVG in printed:
                avg = paper_cell(printed[AVG], unit)
            else:
                avg = average_cell(cells)
                recomputed = recomputed or avg.kind == "num"
            by_method[method][key] = cells + [avg]
    return _PaperRows(by_method, recomputed)


def _has_overlap(paper: pd.DataFrame, table: str, dataset: str, seqs: list[str]) -> bool:
    rows = paper[(paper["table"] == table) & (paper["dataset"] == dataset)]
    shown = {paper_sequence(dataset, s) for s in seqs}
    return bool(shown & set(rows["sequence"]))


def _ordered_rows(measured: list[tuple[Variant, Row]], paper_rows: list[tuple[str, Row]]) -> list[Row]:
    """Measured rows in paper order, each paper row right after the measured row of its method."""
    keyed: list[tuple[tuple[int, str], int, int, Row]] = []
    for i, (variant, row) in enumerate(measured):
        keyed.append((strategy_rank(variant.strategy), 0, i, row))
    for i, (method, row) in enumerate(paper_rows):
        strategy = PAPER_STRATEGY.get(method, method)
        keyed.append((strategy_rank(strategy), 1, i, row))
    return [row for *_, row in sorted(keyed, key=lambda k: k[:3])]


def mark_best(block: Block) -> None:
    """Bold the best measured value per column; ties at printed precision all win, but a column
    where every entry ties has no best. Paper rows and partial averages are not ranked."""
    if block.better is None or not block.rows:
        return
    for col in range(len(block.rows[0].cells)):
        candidates = [
            (row, row.cells[col])
            for row in block.rows
            if not row.paper and row.cells[col].kind == "num" and not row.cells[col].partial
        ]
        shown = [round(_num(c), c.decimals if c.decimals is not None else block.decimals) for _, c in candidates]
        if len(set(shown)) < 2:
            continue
        best = min(shown) if block.better == "lower" else max(shown)
        for (row, cell), value in zip(candidates, shown, strict=True):
            if value == best:
                row.cells[col] = replace(cell, bold=True)


def _metric_block(
    spec: MetricSpec,
    runs: pd.DataFrame,
    seqs: list[str],
    rows_for: list[Variant],
    paper_rows: _PaperRows | None,
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
    block = Block(spec.title, spec.better, "value", spec.decimals, _ordered_rows(measured, prow), key=spec.key)
    mark_best(block)
    return block, measured_cells, paper_cells


def mark_noise(block: Block, measured: dict[Variant, list[Cell]], baseline: Baseline | None) -> None:
    """Test every measured cell against the baseline's cell in its column (Welch, per-seed values)
    and flag it when the difference is within seed noise; ``measured`` is updated alongside."""
    if baseline is None:
        return
    for row in block.rows:
        variant = row.variant
        if variant is None or variant.strategy == baseline.default.strategy:
            continue
        base = measured.get(baseline.for_variant(variant))
        if base is None:
            continue
        for i, (cell, ref) in enumerate(zip(row.cells, base, strict=True)):
            if cell.kind == "num" and ref.kind == "num":
                p = welch_p(cell.values, ref.values)
                row.cells[i] = replace(cell, p_value=p, noise=within_noise(p))
        measured[variant] = row.cells


def seed_note(blocks: list[Block]) -> str:
    """What the spread in the table rests on: how many seeds per cell, and the noise marker."""
    counts = sorted(
        {
            len(c.values)
            for b in blocks
            for r in b.rows
            if not r.paper
            for c in r.cells[:-1]
            if c.kind == "num" and c.values
        }
    )
    if not counts or counts[-1] < 2:
        return "1 seed: no noise estimate; a difference from the baseline may be seed noise."
    n = str(counts[0]) if len(counts) == 1 else f"{counts[0]}-{counts[-1]}"
    return (
        f"Seeds per cell: {n}; 95% confidence intervals in stats.csv. "
        f"†: within seed noise of the baseline (Welch's t-test on the per-seed values, p >= {ALPHA:g}); "
        "a cell with fewer than 2 seeds on either side is not tested. "
        "Avg is tested on per-seed averages over the sequences."
    )


def relative_cells(cells: list[Cell], base: list[Cell], style: Style) -> list[Cell]:
    """Per sequence ``x / base`` (times) or ``x / base - 1`` (percent); Avg is the ratio of the
    means over the sequences both have, so a sequence one of them lost cannot skew it."""
    out = []
    pairs = []
    for cell, ref in zip(cells[:-1], base[:-1], strict=True):
        if cell.kind == "num" and ref.kind == "num" and ref.mean:
            pairs.append((_num(cell), ref.mean))
            out.append(replace(_ratio_cell(_num(cell) / ref.mean, style), p_value=cell.p_value, noise=cell.noise))
        elif "lost" in (cell.kind, ref.kind):
            out.append(Cell("lost"))
        elif "failed" in (cell.kind, ref.kind):
            out.append(Cell("failed"))
        elif cell.kind == "empty" or ref.kind == "empty":
            out.append(EMPTY)
        else:
            out.append(Cell("na"))
    if pairs:
        ratio = statistics.fmean(p[0] for p in pairs) / statistics.fmean(p[1] for p in pairs)
        cell = _ratio_cell(ratio, style)
        if len(pairs) < len(out):
            cell = replace(cell, note=f"{len(pairs)}/{len(out)} seqs", partial=True)
        elif cells[-1].kind == "num":
            cell = replace(cell, p_value=cells[-1].p_value, noise=cells[-1].noise)
        out.append(cell)
    else:
        out.append(average_cell(out))
    return out


def _ratio_cell(ratio: float, style: Style) -> Cell:
    return Cell("num", mean=(ratio - 1.0) * 100.0 if style == "percent" else ratio)


def _relative_block(
    title: str,
    style: Style,
    source: Block,
    measured: dict[Variant, list[Cell]],
    baseline: Baseline,
    paper: dict[str, list[Cell]],
) -> Block:
    by_label = {v.label: (v, cells) for v, cells in measured.items()}
    paper_base = paper.get("LSG-SLAM")
    rows = []
    for row in source.rows:
        if row.paper:
            method = row.label.removeprefix("(paper) ")
            if paper_base is None:
                continue
            cells = paper[method]
            is_base = method == "LSG-SLAM"
            rel = [Cell("ref")] * len(cells) if is_base else relative_cells(cells, paper_base, style)
        else:
            variant, cells = by_label[row.label]
            if variant.strategy == baseline.default.strategy:
                rel = [Cell("ref")] * len(cells)
            else:
                rel = relative_cells(cells, measured[baseline.for_variant(variant)], style)
        rows.append(Row(row.label, rel, paper=row.paper, variant=row.variant))
    decimals = 1 if style == "percent" else 2
    return Block(title, None, style, decimals, rows, key=source.key)


@dataclass(frozen=True)
class Baseline:
    """The measured row(s) others are compared with. A baseline that ran at several keep ratios
    (a sweep over ``prune.keep_ratio`` that includes ``none``) pairs each row with the baseline
    at the same keep ratio, falling back to ``default``."""

    default: Variant
    by_keep: dict[float | None, Variant]
    by_preset: dict[tuple[str, float | None], Variant] = field(default_factory=dict)

    def for_variant(self, variant: Variant) -> Variant:
        """The baseline of the same preset (and keep ratio where it ran several); presets never mix."""
        same = self.by_preset.get((variant.slam_preset, variant.keep_ratio))
        if same is not None:
            return same
        in_preset = [v for (p, _), v in self.by_preset.items() if p == variant.slam_preset]
        if in_preset:
            return ([v for v in in_preset if v.keep_ratio in (None, 1.0)] or in_preset)[0]
        return self.by_keep.get(variant.keep_ratio, self.default)


def pick_baseline(found: list[Variant], baseline: str) -> tuple[Baseline | None, str | None]:
    """The baseline rows for one dataset; a warning when it ran at several keep ratios."""
    candidates = [v for v in found if v.strategy == baseline]
    if not candidates:
        return None, None
    chosen = ([v for v in candidates if v.keep_ratio in (None, 1.0)] or candidates)[0]
    result = Baseline(
        chosen,
        {v.keep_ratio: v for v in candidates if v.slam_preset == chosen.slam_preset},
        {(v.slam_preset, v.keep_ratio): v for v in candidates},
    )
    if len({v.keep_ratio for v in candidates}) == 1:
        return result, None
    return result, (
        f"baseline '{baseline}' ran at several keep ratios; each row is compared with the baseline at its "
        f"own keep ratio, else with '{chosen.label}'"
    )


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
    if paper is not None and _has_overlap(paper, "accuracy", dataset, seqs):
        if is_masked(protocol):
            prows = _paper_rows(paper, "accuracy", dataset, seqs, [m.key for m in ACCURACY_METRICS])
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
    if paper is not None and _has_overlap(paper, "performance", dataset, seqs):
        prows = _paper_rows(paper, "performance", dataset, seqs, [MEMORY.key, FPS.key])
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
        blocks.append(_relative_block("Memory vs baseline", "percent", mem, mem_cells, base, mem_paper))
    blocks.append(fps)
    if base is not None:
        blocks.append(_relative_block("FPS vs baseline", "times", fps, fps_cells, base, fps_paper))
        several = len(base.by_keep) > 1
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


def marks_note(blocks: list[Block]) -> str:
    """The legend of the marks and conventions that occur in these blocks, and only those."""
    cells = [c for b in blocks for r in b.rows if not r.paper for c in r.cells]
    kinds = {c.kind for c in cells}
    parts = [
        text
        for kind, text in (
            ("lost", "'-': tracking lost"),
            ("na", "'n/a': metric unavailable"),
            ("failed", "'failed': run crashed"),
            ("empty", "empty: not run"),
        )
        if kind in kinds
    ]
    sentences = ["; ".join(parts) + "." if parts else ""]
    if any(c.std is not None for c in cells):
        sentences.append("Several seeds: mean ± sample std (n-1).")
    if any(c.note and ("lost" in c.note or "failed" in c.note) for c in cells):
        sentences.append("'k/n lost' counts seeds left out of the mean.")
    if any(c.partial for c in cells):
        sentences.append(
            "Avg: over the sequences with a value (the paper's convention), 'k/n seqs' where not all have one."
        )
    if any(c.bold for c in cells):
        sentences.append(
            "Bold: best measured value" + (" (full averages only)." if any(c.partial for c in cells) else ".")
        )
    return " ".join(s for s in sentences if s)


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
        if paper is not None and not _has_overlap(paper, "accuracy", dataset, sequences(ds, dataset)):
            warnings.append(f"{dataset}: the paper has no figures for the sequences measured, no paper rows")
    return tables, warnings
