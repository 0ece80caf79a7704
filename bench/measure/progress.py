"""Progress for every phase a person waits on: frames, final refinement, evaluation, sweeps.

On a terminal each phase is a tqdm bar left on screen when done. When stderr is not a terminal
(a log file, a SLURM job, a pipe) bars would fill the log with carriage returns, so each phase
prints one line to stderr when it ends instead: what it did, how many, how long.
"""

from __future__ import annotations

import sys
import time
from typing import Any, TextIO


def is_terminal(stream: TextIO) -> bool:
    try:
        return stream.isatty()
    except (AttributeError, ValueError):  # closed or replaced streams
        return False


def format_duration(seconds: float) -> str:
    """``42.1 s``, ``3m05s``, ``1h02m``: short enough for a progress line."""
    if seconds < 60:
        return f"{seconds:.1f} s"
    minutes, sec = divmod(int(round(seconds)), 60)
    if minutes < 60:
        return f"{minutes}m{sec:02d}s"
    hours, minutes = divmod(minutes, 60)
    return f"{hours}h{minutes:02d}m"


class Phase:
    """One phase of ``total`` steps: a bar on a terminal, one closing line otherwise.

    ``enabled=False`` (``progress=false``) prints nothing at all.
    """

    def __init__(self, desc: str, total: int, unit: str, enabled: bool = True, stream: TextIO | None = None) -> None:
        self.desc, self.total, self.unit = desc, int(total), unit
        self.stream = stream or sys.stderr
        self.enabled = enabled
        self.done = 0
        self.postfix: dict[str, Any] = {}
        self._t0 = time.perf_counter()
        self._closed = False
        self._bar = None
        if enabled and is_terminal(self.stream):
            from tqdm import tqdm

            self._bar = tqdm(total=self.total, desc=desc, unit=unit, file=self.stream, dynamic_ncols=True, leave=True)

    def update(self, n: int = 1, **postfix: Any) -> None:
        self.done += n
        if postfix:
            self.postfix.update(postfix)
        if self._bar is not None:
            if postfix:
                self._bar.set_postfix(self.postfix, refresh=False)
            self._bar.update(n)

    def close(self, note: str = "") -> None:
        """End the phase; ``note`` (e.g. ``lost at frame 9``) goes on the closing line."""
        if self._closed:
            return
        self._closed = True
        if self._bar is not None:
            self._bar.close()
        elif self.enabled:
            extra = "".join(f", {k}={v}" for k, v in self.postfix.items())
            note = f" ({note})" if note else ""
            elapsed = format_duration(time.perf_counter() - self._t0)
            print(
                f"{self.desc}: {self.done}/{self.total} {self.unit}s in {elapsed}{extra}{note}",
                file=self.stream,
                flush=True,
            )

    def __enter__(self) -> Phase:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
