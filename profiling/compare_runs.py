"""Two run dirs of the same config: do they hold the same results, bit for bit?

    python profiling/compare_runs.py BEFORE_RUN_DIR AFTER_RUN_DIR

Why: a change meant to keep behaviour (a restructure, a rename) is checked by running the same
config before and after it and comparing what the runs wrote. Compared exactly:

- ``metrics.json``: the ``status``, ``error`` and ``run`` blocks less the code version, and every
  field of ``metrics`` except those that measure the machine rather than the method
  (``bench.run.determinism.VOLATILE_METRICS``: wall, SLAM, warm-up, refine and eval seconds, fps,
  seconds per phase, and the memory peaks, which follow the allocator and the process);
- ``keyframes.csv``: the row count and every column except the per-keyframe timings and memory
  peaks (``VOLATILE_KEYFRAME_COLUMNS``);
- ``traj_est.txt`` and ``traj_gt.txt``: byte for byte; ``map.ply`` and ``density.npz`` byte for byte
  when both dirs have them.

Left out by value: ``provenance`` and ``determinism`` (where and when the run ran: host, packages,
git commit, config file paths), ``run.code_version`` (a restructure changes the commit by design),
``checkpoint`` (write times), and the log file. Their shape still counts: the same keys, and a value
null in one run is null in the other, so a field that stops being filled is caught; the git fields
(``provenance.git_commit``, ``git_dirty``) are left out of that too, since one of the two runs may come
from a source export without ``.git``.
Exit status 0 when everything compared is identical, 1 otherwise (each difference on one line).
"""

from __future__ import annotations

import csv
import json
import sys
from pathlib import Path
from typing import Any

from bench.run.determinism import VOLATILE_KEYFRAME_COLUMNS, VOLATILE_METRICS

BYTE_FILES = ("traj_est.txt", "traj_gt.txt", "map.ply", "density.npz")
RUN_BLOCK_IGNORED = ("code_version",)  # the git commit: differs between the two code versions by design
GIT_FIELDS = ("git_commit", "git_dirty")


def _metrics(run_dir: Path) -> dict[str, Any]:
    return json.loads((run_dir / "metrics.json").read_text())


def _keyframes(run_dir: Path) -> list[dict[str, str]]:
    with open(run_dir / "keyframes.csv", newline="") as fh:
        return list(csv.DictReader(fh))


def _shape(obj: Any) -> Any:
    """Keys and null-ness of a json value, not its values."""
    if isinstance(obj, dict):
        return {k: _shape(v) for k, v in obj.items()}
    return "null" if obj is None else "value"


def compare(before: Path, after: Path) -> list[str]:
    """One line per difference; empty when the two run dirs hold the same results."""
    diffs: list[str] = []
    a, b = _metrics(before), _metrics(after)
    for key in ("provenance", "determinism", "checkpoint"):
        shape_a, shape_b = (
            _shape({k: v for k, v in (r.get(key) or {}).items() if k not in GIT_FIELDS}) for r in (a, b)
        )
        if shape_a != shape_b:
            odd = sorted(k for k in set(shape_a) | set(shape_b) if shape_a.get(k) != shape_b.get(k))
            diffs.append(f"metrics.json {key}: keys or null values differ at {', '.join(odd)}")
    for key in ("status", "error"):
        if a.get(key) != b.get(key):
            diffs.append(f"metrics.json {key}: {a.get(key)!r} != {b.get(key)!r}")
    run_a, run_b = ({k: v for k, v in r.get("run", {}).items() if k not in RUN_BLOCK_IGNORED} for r in (a, b))
    for key in sorted(set(run_a) | set(run_b)):
        if run_a.get(key) != run_b.get(key):
            diffs.append(f"metrics.json run.{key}: {run_a.get(key)!r} != {run_b.get(key)!r}")
    m_a, m_b = a.get("metrics", {}), b.get("metrics", {})
    for key in sorted((set(m_a) | set(m_b)) - VOLATILE_METRICS):
        if m_a.get(key) != m_b.get(key):
            diffs.append(f"metrics.json metrics.{key}: {m_a.get(key)!r} != {m_b.get(key)!r}")
    k_a, k_b = _keyframes(before), _keyframes(after)
    if len(k_a) != len(k_b):
        diffs.append(f"keyframes.csv rows: {len(k_a)} != {len(k_b)}")
    cols_a, cols_b = (list(rows[0]) if rows else [] for rows in (k_a, k_b))
    if cols_a != cols_b:
        diffs.append(f"keyframes.csv columns: {cols_a} != {cols_b}")
    for i, (ra, rb) in enumerate(zip(k_a, k_b, strict=False)):
        for col in ra:
            if col not in VOLATILE_KEYFRAME_COLUMNS and ra[col] != rb.get(col):
                diffs.append(f"keyframes.csv row {i} {col}: {ra[col]!r} != {rb.get(col)!r}")
    for name in BYTE_FILES:
        pa, pb = before / name, after / name
        if pa.exists() != pb.exists():
            diffs.append(f"{name}: present in {'before' if pa.exists() else 'after'} only")
        elif pa.exists() and pa.read_bytes() != pb.read_bytes():
            diffs.append(f"{name}: the bytes differ")
    return diffs


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if len(args) != 2:
        print("usage: python profiling/compare_runs.py BEFORE_RUN_DIR AFTER_RUN_DIR", file=sys.stderr)
        return 2
    before, after = (Path(a) for a in args)
    diffs = compare(before, after)
    n_metrics = len(set(_metrics(before).get("metrics", {})) - VOLATILE_METRICS)
    print(
        f"{before} vs {after}: {n_metrics} metrics, {len(_keyframes(before))} keyframe rows, "
        f"{sum((before / n).exists() for n in BYTE_FILES)} files byte for byte; "
        + ("identical" if not diffs else f"{len(diffs)} differences")
    )
    for line in diffs:
        print("  " + line)
    return 1 if diffs else 0


if __name__ == "__main__":
    sys.exit(main())
