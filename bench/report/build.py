"""``make_report``: run dirs in, CSV + LaTeX + Markdown + PNG figures out.

The one entry point shared by the CLI and by notebooks or tests, so both see the same files.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd

from bench.report.collect import ReportError, collect
from bench.report.paper import load_paper_tables
from bench.report.plots import make_plots
from bench.report.render import tables_markdown, to_latex
from bench.report.tables import Table, build_tables


@dataclass
class ReportResult:
    """What a report wrote and what it had to leave out, for the CLI summary and for tests."""

    out: Path
    runs: pd.DataFrame  # one row per run, as written to runs.csv
    tables: list[Table]
    files: list[Path] = field(default_factory=list)
    skipped: list[tuple[Path, str]] = field(default_factory=list)  # malformed run dirs and why
    warnings: list[str] = field(default_factory=list)


def make_report(run_dirs: list[Path], out: Path, paper: bool = False, baseline: str = "none") -> ReportResult:
    """Collect every run under ``run_dirs`` (sweep or run dirs, searched recursively) and write
    ``runs.csv``, ``accuracy_<dataset>.tex``, ``performance_<dataset>.tex``, ``tables.md`` and
    the figures into ``out``. Raises ``ReportError`` when no usable run is found."""
    if not baseline:
        raise ReportError("expected a baseline strategy name, found an empty string")
    collection = collect(run_dirs)
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ReportError(f"expected an output dir, found the file '{out}'")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ReportError(f"cannot create output dir '{out}': {exc.strerror or exc}") from exc
    runs = collection.runs
    warnings = list(collection.warnings)

    files = [out / "runs.csv"]
    runs.to_csv(files[0], index=False)

    tables, table_warnings = build_tables(runs, load_paper_tables() if paper else None, baseline)
    warnings += table_warnings
    for table in tables:
        path = out / f"{table.name}.tex"
        path.write_text(to_latex(table), encoding="utf-8")
        files.append(path)
    markdown = out / "tables.md"
    markdown.write_text(tables_markdown(tables), encoding="utf-8")
    files.append(markdown)

    files += make_plots(runs, out, warnings.append)
    return ReportResult(out, runs, tables, files, collection.skipped, warnings)
