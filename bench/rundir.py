"""Reading a run directory beside its format (``bench.schema``): who owns a ``running`` record, and
whether that owner is still alive.

A reader (the run deciding whether to resume, a report, the viewer) must tell a run still going from one
killed mid-way (SIGKILL leaves ``running`` behind); the run's writer stamps its ``owner`` block with
``owner()``, and any reader judges it with ``is_leftover``, without importing the run itself.
"""

from __future__ import annotations

import os
import socket
from pathlib import Path
from typing import Any


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
