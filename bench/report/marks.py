"""What a table marks: the best value per column in bold, and the legend of the marks that occur."""

from __future__ import annotations

from dataclasses import replace

from bench.report.cells import Block, cell_mean

MARKS_NOTE = (
    "'-': tracking lost; 'n/a': metric unavailable; 'failed': run crashed; empty: not run. "
    "Several seeds: mean ± sample std (n-1); 'k/n lost' counts seeds left out of the mean. "
    "Avg: over the sequences with a value (the paper's convention), 'k/n seqs' where not all have one. "
    "Bold: best measured value (full averages only)."
)


def mark_best(block: Block) -> None:
    """Bold the best measured value per column among the rows of one input (image size, frame window: a run at
    another resolution is not a rival); ties at printed precision all win, but a group where every entry ties has
    no best. Paper rows and partial averages are not ranked."""
    if block.better is None or not block.rows:
        return
    inputs = {row.variant.input if row.variant is not None else "" for row in block.rows}
    for col in range(len(block.rows[0].cells)):
        for inp in inputs:
            candidates = [
                (row, row.cells[col])
                for row in block.rows
                if not row.paper
                and (row.variant.input if row.variant is not None else "") == inp
                and row.cells[col].kind == "num"
                and not row.cells[col].partial
            ]
            shown = [
                round(cell_mean(c), c.decimals if c.decimals is not None else block.decimals) for _, c in candidates
            ]
            if len(set(shown)) < 2:
                continue
            best = min(shown) if block.better == "lower" else max(shown)
            for (row, cell), value in zip(candidates, shown, strict=True):
                if value == best:
                    row.cells[col] = replace(cell, bold=True)


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
        where = []
        if any(c.partial for c in cells):
            where.append("full averages only")
        if len({r.variant.input for b in blocks for r in b.rows if r.variant is not None}) > 1:
            where.append("among the rows of one input")
        sentences.append("Bold: best measured value" + (f" ({'; '.join(where)})." if where else "."))
    return " ".join(s for s in sentences if s)
