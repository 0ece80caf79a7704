"""SIGINT and SIGTERM as an exception the run loop can catch, so a stopped run keeps its results.

Why not KeyboardInterrupt alone: SIGTERM (a cluster's time limit, ``kill``) would end the process
without unwinding, leaving ``metrics.json`` at ``running``. Both signals raise ``Interrupted``,
which is not an ``Exception``, so no ``except Exception`` on the way swallows it. A second signal
while the partial record is being written is ignored, so the record is not cut in half.
"""

from __future__ import annotations

import os
import signal
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from types import FrameType
from typing import Any

HANDLED = (signal.SIGINT, signal.SIGTERM)


class Interrupted(BaseException):
    """The run was stopped by a signal; ``exit_code`` follows the shell's 128 + signal number."""

    def __init__(self, signum: int, message: str | None = None) -> None:
        self.signum = signum
        super().__init__(message or f"interrupted by {signal.Signals(signum).name}")

    @property
    def exit_code(self) -> int:
        return 128 + self.signum


def signal_behind(exc: BaseException) -> Interrupted | None:
    """The ``Interrupted`` behind ``exc``, if a signal caused it, else None.

    The handler raises wherever the main thread is, and that may be Python code that a C extension
    called back (numba's unpickler inside a jitted call, an autograd Function's backward): the extension
    then reports its own error (``SystemError: ... returned a result with an exception set``), with the
    ``Interrupted`` as its cause. A stop is still a stop there.
    """
    seen: set[int] = set()
    cur: BaseException | None = exc
    while cur is not None and id(cur) not in seen:
        if isinstance(cur, Interrupted):
            return cur
        seen.add(id(cur))
        cur = cur.__cause__ or cur.__context__
    return None


@contextmanager
def raise_on_signals() -> Iterator[None]:
    """Within the block, SIGINT/SIGTERM raise ``Interrupted`` (main thread only; elsewhere a no-op)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum: int, frame: FrameType | None) -> None:
        raise Interrupted(signum)

    previous = {s: signal.signal(s, handler) for s in HANDLED}
    try:
        yield
    finally:
        for s, h in previous.items():
            signal.signal(s, h)


@contextmanager
def deferred_signals() -> Iterator[list[int]]:
    """Within the block, SIGINT/SIGTERM are noted, not acted on (writing the final record)."""
    received: list[int] = []
    if threading.current_thread() is not threading.main_thread():
        yield received
        return
    previous = {s: signal.signal(s, lambda signum, frame: received.append(signum)) for s in HANDLED}
    try:
        yield received
    finally:
        for s, h in previous.items():
            signal.signal(s, h)


def preemption_signal() -> signal.Signals:
    """The signal a launcher sends before a timeout or preemption: submitit's (``SUBMITIT_PREEMPT_SIGNAL``, USR2)."""
    return signal.Signals[f"SIG{os.environ.get('SUBMITIT_PREEMPT_SIGNAL', 'USR2')}"]


class Preemption:
    """A preemption signal held for the frame loop; ``hand_over`` passes it on to the launcher's handler."""

    def __init__(self) -> None:
        self.signum: int | None = None
        self._handler: Callable[[int, FrameType | None], Any] | None = None

    def hand_over(self) -> None:
        if self.signum is not None and self._handler is not None:
            self._handler(self.signum, None)


@contextmanager
def held_preemption() -> Iterator[Preemption]:
    """Within the block, a launcher's preemption signal is noted, not acted on, so the frame loop can
    finish its frame and write a checkpoint first. Why: submitit's handler requeues the job and exits
    at once, from wherever the signal lands (mid-frame, before any checkpoint of that point). Engaged
    only where a Python handler for the signal is installed (submitit's); otherwise a no-op."""
    held = Preemption()
    try:
        sig = preemption_signal()
    except KeyError:
        yield held
        return
    previous = signal.getsignal(sig)
    if threading.current_thread() is not threading.main_thread() or not callable(previous):
        yield held
        return
    held._handler = previous

    def note(signum: int, frame: FrameType | None) -> None:
        held.signum = signum

    signal.signal(sig, note)
    try:
        yield held
    finally:
        signal.signal(sig, previous)
