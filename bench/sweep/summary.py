"""What a person reads when a run or a sweep ends: an aligned run table, a sweep comparison.

A run prints a short two-column table (headline metrics with units, wall time, run dir). A sweep
(``--multirun``) plans its jobs once (``bench.sweep.plan.planned``) and ``SweepSummary`` (a Hydra callback
in the main process) writes that plan to ``<sweep dir>/.pocketbench_jobs.jsonl``. Each job, wherever
it runs (a launcher's worker, a cluster node, the sweeper for a job that cannot be composed), appends
its outcome there and prints ``sweep: k/n runs done, ETA ...``. When the sweep is over the callback
prints one table of every planned job, with the status it ended in or ``not run``, and writes each
sweep dir's rows as its ``summary.md`` (a study's jobs are in several sweep dirs).
"""

from __future__ import annotations

import json
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from hydra.experimental.callback import Callback
from omegaconf import DictConfig

from bench.measure.progress import format_duration

JOBS_FILE = ".pocketbench_jobs.jsonl"
SUMMARY_FILE = "summary.md"
# where the jobs of the sweep in progress record their outcome: set by SweepSummary in the main
# process, inherited by the launcher's workers; a study's jobs write to several sweep dirs
JOBS_ENV = "POCKETBENCH_SWEEP_JOBS"
NOT_RUN = "not run"


def _num(fmt: str, unit: str = "") -> Callable[[Any], str]:
    def show(value: Any) -> str:
        if value is None:
            return "n/a"
        return f"{value:{fmt}}{unit}"

    return show


# (label, metrics key, formatter) for the per-run table and the sweep columns
FIELDS: tuple[tuple[str, str, Callable[[Any], str]], ...] = (
    ("ATE", "ate_rmse_m", _num(".4f", " m")),
    ("PSNR", "psnr_db", _num(".2f", " dB")),
    ("SSIM", "ssim", _num(".4f")),
    ("MS-SSIM", "ms_ssim", _num(".4f")),
    ("LPIPS", "lpips", _num(".4f")),
    ("FPS", "fps", _num(".2f")),
    ("peak memory", "peak_mem_mib", _num(".1f", " MiB")),
    ("Gaussians", "gaussians_peak", _num("d", " peak")),
)


def run_table(status: str, out_dir: Path, metrics: dict[str, Any], wall_s: float | None) -> str:
    """The aligned table printed after one run."""
    rows = [("status", status)]
    if metrics.get("eval_protocol"):  # the pixels PSNR/SSIM/MS-SSIM/LPIPS were scored on (eval.protocol)
        rows.append(("protocol", str(metrics["eval_protocol"])))
    for label, key, show in FIELDS:
        value = show(metrics.get(key))
        if key == "peak_mem_mib" and metrics.get("peak_mem_source") and value != "n/a":
            value += f" ({metrics['peak_mem_source']})"
        if key == "gaussians_peak" and metrics.get("gaussians_final") is not None:
            value += f", {metrics['gaussians_final']} final"
        if key == "ms_ssim" and value == "n/a" and metrics.get("psnr_db") is not None:
            value += " (images under 176 px on a side)"
        if key == "lpips" and value == "n/a":
            value += " (no AlexNet weights: set eval.lpips_weights=PATH)"
        rows.append((label, value))
    if wall_s is not None:
        phases = (
            ("SLAM", "slam_wall_s"),
            ("first frame", "warmup_s"),
            ("refine", "refine_s"),
            ("evaluation", "eval_s"),
        )
        parts = [f"{k} {metrics[m]:.1f} s" for k, m in phases if metrics.get(m) is not None]
        rows.append(("wall time", format_duration(wall_s) + (f" ({', '.join(parts)})" if parts else "")))
    rows.append(("run dir", str(out_dir)))
    width = max(len(label) for label, _ in rows)
    return "\n".join(f"  {label:<{width}}  {value}" for label, value in rows)


# sweep table columns: header, metrics key, formatter (units in the header, bare numbers below)
SWEEP_COLUMNS: tuple[tuple[str, str, Callable[[Any], str]], ...] = (
    ("ATE [m]", "ate_rmse_m", _num(".4f")),
    ("PSNR [dB]", "psnr_db", _num(".2f")),
    ("SSIM", "ssim", _num(".4f")),
    ("LPIPS", "lpips", _num(".4f")),
    ("FPS", "fps", _num(".2f")),
    ("peak [MiB]", "peak_mem_mib", _num(".1f")),
    ("Gaussians", "gaussians_peak", _num("d")),
)


def varying_overrides(names: list[str]) -> tuple[list[str], list[str]]:
    """Each run's name cut to the overrides that differ between runs, and the shared ones.

    Hydra names a sweep run dir by all its overrides (``a=1,b=2``); in a table only the swept
    ones tell the runs apart.
    """
    split = [[t for t in name.split(",") if t] for name in names]
    shared = [t for t in split[0] if all(t in s for s in split[1:])] if split else []
    short = [" ".join(t for t in s if t not in shared) or "(shared overrides only)" for s in split]
    return short, shared


def sweep_table(jobs: list[dict[str, Any]]) -> str:
    """A Markdown pipe table, padded so it also reads well in a terminal."""
    header = ["run", "status", *(h for h, _, _ in SWEEP_COLUMNS), "wall"]
    body = []
    jobs = sorted(jobs, key=lambda j: (j.get("num", 0), j.get("name", "")))
    names, _ = varying_overrides([j.get("name") or "" for j in jobs])
    for job, name in zip(jobs, names, strict=True):
        metrics = job.get("metrics") or {}
        cells = [show(metrics.get(key)) for _, key, show in SWEEP_COLUMNS]
        wall = job.get("wall_s")
        body.append([name, job.get("status", "?"), *cells, format_duration(wall) if wall is not None else "n/a"])
    widths = [max(len(r[i]) for r in [header, *body]) for i in range(len(header))]
    left = {0, 1}

    def line(cells: list[str]) -> str:
        padded = [c.ljust(w) if i in left else c.rjust(w) for i, (c, w) in enumerate(zip(cells, widths, strict=True))]
        return "| " + " | ".join(padded) + " |"

    rule = "|" + "|".join(("-" * (w + 1) + ":" if i not in left else "-" * (w + 2)) for i, w in enumerate(widths))
    return "\n".join([line(header), rule + "|", *(line(r) for r in body)])


def _jobs_path(sweep_dir: str | Path) -> Path:
    """The record of the sweep in progress (``JOBS_ENV``), else the one in ``sweep_dir``."""
    return Path(os.environ.get(JOBS_ENV) or Path(sweep_dir).resolve() / JOBS_FILE)


def read_jobs(sweep_dir: str | Path) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """``(header, jobs)`` recorded so far in this sweep (header: start time, total, the planned jobs)."""
    try:
        lines = _jobs_path(sweep_dir).read_text().splitlines()
    except OSError:
        return {}, []
    records = []
    for ln in lines:
        try:
            records.append(json.loads(ln))
        except json.JSONDecodeError:  # a line cut short by a killed job
            continue
    header: dict[str, Any] = next((r for r in records if "total" in r), {})
    return header, [r for r in records if "status" in r]


def record_job(sweep_dir: str | Path, job: dict[str, Any]) -> str:
    """Append one finished run; returns the ``sweep: k/n runs done`` progress line."""
    path = _jobs_path(sweep_dir)
    path.parent.mkdir(parents=True, exist_ok=True)
    # a leading newline ends a line a killed job may have left unfinished
    line = ("\n" + json.dumps(job, default=str) + "\n").encode()
    fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    try:
        os.write(fd, line)  # one write with O_APPEND: lines from parallel jobs do not interleave
    finally:
        os.close(fd)
    header, jobs = read_jobs(sweep_dir)
    done, total = len({(j.get("num"), j.get("name")) for j in jobs}), header.get("total")
    text = f"sweep: {done}/{total or '?'} runs done"
    start = header.get("start")
    if total and start and done:
        elapsed = time.time() - float(start)
        text += f" in {format_duration(elapsed)}"
        if done < total:
            text += f", ETA {format_duration(elapsed / done * (total - done))}"
    return text


def planned_rows(header: dict[str, Any], jobs: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Every planned job with what it recorded (matched by its settings, duplicates in order), or
    ``not run``; without a plan (a record from before plans were written), the records as they are."""
    plan = header.get("planned")
    if not plan:
        return jobs
    left: dict[str, list[dict[str, Any]]] = {}
    for job in sorted(jobs, key=lambda j: j.get("num", 0)):
        left.setdefault(job.get("name") or "", []).append(job)
    rows = []
    for job in plan:
        done = left.get(job["name"]) or []
        rows.append({**done.pop(0), **job} if done else {**job, "status": NOT_RUN, "metrics": {}, "wall_s": None})
    return rows


class SweepSummary(Callback):
    """Hydra callback (``hydra.callbacks`` in config.yaml): writes the plan of a sweep, and prints
    and writes the comparison table when it ends. Runs in the main process only."""

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        from bench.sweep.plan import header, planned

        path = Path(config.hydra.sweep.dir).resolve() / JOBS_FILE
        path.parent.mkdir(parents=True, exist_ok=True)
        plan = header(config, planned(config, list(config.hydra.overrides.task)))
        path.write_text(json.dumps({"start": time.time(), **plan}) + "\n")
        os.environ[JOBS_ENV] = str(path)

    def on_multirun_end(self, config: DictConfig, **kwargs: Any) -> None:
        path = Path(os.environ.pop(JOBS_ENV, "") or Path(config.hydra.sweep.dir).resolve() / JOBS_FILE)
        header, jobs = read_jobs(path.parent)
        rows = planned_rows(header, jobs)
        if not rows:
            return
        elapsed = time.time() - float(header.get("start", time.time()))
        by_dir: dict[Path, list[dict[str, Any]]] = {}
        for row in rows:
            by_dir.setdefault(_sweep_of(row, path.parent), []).append(row)
        for sweep_dir, own in by_dir.items():
            _, shared = varying_overrides([j.get("name") or "" for j in own])
            common = f"Shared overrides: `{' '.join(shared)}`.\n" if shared else ""
            title = f"# Sweep {sweep_dir.name}: {_counts(own)} in {format_duration(elapsed)}"
            intro = f"Run dirs are under `{sweep_dir}`. {common}".rstrip()
            sweep_dir.mkdir(parents=True, exist_ok=True)
            (sweep_dir / SUMMARY_FILE).write_text(f"{title}\n\n{intro}\n\n{sweep_table(own)}\n")
        written = ", ".join(str(d / SUMMARY_FILE) for d in by_dir)
        print(f"\n{sweep_table(rows)}\n{_counts(rows)}; summary written to {written}", file=sys.stdout, flush=True)
        path.unlink(missing_ok=True)


def _sweep_of(row: dict[str, Any], default: Path) -> Path:
    """The sweep dir a job belongs to: as planned, else its run dir's parent (a record from before plans named
    it), else ``default``."""
    if row.get("sweep"):
        return Path(row["sweep"]).resolve()
    return Path(row["dir"]).resolve().parent if row.get("dir") else default


def _counts(rows: list[dict[str, Any]]) -> str:
    """``3 jobs: 2 ok, 1 failed``: every planned job accounted for."""
    by: dict[str, int] = {}
    for row in rows:
        by[str(row.get("status"))] = by.get(str(row.get("status")), 0) + 1
    return f"{len(rows)} job{'s' * (len(rows) != 1)}: " + ", ".join(f"{n} {status}" for status, n in by.items())
