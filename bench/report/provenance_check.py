"""Clean provenance: a study's report comes from runs made at a commit of this repository, from a clean tree.

``python -m bench.report --study NAME`` refuses runs whose ``git_dirty`` is true (uncommitted changes in the code
they ran) or whose ``git_commit`` is not in the history of the checkout's HEAD (or was not recorded), in one line
naming them. ``--allow-dirty`` writes the report anyway and stamps every table (``tables.md``, ``scale.md``, each
``.tex``) and the folder's README with ``stamp_text``, e.g. "made from runs with uncommitted changes: 17 of 18".

The committed folders whose run dirs are gone are stamped from their ``runs.csv`` alone:
``python -m bench.report.committed reports/NAME [...]`` (``tests/report/test_provenance_check.py`` checks
every folder's stamp against its data).
"""

from __future__ import annotations

import re
import subprocess
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import pandas as pd

from bench.errors import ReportError
from bench.report.blocks import get_block, put_block

REPO = Path(__file__).resolve().parents[2]
STAMP_BLOCK = "provenance-stamp"
STAMP_BEGIN = f"<!-- {STAMP_BLOCK} -->"
TEX_STAMP = "% provenance: "
MARKDOWN_TABLES = ("tables.md", "scale.md")


@cache
def in_history(commit: str, repo: Path = REPO) -> bool:
    """True when ``commit`` is HEAD or one of its ancestors in ``repo``."""
    try:
        out = subprocess.run(
            ["git", "merge-base", "--is-ancestor", commit, "HEAD"], cwd=repo, capture_output=True, timeout=10
        )
    except (OSError, subprocess.TimeoutExpired):
        return False
    return out.returncode == 0


@dataclass(frozen=True)
class Provenance:
    """Which runs of a report are not clean, by their ``runs.csv`` path."""

    total: int
    dirty: tuple[str, ...]  # git_dirty true
    foreign: tuple[str, ...]  # git_commit missing or not in HEAD's history

    @property
    def clean(self) -> bool:
        return not self.dirty and not self.foreign


def _truthy(value: object) -> bool:
    return str(value).strip().lower() in {"true", "1", "1.0"}


def provenance(runs: pd.DataFrame, repo: Path = REPO) -> Provenance:
    """The unclean runs of ``runs`` (a ``runs.csv`` table: ``path``, ``git_dirty``, ``git_commit``)."""
    paths = runs["path"].astype(str) if "path" in runs else pd.Series(map(str, range(len(runs))))
    dirty = runs["git_dirty"].map(_truthy) if "git_dirty" in runs else pd.Series(False, index=runs.index)
    commits = runs["git_commit"] if "git_commit" in runs else pd.Series(None, index=runs.index)
    foreign = commits.map(lambda c: not isinstance(c, str) or not c or not in_history(c, repo))
    return Provenance(len(runs), tuple(paths[dirty.to_numpy()]), tuple(paths[foreign.to_numpy()]))


def stamp_text(prov: Provenance) -> str | None:
    """The stamp a report made from ``prov``'s runs carries; None when every run is clean."""
    parts = []
    if prov.dirty:
        parts.append(f"made from runs with uncommitted changes: {len(prov.dirty)} of {prov.total}")
    if prov.foreign:
        parts.append(
            f"made from runs at a commit not in this repository's history: {len(prov.foreign)} of {prov.total}"
        )
    return "; ".join(parts) or None


def refusal(study: str, prov: Provenance) -> str:
    """The one line ``--study`` prints when it refuses ``prov``'s runs."""
    named = [*prov.dirty, *(p for p in prov.foreign if p not in prov.dirty)]
    shown = ", ".join(named[:3]) + (f", and {len(named) - 3} more" if len(named) > 3 else "")
    return (
        f"study '{study}': expected runs from a clean tree at a commit of this repository, found "
        f"{len(prov.dirty)} of {prov.total} made with uncommitted changes and {len(prov.foreign)} at a commit not "
        f"in its history ({shown}); rerun them from a clean checkout, or pass --allow-dirty to stamp the report"
    )


def check(study: str, runs: pd.DataFrame, allow_dirty: bool, repo: Path = REPO) -> str | None:
    """The stamp for a study's report of ``runs``; ``ReportError`` (``refusal``) unless clean or ``allow_dirty``."""
    prov = provenance(runs, repo)
    if not prov.clean and not allow_dirty:
        raise ReportError(refusal(study, prov))
    return stamp_text(prov)


def stamp_report(folder: Path, stamp: str | None) -> list[Path]:
    """Put ``stamp`` (None: take any old one out) on the tables and README of ``folder``; the files changed."""
    changed = []
    for path in sorted(Path(folder).iterdir()):
        if not path.is_file():
            continue
        text = path.read_text(encoding="utf-8") if path.suffix in {".md", ".tex"} else None
        if text is None:
            continue
        if path.name in MARKDOWN_TABLES or path.name == "README.md":
            new = _stamp_markdown(text, stamp, readme=path.name == "README.md")
        elif path.suffix == ".tex":
            kept = "".join(line for line in text.splitlines(keepends=True) if not line.startswith(TEX_STAMP))
            new = (f"{TEX_STAMP}{stamp}\n" if stamp else "") + kept
        else:
            continue
        if new != text:
            path.write_text(new, encoding="utf-8")
            changed.append(path)
    return changed


def _stamp_markdown(text: str, stamp: str | None, readme: bool) -> str:
    """The block goes after a README's title line, at the top of a generated table file."""
    body = None if stamp is None else f"**Provenance: {stamp}** (`git_dirty`, `git_commit` in `runs.csv`)."
    return put_block(text, STAMP_BLOCK, body, after_title=readme)


def stamp_of(folder: Path) -> str | None:
    """The stamp a README or table of ``folder`` carries now (None: none)."""
    for name in ("README.md", *MARKDOWN_TABLES):
        path = Path(folder) / name
        body = get_block(path.read_text(encoding="utf-8"), STAMP_BLOCK) if path.is_file() else None
        found = re.search(r"\*\*Provenance: (.*?)\*\*", body or "")
        if found:
            return found.group(1)
    return None


def stamp_committed(folder: Path) -> str | None:
    """Stamp a report folder from its own ``runs.csv`` (its run dirs may be gone); the stamp written."""
    runs_csv = Path(folder) / "runs.csv"
    if not runs_csv.is_file():
        raise ReportError(f"expected a report folder with runs.csv, found no '{runs_csv}'")
    stamp = stamp_text(provenance(pd.read_csv(runs_csv, low_memory=False)))
    stamp_report(Path(folder), stamp)
    return stamp
