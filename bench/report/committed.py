"""``python -m bench.report.committed reports/NAME [...]``: the generated blocks of committed report folders, again
from their own ``runs.csv`` (their run dirs may be gone): the provenance stamp (``bench.report.provenance_check``)
on the tables and the README, and the two regimes (``bench.report.regime``) in ``scale.md`` and, for a study
with ``paper: true``, ``tables.md``. Nothing else in the folder changes; the tests under ``tests/report/`` fail
when a folder's blocks differ from what this writes.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path

from bench.errors import BenchError, ReportError, failed
from bench.report.provenance_check import stamp_committed
from bench.report.regime import paper_study, regime_committed


def refresh(folder: Path) -> str:
    """Rewrite ``folder``'s generated blocks; one line saying what it holds now."""
    if not (Path(folder) / "runs.csv").is_file():
        raise ReportError(f"expected a report folder with runs.csv, found no '{Path(folder) / 'runs.csv'}'")
    regime = regime_committed(folder, paper_study(folder))  # first: the stamp goes above it
    stamp = stamp_committed(folder)
    return f"{folder}: {stamp or 'clean runs'}; regime in {', '.join(p.name for p in regime) or 'no file'}"


def main(argv: Sequence[str] | None = None) -> int:
    folders = [Path(a) for a in (sys.argv[1:] if argv is None else argv)]
    try:
        if not folders:
            raise ReportError("expected report folders, e.g. reports/memory, found none")
        for folder in folders:
            print(refresh(folder))
    except BenchError as exc:
        return failed(exc)
    return 0


if __name__ == "__main__":
    sys.exit(main())
