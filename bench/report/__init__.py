"""Reports over many run dirs: tidy CSV, the paper's tables (LaTeX, Markdown) and figures.

``python -m bench.report SWEEP_DIR ... --out reports/NAME [--paper] [--baseline none]``
"""

from bench.errors import ReportError
from bench.report.build import ReportResult, make_report

__all__ = ["ReportError", "ReportResult", "make_report"]
