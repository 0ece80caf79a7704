"""The paper's printed rows beside the measured ones: read from ``paper_tables.csv``, and placed after the
measured row of their method."""

from __future__ import annotations

from dataclasses import dataclass

import pandas as pd

from bench.names import paper_sequence, strategy_rank
from bench.report.cells import AVG, Cell, Row
from bench.report.paper import PAPER_METRIC, PAPER_STRATEGY, PAPER_UNIT, paper_values
from bench.report.pooling import average_cell, paper_cell
from bench.report.variants import Variant


@dataclass
class PaperRows:
    """Paper rows of one table, keyed by paper method, with per-sequence cells."""

    by_method: dict[str, dict[str, list[Cell]]]  # method -> metric key -> cells (columns order)
    recomputed_avg: bool


def read_paper_rows(paper: pd.DataFrame, table: str, dataset: str, seqs: list[str], metrics: list[str]) -> PaperRows:
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
    return PaperRows(by_method, recomputed)


def paper_overlaps(paper: pd.DataFrame, table: str, dataset: str, seqs: list[str]) -> bool:
    rows = paper[(paper["table"] == table) & (paper["dataset"] == dataset)]
    shown = {paper_sequence(dataset, s) for s in seqs}
    return bool(shown & set(rows["sequence"]))


def ordered_rows(measured: list[tuple[Variant, Row]], paper_rows: list[tuple[str, Row]]) -> list[Row]:
    """Measured rows in paper order, each paper row right after the measured row of its method."""
    keyed: list[tuple[tuple[int, str], int, int, Row]] = []
    for i, (variant, row) in enumerate(measured):
        keyed.append((strategy_rank(variant.strategy), 0, i, row))
    for i, (method, row) in enumerate(paper_rows):
        strategy = PAPER_STRATEGY.get(method, method)
        keyed.append((strategy_rank(strategy), 1, i, row))
    return [row for *_, row in sorted(keyed, key=lambda k: k[:3])]
