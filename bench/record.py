"""Writing ``metrics.json``: atomically, so a reader never sees half a record.

Shared by the run itself and by the sweeper, which records jobs that never reach a run.
"""

from __future__ import annotations

import json
import os
import socket
from pathlib import Path
from typing import Any

import numpy as np


def write_json(path: Path, obj: dict[str, Any]) -> None:
    """Replace ``path`` by ``obj`` as json, through a temporary file and ``os.replace``."""
    tmp = path.with_suffix(".json.tmp")
    with open(tmp, "w") as fh:
        fh.write(json.dumps(obj, indent=2, default=_json_default))
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)


def _json_default(o: Any) -> Any:
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(type(o))


def record_failed(out: Path, error: str, run: dict[str, Any]) -> None:
    """A run dir holding a ``failed`` metrics.json with its one-line ``error`` (what the report reads)."""
    out.mkdir(parents=True, exist_ok=True)
    write_json(out / "metrics.json", {"status": "failed", "error": error, "run": run, "metrics": {}, "provenance": {}})


def owner() -> dict[str, Any]:
    """Who writes a ``running`` record: lets a later reader tell a live run from a killed one."""
    return {"pid": os.getpid(), "host": socket.gethostname(), "start_ticks": _start_ticks(os.getpid())}


def is_leftover(record: dict[str, Any]) -> bool:
    """A ``running`` record whose process is gone (same host, pid not alive): killed, e.g. by SIGKILL.

    A record from another host, or without an owner, cannot be judged and counts as live.
    """
    who = record.get("owner") if isinstance(record.get("owner"), dict) else None
    if record.get("status") != "running" or not who or who.get("host") != socket.gethostname():
        return False
    pid = who.get("pid")
    if not isinstance(pid, int) or pid == os.getpid():
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    except PermissionError:
        return False
    stat = _stat(pid)
    if stat is None:
        return False
    recycled = who.get("start_ticks") is not None and stat[19] != str(who["start_ticks"])
    return recycled or stat[0] == "Z"  # the pid now names another process, or a dead one not reaped


def _stat(pid: int) -> list[str] | None:
    """Fields of /proc/PID/stat after the command name (state first; start time is index 19)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(") ", 1)[1].split()
    except (OSError, IndexError):
        return None


def _start_ticks(pid: int) -> int | None:
    stat = _stat(pid)
    return int(stat[19]) if stat and len(stat) > 19 else None
