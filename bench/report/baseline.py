"""Comparison with the baseline strategy: which row is the baseline of which, the seed-noise test of each
cell against it, and the relative rows (memory and FPS vs baseline)."""

from __future__ import annotations

import statistics
from dataclasses import dataclass, field, replace

from bench.report.cells import EMPTY, Block, Cell, Row, Style, cell_mean
from bench.report.pooling import average_cell
from bench.report.stats import ALPHA, welch_p, within_noise
from bench.report.variants import Variant


@dataclass(frozen=True)
class Baseline:
    """The measured row(s) others are compared with. A baseline that ran at several keep ratios
    (a sweep over ``prune.keep_ratio`` that includes ``none``) pairs each row with the baseline
    at the same keep ratio, falling back to ``default``."""

    default: Variant
    by_keep: dict[float | None, Variant]
    by_preset: dict[tuple[str, float | None], Variant] = field(default_factory=dict)
    candidates: tuple[Variant, ...] = ()  # every baseline row, of every preset and input

    @property
    def several_inputs(self) -> bool:
        """Whether the baseline ran several inputs (image sizes, frame windows)."""
        return len({v.input for v in self.candidates}) > 1

    def for_variant(self, variant: Variant) -> Variant | None:
        """The baseline of the same preset (and keep ratio where it ran several); presets never mix. Where the
        baseline ran several inputs (image sizes, frame windows), the same rule among the rows of the variant's
        input, and None where the baseline never read that input: a row is never compared with a run of another
        input."""
        if self.several_inputs:
            same_input = [v for v in self.candidates if v.input == variant.input]
            own, _ = pick_baseline(same_input, self.default.strategy)
            return None if own is None else own.for_variant(variant)
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
        tuple(candidates),
    )
    if len({v.keep_ratio for v in candidates}) == 1:
        return result, None
    return result, (
        f"baseline '{baseline}' ran at several keep ratios; each row is compared with the baseline at its "
        f"own keep ratio, else with '{chosen.label}'"
    )


def mark_noise(block: Block, measured: dict[Variant, list[Cell]], baseline: Baseline | None) -> None:
    """Test every measured cell against the baseline's cell in its column (Welch, per-seed values)
    and flag it when the difference is within seed noise; ``measured`` is updated alongside."""
    if baseline is None:
        return
    for row in block.rows:
        variant = row.variant
        if variant is None or variant.strategy == baseline.default.strategy:
            continue
        ref_variant = baseline.for_variant(variant)
        base = None if ref_variant is None else measured.get(ref_variant)
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
            pairs.append((cell_mean(cell), ref.mean))
            out.append(replace(_ratio_cell(cell_mean(cell) / ref.mean, style), p_value=cell.p_value, noise=cell.noise))
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


def relative_block(
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
            ref_variant = baseline.for_variant(variant)
            if variant.strategy == baseline.default.strategy:
                rel = [Cell("ref")] * len(cells)
            elif ref_variant is None:  # the baseline never read this input
                rel = [Cell("na")] * len(cells)
            else:
                rel = relative_cells(cells, measured[ref_variant], style)
        rows.append(Row(row.label, rel, paper=row.paper, variant=row.variant))
    decimals = 1 if style == "percent" else 2
    return Block(title, None, style, decimals, rows, key=source.key)
