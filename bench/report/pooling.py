"""Cells from numbers: the seeds of one row and sequence pooled, an ``Avg`` over sequences, a paper figure."""

from __future__ import annotations

import statistics

import pandas as pd

from bench.report.cells import EMPTY, Cell, cell_mean
from bench.report.collect import is_missing
from bench.report.paper import LOST


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
            mean=statistics.fmean(cell_mean(c) for c in numbers),
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
