"""Find run dirs under sweep dirs and flatten each metrics.json into one tidy row.

A sweep nests runs anywhere (Hydra's ``multirun/DATE/TIME/N/``), so any dir holding
``metrics.json`` is a run. A malformed run is skipped with a warning rather than aborting the
report: one crashed job must not hide the rest of a sweep.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd

from bench import schema
from bench.datasets import canonical_seq
from bench.errors import ReportError
from bench.names import method_name, synthetic_drive
from bench.report.settings import read_settings
from bench.rundir import is_leftover

REQUIRED_RUN_KEYS: tuple[str, ...] = ("strategy", "dataset")
DEFAULT_SEQ = "default"  # the harness writes seq null when a dataset has no named default sequence
DEFAULT_PRESET = "default"  # runs written before slam_preset existed used the default backend
DEFAULT_PROTOCOL = "full"  # runs written before eval.protocol existed were scored on the whole image
# The metrics every row has, first and in this order (names from bench.schema, which says which are
# numbers); any other metric a run wrote is kept and appended.
METRIC_KEYS: tuple[str, ...] = (
    "ate_rmse_m", "ate_alignment", "ate_num_poses", "psnr_db", "ssim", "ms_ssim", "lpips", "eval_frames",
    "fps", "fps_slam", "slam_wall_s", "refine_s", "num_frames", "num_keyframes", "gaussians_final", "gaussians_peak",
    "gaussians_added_total", "gaussians_pruned_total", "prune_candidates_total",
    "state_peak_mib", "cpu_rss_peak_mib", "torch_live_peak_mib", "cuda_alloc_peak_mib",
    "cuda_reserved_peak_mib", schema.PEAK_FIELD,
)  # fmt: skip


@dataclass
class Collection:
    """Every run found: usable ones as rows, malformed ones with the reason they were skipped."""

    runs: pd.DataFrame
    skipped: list[tuple[Path, str]] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)


def find_run_dirs(roots: Iterable[Path]) -> list[Path]:
    """Every dir holding ``metrics.json`` under ``roots`` (recursive, deduplicated, sorted), a redo's
    staging dir (``schema.REDO_DIR``) left out."""
    found: dict[Path, Path] = {}
    for root in roots:
        root = Path(root)
        if not root.exists():
            raise ReportError(f"sweep dir not found: expected an existing dir, found no '{root}'")
        if root.is_file():
            if root.name != schema.METRICS_FILE:
                raise ReportError(f"expected a sweep or run dir, found the file '{root}'")
            candidates = [root]
        else:
            # a redo's staging dir is not a run of its own: it replaces its run's files once it finishes
            candidates = sorted(m for m in root.rglob(schema.METRICS_FILE) if schema.REDO_DIR not in m.parts)
        for metrics in candidates:
            found.setdefault(metrics.parent.resolve(), metrics.parent)
    return sorted(found.values(), key=lambda p: str(p))


def _number(key: str, value: Any) -> int | float | None:
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ReportError(f"expected a number or null for '{key}', found {value!r}")
    return value


def _flat_metrics(metrics: dict[str, Any]) -> dict[str, Any]:
    """Known metrics must be numbers or null; anything else the harness adds (a per-phase time
    dict, the probe behind the peak, a frame range) is kept for runs.csv: dicts one level flat as
    ``key.sub``, lists as json text."""
    out: dict[str, Any] = {}
    for key, value in metrics.items():
        if key in schema.NUMERIC_METRICS:
            out[key] = _number(key, value)
        elif isinstance(value, dict):
            for sub, item in value.items():
                out[f"{key}.{sub}"] = json.dumps(item) if isinstance(item, (dict, list)) else item
        elif isinstance(value, list):
            out[key] = json.dumps(value)
        else:
            out[key] = value
    return out


def _dict_or_empty(value: Any) -> dict[str, Any]:
    """``value`` if a JSON object, else ``{}`` (a block missing or null in an older metrics.json)."""
    return value if isinstance(value, dict) else {}


def read_run(run_dir: Path) -> dict[str, Any]:
    """One flat row from ``run_dir/metrics.json``; ``ReportError`` says what is malformed."""
    path = Path(run_dir) / schema.METRICS_FILE
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise ReportError(f"cannot read {path}: {exc.strerror or exc}") from exc
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ReportError(f"expected json in {path}, found invalid json ({exc})") from exc
    if not isinstance(data, dict):
        raise ReportError(f"expected a json object in {path}, found {type(data).__name__}")
    status = data.get("status")
    if status == "running" and is_leftover(data):
        status = "interrupted"  # its process is gone: killed (SIGKILL, power) before it could say so
    if status not in schema.STATUSES:
        raise ReportError(f"expected status one of {'|'.join(schema.STATUSES)} in {path}, found {status!r}")
    run = data.get("run")
    if not isinstance(run, dict) or any(run.get(k) in (None, "") for k in REQUIRED_RUN_KEYS):
        keys = sorted(run) if isinstance(run, dict) else type(run).__name__
        raise ReportError(f"expected run.strategy and run.dataset in {path}, found {keys}")
    metrics = data.get("metrics")
    if metrics is None and status == "failed":
        metrics = {}
    if not isinstance(metrics, dict):
        raise ReportError(f"expected a 'metrics' object in {path}, found {type(metrics).__name__}")

    seed = run.get("seed")
    if seed is not None and (isinstance(seed, bool) or not isinstance(seed, int)):
        raise ReportError(f"expected an integer run.seed in {path}, found {seed!r}")
    try:
        keep_ratio = _number("run.keep_ratio", run.get("keep_ratio"))
        keep_ratio = None if keep_ratio is None else float(keep_ratio)
        values = _flat_metrics(metrics)
        protocol = values.pop("eval_protocol", None)
        if protocol is not None and not isinstance(protocol, str):
            raise ReportError(f"expected a protocol name or null for 'eval_protocol', found {protocol!r}")
    except ReportError as exc:
        raise ReportError(f"{exc} in {path}") from None

    row: dict[str, Any] = {
        "strategy": str(run["strategy"]),
        "method": method_name(str(run["strategy"])),
        "dataset": str(run["dataset"]),
        "seq": DEFAULT_SEQ if run.get("seq") in (None, "") else canonical_seq(str(run["dataset"]), run["seq"]),
        "seed": seed,
        "keep_ratio": keep_ratio,
        "slam_preset": str(run.get("slam_preset") or DEFAULT_PRESET),
        "eval_protocol": protocol,  # which pixels the image metrics scored (bench.metrics.protocol); set below
        "config_hash": run.get("config_hash"),
        "status": status,
        "error": data.get("error"),
    }
    for key in METRIC_KEYS:
        row[key] = values.pop(key, None)
    for key, value in sorted(values.items()):
        if key not in row:  # metrics.keep_ratio repeats run.keep_ratio (bench.schema): the run key stands
            row[key] = value
    provenance = _dict_or_empty(data.get("provenance"))
    for key in (
        "git_commit",
        "git_dirty",
        "device",
        "numba_cpu",
        "numba_cpu_features_sha",
        "cpu_model",
        "torch_cpu_capability",
    ):
        row[key] = provenance.get(key)
    versions = _dict_or_empty(provenance.get("versions"))
    for name, version in sorted(versions.items()):
        row[f"version_{name}"] = version
    row.update(read_settings(run_dir, provenance.get("device")))
    # a run that failed before evaluating says its protocol only in its config.yaml, if at all (then None:
    # its 'failed' mark stands in every protocol's table); a finished run from before protocols was full
    row["eval_protocol"] = protocol or row.get("eval.protocol") or (None if status == "failed" else DEFAULT_PROTOCOL)
    if row.get("dataset") == "synthetic" and row.get("seq") is not None:
        row["seq"] = synthetic_drive(row["seq"], row.get("dataset.route"), row.get("dataset.route_file"))
    row["path"] = str(run_dir)
    return row


def collect(roots: Iterable[Path]) -> Collection:
    """All runs under ``roots`` as a DataFrame; fails only when nothing usable remains."""
    roots = [Path(r) for r in roots]
    if not roots:
        raise ReportError("expected at least one sweep dir, found none")
    run_dirs = find_run_dirs(roots)
    shown = ", ".join(str(r) for r in roots)
    if not run_dirs:
        raise ReportError(f"no run dirs found: expected metrics.json somewhere under {shown}, found none")
    rows: list[dict[str, Any]] = []
    skipped: list[tuple[Path, str]] = []
    warnings: list[str] = []
    for run_dir in run_dirs:
        try:
            rows.append(read_run(run_dir))
        except ReportError as exc:
            skipped.append((run_dir, str(exc)))
            warnings.append(f"skipped malformed run: {exc}")
    if not rows:
        raise ReportError(
            f"no usable runs under {shown}: found {len(run_dirs)} metrics.json, all malformed (first: {skipped[0][1]})"
        )
    runs = pd.DataFrame(rows)
    runs = runs[[c for c in runs.columns if c != "path"] + ["path"]]
    for column in runs.columns:  # counts stay integers in runs.csv (20, not 20.0)
        present = [v for v in (row.get(column) for row in rows) if v is not None]
        if present and all(isinstance(v, int) and not isinstance(v, bool) for v in present):
            runs[column] = runs[column].astype("Int64")
    runs["seed"] = runs["seed"].astype("Int64")
    keys = [
        "strategy",
        "dataset",
        "seq",
        "seed",
        "keep_ratio",
        "slam_preset",
        "memory_policy",
        "pruning",
        "input",
        "eval_protocol",
    ]
    dupes = runs[runs.duplicated(subset=keys, keep=False)]
    for key, group in dupes.groupby(keys, dropna=False, sort=True):
        warnings.append(
            f"duplicate run {dict(zip(keys, key, strict=True))} in {', '.join(group['path'])}: all are counted as seeds"
        )
    for status in schema.UNFINISHED:
        n = int((runs["status"] == status).sum())
        if n:
            what = "still running" if status == "running" else "interrupted"
            warnings.append(f"{n} run(s) {what}, left out of tables and plots")
    return Collection(runs=runs, skipped=skipped, warnings=warnings)


def is_missing(value: Any) -> bool:
    """True for None, NaN and pandas' NA, the three shapes a null metric takes in a row."""
    if value is None or value is pd.NA:
        return True
    return isinstance(value, float) and math.isnan(value)


def read_run_table(
    path: Path, required: Iterable[str | tuple[str, ...]], warn: Callable[[str], None], where: str = ""
) -> pd.DataFrame | None:
    """One of a run's csv tables (keyframes.csv, milestones.csv), or None with a warning when it is
    not a table holding ``required`` (a tuple there: any one of its columns will do). A missing file
    is None without a warning: the run did not write that table."""
    path = Path(path)
    if not path.is_file():
        return None
    where = f" {where}" if where else ""
    try:
        rows = pd.read_csv(path)
    except (OSError, ValueError) as exc:
        warn(f"skipped {path}{where}: expected a csv table, found {exc}")
        return None
    have = set(rows.columns)
    missing = [
        c if isinstance(c, str) else "/".join(c)
        for c in required
        if not (have & ({c} if isinstance(c, str) else set(c)))
    ]
    if missing:
        warn(f"skipped {path}{where}: expected columns {', '.join(missing)}, found {list(rows.columns)}")
        return None
    return rows


def finished_run_tables(runs: pd.DataFrame, read: Callable[[Path], pd.DataFrame | None]) -> dict[str, pd.DataFrame]:
    """``read`` of every finished (ok or lost) run's dir, keyed by its runs.csv path (runs without one left out)."""
    tables = {}
    for path, status in zip(runs["path"], runs["status"], strict=True):
        if status in ("ok", "lost") and (table := read(Path(path))) is not None:
            tables[str(path)] = table
    return tables


def stack_run_tables(tables: dict[str, pd.DataFrame]) -> pd.DataFrame:
    """The per-run tables as one, with each row's runs.csv ``path`` (a report folder's keyframes.csv and
    milestones.csv, which ``grouped_run_tables`` splits again)."""
    frames = [t.assign(path=p) for p, t in tables.items() if len(t)]
    return pd.concat(frames, ignore_index=True) if frames else pd.DataFrame(columns=["path"])


def grouped_run_tables(rows: pd.DataFrame) -> dict[str, pd.DataFrame]:
    return {str(p): g.drop(columns="path").reset_index(drop=True) for p, g in rows.groupby("path")}
