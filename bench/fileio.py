"""Run files opened without following a symlink planted in their place.

Why: a run dir is written by the harness alone. A symlink put where a run file goes (``keyframes.csv`` ->
a file elsewhere) would have the run overwrite, or append to, whatever it points at. ``open_nofollow``
refuses such a link (``O_NOFOLLOW``) where a file is appended or written in place; files replaced by
rename (``bench.run.record.write_text``) replace the link itself. ``planted_links`` finds the links a
run dir holds before the run writes anything (``bench.run.lifecycle`` refuses the run then).

``content_digest`` names an input file by its bytes, for the keys that must survive a copy, a restore or a
remount (which keep bytes, not mtimes): the resume key's input fingerprint and the stereo depth cache.
"""

from __future__ import annotations

import errno
import hashlib
import os
from pathlib import Path
from typing import IO, Any

from bench.errors import ConfigError


def content_digest(path: Path) -> str:
    """BLAKE2b of the file's bytes, hex, read in 1 MiB chunks."""
    digest = hashlib.blake2b()
    with Path(path).open("rb") as fh:  # hashlib.file_digest is Python 3.11+; the package supports 3.10
        while chunk := fh.read(1 << 20):
            digest.update(chunk)
    return digest.hexdigest()


_MODES = {
    "w": os.O_WRONLY | os.O_CREAT | os.O_TRUNC,
    "a": os.O_WRONLY | os.O_CREAT | os.O_APPEND,
    "x": os.O_WRONLY | os.O_CREAT | os.O_EXCL,
}


def open_nofollow(path: Path, mode: str = "w", **kwargs: Any) -> IO[Any]:
    """``open(path, mode)`` (``w``, ``a`` or ``x``, ``b`` for bytes) that refuses a symlink at ``path`` in one
    ``ConfigError`` line rather than write through it."""
    flags = _MODES[mode.replace("b", "")] | os.O_NOFOLLOW | os.O_CLOEXEC
    try:
        fd = os.open(path, flags, 0o644)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise ConfigError(link_message(Path(path))) from None
        raise
    return os.fdopen(fd, mode.replace("x", "w"), **kwargs)


def link_message(path: Path) -> str:
    return (
        f"run file {path}: expected a file the run writes itself, found a symlink to {os.readlink(path)} "
        "(nothing written through it; remove the link)"
    )


def planted_links(root: Path) -> list[Path]:
    """Every symlink under ``root`` (the links themselves; linked folders are not entered)."""
    found = []
    for folder, dirs, files in os.walk(root):
        for name in [*dirs, *files]:
            if os.path.islink(os.path.join(folder, name)):
                found.append(Path(folder) / name)
    return sorted(found)
