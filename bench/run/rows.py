"""Result rows written as they come: a csv file flushed after every row, so a run stopped at any point keeps
every row it made (keyframes.csv, milestones.csv, refine_curve.csv)."""

from __future__ import annotations

import csv
from pathlib import Path
from typing import Any

from bench.fileio import open_nofollow


class FlushedRows:
    """A csv file written a row at a time and flushed after each (appended to on resume); no file when off."""

    def __init__(self, path: Path, columns: list[str], append: bool, on: bool = True) -> None:
        self.path, self.columns, self.append, self.on = path, columns, append, on
        self._fh: Any = None

    def __enter__(self) -> FlushedRows:
        if self.on:
            self._fh = open_nofollow(self.path, "a" if self.append else "w", newline="")
            self._writer = csv.DictWriter(self._fh, fieldnames=self.columns)
            if not self.append:
                self._writer.writeheader()
                self._fh.flush()
        elif not self.append:
            self.path.unlink(missing_ok=True)  # a previous run's rows are not this run's
        return self

    def writerow(self, row: dict[str, Any]) -> None:
        self._writer.writerow(row)
        self._fh.flush()

    def __exit__(self, *exc: object) -> None:
        if self._fh is not None:
            self._fh.close()
