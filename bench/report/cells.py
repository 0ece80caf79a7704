"""The table model: cells, rows, metric blocks and tables, independent of output format.

A table is method rows grouped in metric blocks, sequences as columns plus ``Avg``; the
renderers in ``render.py`` only format these cells. Keeping the numbers here lets tests check
values (best, relative figures) without parsing LaTeX. How the tables are laid out: ``tables.py``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

from bench.names import file_token
from bench.report.collect import DEFAULT_PROTOCOL
from bench.report.variants import Variant

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


def cell_mean(cell: Cell) -> float:
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
