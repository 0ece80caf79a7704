"""One writer per run dir: an OS lock (``fcntl.flock``) on ``LOCK_FILE`` in the dir, held for a run's whole life.

Why the OS and not the ``running`` record: the record names its owner's pid, but two processes that
both read "no live owner" before either writes would both run. ``flock`` is granted to one of them
only, and the kernel lets it go when its holder ends, however it ends (SIGKILL included), so a stale
lock of a dead process is simply taken over; the ``running`` record it left is then marked
interrupted as before (``bench.run.lifecycle``). The lock file holds the holder's pid and host,
which the refusal names. It is removed when the run lets go of it, so a finished dir holds no lock
file.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import logging
import os
import socket
from collections.abc import Iterator
from pathlib import Path

from bench.errors import RunDirBusy

LOCK_FILE = ".pocketbench.lock"
log = logging.getLogger(__name__)


@contextlib.contextmanager
def run_dir_lock(out: Path) -> Iterator[None]:
    """Hold ``out``'s lock while the block runs; ``RunDirBusy`` (one line naming the pid) when another process
    holds it. ``out`` must exist."""
    path = out / LOCK_FILE
    fd = _acquire(path)
    if fd is None:  # a file system without flock (some network mounts): the run goes on unguarded, said once
        log.warning("%s: the file system cannot lock it; nothing stops a second run writing there at once", out)
        yield
        return
    try:
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()} {socket.gethostname()}\n".encode())
        yield
    finally:
        with contextlib.suppress(OSError):
            path.unlink()  # while still held: a process that opened this file finds it gone and retries
        os.close(fd)


def _acquire(path: Path) -> int | None:
    for _ in range(10):  # a holder may remove the file between our open and our flock: then open the new one
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | os.O_CLOEXEC, 0o644)
        except OSError as exc:
            if exc.errno == errno.ELOOP:
                raise RunDirBusy(f"run dir lock: expected a file at {path}, found a symlink") from None
            raise RunDirBusy(f"run dir lock: expected a writable {path}, found: {exc.strerror or exc}") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            if not isinstance(exc, BlockingIOError):  # ENOLCK, EOPNOTSUPP: no locks here at all
                os.close(fd)
                with contextlib.suppress(OSError):
                    path.unlink()
                return None
            holder = _holder(fd)
            os.close(fd)
            raise RunDirBusy(
                f"run dir {path.parent}: expected no other run writing there, found {holder} running in it "
                "(wait for it to end, or choose another hydra.run.dir)"
            ) from None
        try:
            same = os.fstat(fd).st_ino == os.stat(path, follow_symlinks=False).st_ino
        except FileNotFoundError:
            same = False
        if same:
            return fd
        os.close(fd)
    raise RunDirBusy(f"run dir lock: expected to take {path}, found it replaced again and again")


def _holder(fd: int) -> str:
    """``process PID (host)`` as the holder wrote it, or what can be said without it."""
    try:
        pid, _, host = os.pread(fd, 256, 0).decode(errors="replace").strip().partition(" ")
    except OSError:
        pid, host = "", ""
    if not pid.isdigit():
        return "another process"
    return f"process {pid}" + (f" on {host}" if host and host != socket.gethostname() else "")
