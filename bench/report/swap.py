"""A report folder replaced as a unit: built in a temporary folder beside it, swapped in once whole.

Why: written in place, a report stopped part-way (Ctrl-C, SIGTERM, a full disk) left some new files
beside the old ones with no mark, and a smaller report written over a larger one left the old one's
figures and tables beside the new ``tables.md``. Here the report is written into
``.NAME.building-PID-*`` beside ``NAME``; only when it is complete is it swapped in (one
``renameat2(RENAME_EXCHANGE)`` on Linux, two renames with signals held elsewhere), and the old folder
is removed. A stop before that leaves ``NAME`` as it was and removes the temporary folder.

What a report does not write (a hand-written ``README.md``, notes, sub-folders) is carried over from
the old folder (copied before the swap, so a killed process never loses it); the files a report
writes (``REPORT_SUFFIXES``, ``REPORT_NAMES``) come only from the new report.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import errno
import os
import shutil
import tempfile
from collections.abc import Iterator, Sequence
from pathlib import Path

from bench.errors import ReportError
from bench.run.signals import deferred_signals

REPORT_SUFFIXES = (".csv", ".tex", ".png", ".pdf", ".svg")  # tables, figures: what a report writes
REPORT_NAMES = ("tables.md", "scale.md")
_RENAME_EXCHANGE = 2  # linux/fs.h


@contextlib.contextmanager
def built_beside(out: Path, inputs: Sequence[Path] = ()) -> Iterator[Path]:
    """Yield an empty temporary folder beside ``out`` to write the report into; when the block ends without an
    exception it replaces ``out`` as a unit, else it is removed and ``out`` stays as it was. ``out`` may not
    hold any of ``inputs`` (the run dirs read) nor the current dir: replacing it would move them."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ReportError(f"expected an output dir, found the file '{out}'")
    where = out.resolve()
    for inside in (Path.cwd(), *inputs):
        if where == Path(inside).resolve() or where in Path(inside).resolve().parents:
            raise ReportError(
                f"--out: expected a report folder apart from the run dirs and the current dir, found '{out}' "
                f"holding '{inside}'"
            )
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        _remove_leftovers(out)
        work = Path(tempfile.mkdtemp(prefix=f".{out.name}.building-{os.getpid()}-", dir=out.parent))
    except OSError as exc:
        raise ReportError(f"cannot create output dir '{out}': {exc.strerror or exc}") from None
    try:
        yield work
        _carry_over(out, work)
        with deferred_signals():  # the swap and the old folder's removal: never half done by a Ctrl-C
            old = _swap_in(work, out)
            if old is not None:
                shutil.rmtree(old, ignore_errors=True)
    finally:
        shutil.rmtree(work, ignore_errors=True)


def is_report_file(path: Path) -> bool:
    """A file a report writes (and a new report replaces), as opposed to one a person put beside it."""
    return path.is_file() and (path.suffix.lower() in REPORT_SUFFIXES or path.name in REPORT_NAMES)


def _carry_over(out: Path, work: Path) -> None:
    """Copy what the old folder holds that the report does not write into the new one (the new report wins)."""
    if not out.is_dir():
        return
    for old in out.iterdir():
        target = work / old.name
        if is_report_file(old) or target.exists() or target.is_symlink():
            continue
        if old.is_dir() and not old.is_symlink():
            shutil.copytree(old, target, symlinks=True)
        else:
            shutil.copy2(old, target, follow_symlinks=False)


def _swap_in(work: Path, out: Path) -> Path | None:
    """``work`` renamed to ``out``; returns the old folder (now under a temporary name) to remove, if any."""
    if not out.exists():
        os.rename(work, out)
        return None
    if _exchange(work, out):
        return work  # the two names traded places: ``work`` now names the old report
    old = out.with_name(f".{out.name}.old-{os.getpid()}")
    os.rename(out, old)
    os.rename(work, out)
    return old


def _exchange(a: Path, b: Path) -> bool:
    """Swap two paths in one step (Linux ``renameat2``); False where the system cannot."""
    libc_name = ctypes.util.find_library("c")
    if libc_name is None:
        return False
    libc = ctypes.CDLL(libc_name, use_errno=True)
    renameat2 = getattr(libc, "renameat2", None)
    if renameat2 is None:
        return False
    at_fdcwd = -100
    done = renameat2(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), _RENAME_EXCHANGE)
    if done == 0:
        return True
    if ctypes.get_errno() in (errno.EINVAL, errno.ENOSYS, errno.EOPNOTSUPP):  # a file system without it
        return False
    raise OSError(ctypes.get_errno(), os.strerror(ctypes.get_errno()), str(b))


def _remove_leftovers(out: Path) -> None:
    """Temporary folders a killed report left beside ``out`` (its process gone)."""
    for path in out.parent.glob(f".{out.name}.*"):
        kind, _, rest = path.name.removeprefix(f".{out.name}.").partition("-")
        pid = rest.split("-", 1)[0]
        if kind in ("building", "old") and pid.isdigit() and not _alive(int(pid)) and path.is_dir():
            shutil.rmtree(path, ignore_errors=True)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True
