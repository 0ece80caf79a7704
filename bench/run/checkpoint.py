"""Checkpoints of the frame loop, so that a stopped run resumes where it stopped and ends as if never stopped.

A checkpoint is written into the run dir after a keyframe's prune (every ``checkpoint.every``
keyframes), and on a launcher's preemption signal at the next frame boundary. It holds everything
that decides what happens next: the map with its Adam moments, the keyframe store (by frame index;
the images are re-read from the sequence), poses, the velocity and flow state, the lost-detector
counters, the strategy's own attributes, every random generator (the system's own, torch's, numpy's
and Python's global ones), the loop's running sums, and how many rows of ``traj_est.txt`` and
``keyframes.csv`` were flushed, so a resume truncates rows written after it.

Why this is enough for a bit-identical resume: every other input of a frame is a pure function of the
config, the frame index and the input files, and all three are in the resume key checked on load.
OpenCV's global generator is not saved: nothing in the loop draws from it (its RANSAC keeps a
private, fixed-seed one; see ``bench/slam/frontend.py``), so re-seeding it at the start is exact.

Files are written atomically (a temporary file, fsync, then ``os.replace``); with ``keep=2`` the
previous checkpoint stays as ``checkpoint.prev.pt`` and is used when the newest one cannot be.
Loading uses ``torch.load(weights_only=True)``: a checkpoint holds tensors and plain values only.
"""

from __future__ import annotations

import logging
import os
import random
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import numpy as np
import torch

from bench.config.settings import check_rules, setting
from bench.errors import BenchError
from bench.fileio import open_nofollow
from bench.run.resume import redo_reason

log = logging.getLogger(__name__)

FILES = ("checkpoint.pt", "checkpoint.prev.pt")  # newest first
FORMAT = 2  # bumped when the layout changes: an older checkpoint is then refused, not misread
MIB = 1 << 20


@dataclass
class CheckpointConfig:
    """``checkpoint.every=K``: a checkpoint every K keyframes (0 = none); ``checkpoint.keep``: 1 or 2 files."""

    every: int = setting(1, "int", lo=0)  # keyframes; 0 = none
    keep: int = setting(2, "int", lo=1, hi=2)

    def __post_init__(self) -> None:
        check_rules(self, "checkpoint.")


@dataclass
class Written:
    """What one checkpoint cost: its size and the time to serialise and write it."""

    mib: float
    write_s: float


class CheckpointError(BenchError):
    """A checkpoint cannot be written where it belongs (a directory in its place, a full disk)."""


def check_files(out: Path) -> None:
    """One line unless each checkpoint path of ``out`` is a plain file or absent: checked before a run
    starts, as a directory there would fail the first write after frames of work."""
    for name in (*FILES, FILES[0] + ".tmp"):
        path = out / name
        if path.exists() and not path.is_file():
            raise CheckpointError(f"checkpoint: expected a file or nothing at {path}, found a directory")


def save(out: Path, payload: dict[str, Any], keep: int = 2) -> Written:
    """Write ``payload`` as the newest checkpoint of run dir ``out``; the older one is rotated or dropped.

    A failed write (a full disk) leaves the checkpoints as they were and no temporary file, and is
    one ``CheckpointError`` line: the run then ends ``failed`` with what it computed."""
    t0 = time.perf_counter()
    newest, previous = (out / f for f in FILES)
    tmp = out / (FILES[0] + ".tmp")
    try:
        tmp.unlink(missing_ok=True)  # a leftover (or a link planted there): the temporary file is made new
        with open_nofollow(tmp, "xb") as fh:
            torch.save({"format": FORMAT, **payload}, fh)
            fh.flush()
            os.fsync(fh.fileno())
    except (OSError, RuntimeError) as exc:  # torch reports a failed write as a RuntimeError
        tmp.unlink(missing_ok=True)
        why = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc).strip().splitlines()[0]
        raise CheckpointError(f"checkpoint: expected to write {newest}, found the write failing: {why}") from None
    size = tmp.stat().st_size
    if keep == 2 and newest.exists():
        os.replace(newest, previous)  # between the two renames the previous one is still there
    elif keep == 1:
        previous.unlink(missing_ok=True)
    os.replace(tmp, newest)
    return Written(round(size / MIB, 3), round(time.perf_counter() - t0, 4))


def remove(out: Path) -> None:
    """Drop every checkpoint of ``out`` (a fresh start, or a run that finished)."""
    for name in (*FILES, FILES[0] + ".tmp"):
        (out / name).unlink(missing_ok=True)


def exists(out: Path) -> bool:
    return any((out / f).exists() for f in FILES)


def find(out: Path, key: dict[str, Any], rows: dict[str, int]) -> tuple[dict | None, str]:
    """(the newest usable checkpoint, "") or (None, why none is usable).

    ``key`` is the run's resume key; ``rows`` the data rows now in the run's flushed files
    (``traj``, ``keyframes``), which must hold at least what the checkpoint counted. Tensors load
    on the CPU, where torch keeps Adam's step counts and generator states; the run moves the rest.
    """
    reasons: list[str] = []
    for name in FILES:
        path = out / name
        if not path.exists():
            continue
        ckpt, why = _load(path, key, rows)
        if ckpt is not None:
            if reasons:
                log.warning("%s: %s; using %s", out, reasons[0], name)
            return ckpt, ""
        reasons.append(f"{name} {why}")
    return None, reasons[0] if reasons else "no checkpoint"


def _load(path: Path, key: dict[str, Any], rows: dict[str, int]) -> tuple[dict | None, str]:
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # truncated, corrupt, or a pickle that is not plain tensors and values
        first = (str(exc).strip().splitlines() or [type(exc).__name__])[0].split(". ")[0]  # its first sentence
        return None, f"is unreadable (truncated or corrupt: {first[:120]})"
    if not isinstance(ckpt, dict) or ckpt.get("format") != FORMAT:
        found = ckpt.get("format") if isinstance(ckpt, dict) else type(ckpt).__name__
        return None, f"has format {found}, expected {FORMAT}"
    try:
        stored_key = ckpt["key"]
        why = redo_reason({"status": "ok", "run": stored_key}, key)
        if why is not None:
            return None, f"is foreign: {why}"
        for name, n in ckpt["rows"].items():
            if rows.get(name, 0) < n:
                return None, f"counts {n} {name} rows but the run dir holds {rows.get(name, 0)}"
        ckpt["frame"], ckpt["keyframe"], ckpt["system"], ckpt["drive"], ckpt["rng"]  # noqa: B018 (all present)
    except (KeyError, TypeError) as exc:
        return None, f"is incomplete (missing {exc})"
    return ckpt, ""


# ---------------------------------------------------------------------------------------------- generators


def global_rng_state() -> dict[str, Any]:
    """torch's, numpy's legacy and Python's global generators (and CUDA's where present), as plain values."""
    # numpy's stub picks the dict overload for no argument; the call returns the legacy tuple
    legacy = cast(tuple[str, np.ndarray, int, int, float], np.random.get_state())
    name, keys, pos, has_gauss, cached = legacy
    version, internal, gauss = random.getstate()
    state = {
        "torch": torch.get_rng_state(),
        "numpy": [name, torch.from_numpy(keys.astype(np.int64)), pos, has_gauss, cached],
        "python": [version, torch.tensor(internal, dtype=torch.int64), gauss],
    }
    if torch.cuda.is_available() and torch.cuda.is_initialized():
        state["cuda"] = torch.cuda.get_rng_state_all()
    return state


def set_global_rng_state(state: dict[str, Any]) -> None:
    torch.set_rng_state(state["torch"].cpu())
    name, keys, pos, has_gauss, cached = state["numpy"]
    np.random.set_state((name, keys.cpu().numpy().astype(np.uint32), pos, has_gauss, cached))
    version, internal, gauss = state["python"]
    random.setstate((version, tuple(internal.tolist()), gauss))
    if "cuda" in state and torch.cuda.is_available():
        torch.cuda.set_rng_state_all([s.cpu() for s in state["cuda"]])


# ---------------------------------------------------------------------------------------------- flushed rows


def data_rows(path: Path, header_lines: int) -> int:
    """Complete data rows in a flushed text file (a last line without its newline does not count)."""
    try:
        text = path.read_bytes()
    except OSError:
        return 0
    return max(0, text.count(b"\n") - header_lines)


def truncate_rows(path: Path, header_lines: int, n: int) -> None:
    """Keep the header and the first ``n`` data rows of ``path``; later rows (written after the
    checkpoint) are cut, so the resumed run appends exactly where the checkpoint stood."""
    data = path.read_bytes()
    end = 0
    for _ in range(header_lines + n):
        end = data.index(b"\n", end) + 1
    with open(path, "r+b") as fh:
        fh.truncate(end)
        fh.flush()
        os.fsync(fh.fileno())
