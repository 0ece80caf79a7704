"""Claims: the hand-written figures of a report's README, recomputed from the folder's committed data.

A figure in a README is followed, on the same line, by an HTML comment that says how to compute it::

    the baseline ends with 38,618 Gaussians<!-- claim: {csv: runs.csv, where: "strategy == 'none'",
    col: gaussians_final, stat: mean, round: 0} -->

(on one line in the file). The comment is a YAML flow mapping:

- ``csv``: the table, relative to the README's folder (``runs.csv``, ``keyframes.csv``, ``milestones.csv``,
  ``stats.csv``, or ``../scale/runs.csv``);
- ``where``: a pandas ``DataFrame.query`` expression selecting the rows (all rows when absent);
- ``col``: the column; ``stat``: one of ``STATS``; ``round``: the printed decimals;
- ``vs``: a second ``where`` for the two-group statistics (``ratio``, ``diff``, ``p_welch``);
- ``scale``: a factor applied before rounding (``0.001`` for a figure printed as ``39.0k``).

The figure is the last number before the comment on its line (thousands commas, a leading ``x`` and the
Unicode minus are read as written). ``check_file`` recomputes every claim and reports each that differs, so a
figure changed by hand, or data changed under a figure, fails ``tests/report/test_claims.py``.

``python -m bench.report.claims [PATH ...]`` checks the given READMEs (default: every ``README.md`` under
``reports/``) and exits 1 when one differs.
"""

from __future__ import annotations

import re
import statistics
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd
import yaml

from bench.errors import ReportError, failed
from bench.report.stats import welch_p

CLAIM = re.compile(r"<!--\s*claim:\s*(\{.*?\})\s*-->")
NUMBER = re.compile(r"(?:(?<![\w.])[-−+])?\d[\d,]*(?:\.\d+)?")  # "0.72-0.80": a range, not -0.80
KEYS = frozenset({"csv", "where", "col", "stat", "round", "vs", "scale"})


STATS: dict[str, Callable[[list[float], list[float]], float | None]] = {
    "mean": lambda a, _b: statistics.fmean(a),
    "std": lambda a, _b: statistics.stdev(a),
    "min": lambda a, _b: min(a),
    "max": lambda a, _b: max(a),
    "median": lambda a, _b: statistics.median(a),
    "sum": lambda a, _b: sum(a),
    "count": lambda a, _b: float(len(a)),
    "ratio": lambda a, b: statistics.fmean(a) / statistics.fmean(b),  # mean(where) / mean(vs)
    "diff": lambda a, b: statistics.fmean(a) - statistics.fmean(b),  # mean(where) - mean(vs)
    "p_welch": welch_p,  # Welch's two-sided p, where against vs
}
TWO_GROUPS = frozenset({"ratio", "diff", "p_welch"})


@dataclass(frozen=True)
class Claim:
    """One figure of a README and the rule that recomputes it."""

    readme: Path
    line: int  # 1-based
    printed: str  # the figure as written, e.g. "38,618"
    spec: dict[str, Any]

    @property
    def where(self) -> str:
        return f"{self.readme}:{self.line}"


def parse(readme: Path) -> list[Claim]:
    """Every claim of ``readme``, in order; ``ReportError`` for a comment that is not a claim as documented."""
    claims = []
    for number, text in enumerate(Path(readme).read_text(encoding="utf-8").splitlines(), start=1):
        for match in CLAIM.finditer(text):
            where = f"{readme}:{number}"
            try:
                spec = yaml.safe_load(match.group(1))
            except yaml.YAMLError as exc:
                raise ReportError(f"{where}: expected a YAML mapping in the claim, found: {exc.problem}") from None
            if not isinstance(spec, dict) or set(spec) - KEYS or not {"csv", "col", "stat", "round"} <= set(spec):
                found = sorted(spec) if isinstance(spec, dict) else type(spec).__name__
                raise ReportError(
                    f"{where}: expected claim keys csv, col, stat, round (and where, vs, scale), found {found}"
                )
            if spec["stat"] not in STATS:
                raise ReportError(f"{where}: expected a stat among {', '.join(STATS)}, found {spec['stat']!r}")
            if (spec["stat"] in TWO_GROUPS) != ("vs" in spec):
                raise ReportError(
                    f"{where}: expected 'vs' with {', '.join(sorted(TWO_GROUPS))} only, found stat {spec['stat']}"
                )
            before = CLAIM.sub("", text[: match.start()])
            figures = NUMBER.findall(before)
            if not figures:
                raise ReportError(f"{where}: expected a figure before the claim on its line, found none")
            claims.append(Claim(Path(readme), number, figures[-1], spec))
    return claims


def _values(table: pd.DataFrame, query: str | None, column: str, where: str) -> list[float]:
    try:
        rows = table if query is None else table.query(query, engine="python")
    except Exception as exc:  # a bad expression: pandas raises several types
        raise ReportError(f"{where}: cannot select rows with {query!r}: {exc}") from None
    if column not in rows:
        raise ReportError(f"{where}: expected a column {column!r}, found none")
    values = [float(v) for v in pd.to_numeric(rows[column], errors="coerce").dropna()]
    if not values:
        raise ReportError(f"{where}: expected rows with {column} where {query!r}, found none")
    return values


def recompute(claim: Claim, tables: dict[Path, pd.DataFrame] | None = None) -> str:
    """The figure as the claim's rule computes and rounds it, written as the README should print it."""
    spec = claim.spec
    path = (claim.readme.parent / spec["csv"]).resolve()
    tables = {} if tables is None else tables
    if path not in tables:
        if not path.is_file():
            raise ReportError(f"{claim.where}: expected the table '{spec['csv']}', found no such file")
        tables[path] = pd.read_csv(path, low_memory=False)
    table = tables[path]
    values = _values(table, spec.get("where"), spec["col"], claim.where)
    other = _values(table, spec["vs"], spec["col"], claim.where) if "vs" in spec else []
    value = STATS[spec["stat"]](values, other)
    if value is None:
        raise ReportError(
            f"{claim.where}: {spec['stat']} needs two values on each side, found {len(values)} and {len(other)}"
        )
    value *= float(spec.get("scale", 1))
    return f"{value:.{int(spec['round'])}f}"


def _normal(figure: str) -> str:
    return figure.replace(",", "").replace("−", "-").lstrip("+")


def check_file(readme: Path) -> list[str]:
    """One line per claim of ``readme`` whose printed figure differs from its recomputed one."""
    tables: dict[Path, pd.DataFrame] = {}
    problems = []
    for claim in parse(readme):
        expected = recompute(claim, tables)
        if _normal(claim.printed) != expected:
            problems.append(
                f"{claim.where}: printed {claim.printed}, the data give {expected} ({_describe(claim.spec)})"
            )
    return problems


def _describe(spec: dict[str, Any]) -> str:
    where = f" where {spec['where']}" if "where" in spec else ""
    vs = f" vs {spec['vs']}" if "vs" in spec else ""
    return f"{spec['stat']} of {spec['col']} in {spec['csv']}{where}{vs}"


def readmes(root: Path) -> list[Path]:
    """The READMEs under ``root`` (``reports/``), the top one first."""
    return sorted(Path(root).rglob("README.md"), key=lambda p: (len(p.parts), str(p)))


def main(argv: Sequence[str] | None = None) -> int:
    paths = [Path(a) for a in (sys.argv[1:] if argv is None else argv)] or readmes(Path("reports"))
    problems: list[str] = []
    count = 0
    try:
        for path in paths:
            count += len(parse(path))
            problems += check_file(path)
    except ReportError as exc:
        return failed(exc)
    for line in problems:
        print(line)
    print(f"{count} claims in {len(paths)} READMEs: {len(problems)} differ from their data")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
