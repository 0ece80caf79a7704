"""Writing ``metrics.json``: atomically, so a reader never sees half a record.

Every write of a run dir's record goes through ``RunRecord`` here: the run itself (``bench.run``) and the
sweeper, which records jobs that never reach a run. A refusal (a job refused before any work: a
bad setting, data that cannot be opened) writes its ``failed`` record only where no previous run
left one worth keeping (``record_refusal``), so a rerun refused for a passing reason never turns a
finished run into a failed one.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path
from typing import Any

import numpy as np

from bench.fileio import open_nofollow
from bench.run import job_outputs
from bench.run.lock import LOCK_FILE
from bench.schema import METRICS_FILE, REDO_DIR

# statuses a refusal must not replace: finished results, a resumable run, a run that may still be going
KEPT = ("ok", "lost", "interrupted", "running")


def write_json(path: Path, obj: dict[str, Any]) -> None:
    """Replace ``path`` by ``obj`` as json, through a temporary file and ``os.replace``."""
    write_text(path, json.dumps(obj, indent=2, default=_json_default))


def write_text(path: Path, text: str) -> None:
    """Replace ``path`` by ``text`` atomically; a failed write leaves the old file and no temporary one."""
    tmp = path.with_name(path.name + ".tmp")
    tmp.unlink(missing_ok=True)  # a leftover (or a link planted there): the temporary file is made new
    try:
        with open_nofollow(tmp, "x") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


class RunRecord(dict):
    """A run's ``metrics.json`` as it is being made: held here and written whole, atomically, by ``save``.

    The one writer of a run's record: the run while it runs (``save`` after each step a later reader
    may need), at its end (``close``), and a later run marking a killed one's record (``close``).
    """

    def __init__(self, path: Path, fields: dict[str, Any]) -> None:
        super().__init__(fields)
        self.path = path

    def save(self) -> None:
        write_json(self.path, self)

    def close(self, **fields: Any) -> None:
        """The record's last write: ``fields`` (status, error, metrics) set, its owner gone (no longer running)."""
        self.update(fields)
        self.pop("owner", None)
        self.save()


def read_record(out: Path) -> dict[str, Any] | None:
    """The ``metrics.json`` in run dir ``out``, or None where there is none (or none readable)."""
    try:
        stored = json.loads((out / METRICS_FILE).read_text())
    except (OSError, ValueError):
        return None
    return stored if isinstance(stored, dict) else None


def _json_default(o: Any) -> Any:
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(type(o))


def record_refusal(
    out: Path, error: str, run: dict[str, Any], config_yaml: str | None = None, task_cfg: Any = None
) -> str | None:
    """A ``failed`` record for a job refused before any work, with its one-line ``error`` (what the
    report reads), unless ``out`` holds a record to keep (``KEPT``): then nothing is written.

    Returns None when the record was written, else the status of the record kept.
    """
    stored = read_record(out)
    if stored is not None and stored.get("status") in KEPT:
        return str(stored["status"])
    out.mkdir(parents=True, exist_ok=True)
    job_outputs.keep(out, task_cfg)  # Hydra's files, for the job that records here
    if config_yaml is not None:
        write_text(out / "config.yaml", config_yaml)
    refused = {"status": "failed", "error": error, "run": run, "metrics": {}, "provenance": {}}
    RunRecord(out / METRICS_FILE, refused).save()
    return None


def promote(staged: Path, final: Path) -> None:
    """Move a finished redo's files (``staged``, the run dir's ``REDO_DIR``) over the run it redid.

    ``metrics.json`` moves after the files it describes and before the old run's leftovers go, so a
    stop midway leaves either the old record (a rerun finds the finished redo and moves it in) or
    the new one, never a record beside files of another run.
    """
    names = {p.name for p in staged.iterdir()}
    for path in sorted(staged.iterdir(), key=lambda p: p.name == METRICS_FILE):
        target = final / path.name
        if path.is_dir() and target.is_dir():
            shutil.rmtree(target)
        os.replace(path, target)
    for old in final.iterdir():
        if old.name not in names and old.name not in (REDO_DIR, LOCK_FILE):
            shutil.rmtree(old) if old.is_dir() and not old.is_symlink() else old.unlink()
    staged.rmdir()
