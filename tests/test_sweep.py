"""Sweeps: a failed run does not stop the sweep, reruns resume, the joblib launcher works."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
TINY = [
    "dataset.width=48",
    "dataset.height=32",
    "dataset.n_frames=4",
    "slam.tracking_iters=4",
    "slam.mapping_iters=4",
    "slam.refine_iters=4",
    "progress=false",
    "eval.lpips=false",
]


def sweep(tmp_path: Path, *args: str) -> subprocess.CompletedProcess:
    swept = {a.split("=")[0] for a in args}
    tiny = [t for t in TINY if t.split("=")[0] not in swept]
    cmd = [sys.executable, "-m", "bench", "--multirun", *tiny, f"hydra.sweep.dir={tmp_path}/sweep", *args]
    env = {**os.environ, "PYTHONPATH": f"{REPO}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}  # this checkout
    return subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=600, env=env)


def run_dirs(tmp_path: Path) -> dict[str, dict]:
    return {p.parent.name: json.loads(p.read_text()) for p in (tmp_path / "sweep").glob("*/metrics.json")}


@pytest.mark.slow
def test_interrupted_sweep_resumes_without_redoing_runs(tmp_path):
    first = sweep(tmp_path, "+strategy=none,pocket")
    assert first.returncode == 0, first.stderr[-2000:]
    runs = run_dirs(tmp_path)
    assert len(runs) == 2 and all(r["status"] == "ok" for r in runs.values())
    # simulate an interruption: the pocket run never finished
    pocket_dir = next(d for d in (tmp_path / "sweep").iterdir() if "pocket" in d.name)
    stamp = {p: p.stat().st_mtime_ns for p in (tmp_path / "sweep").glob("*/metrics.json")}
    (pocket_dir / "metrics.json").write_text(json.dumps({**runs[pocket_dir.name], "status": "running"}))
    second = sweep(tmp_path, "+strategy=none,pocket")
    assert second.returncode == 0, second.stderr[-2000:]
    assert second.stdout.count("skipped (completed)") == 1
    assert second.stdout.count("| ok (resumed) |") == 1  # the sweep table marks the run it did not redo
    after = {p: p.stat().st_mtime_ns for p in (tmp_path / "sweep").glob("*/metrics.json")}
    none_file = next(p for p in after if "none" in p.parent.name)
    assert after[none_file] == stamp[none_file]  # the finished run was not redone
    assert run_dirs(tmp_path)[pocket_dir.name]["status"] == "ok"


@pytest.mark.slow
def test_failed_run_does_not_stop_the_sweep(tmp_path):
    proc = sweep(tmp_path, "dataset.width=8,48")  # 8 px is rejected with a config error
    assert proc.returncode == 0, proc.stderr[-2000:]
    status = {name: r["status"] for name, r in run_dirs(tmp_path).items()}
    assert sorted(status.values()) == ["failed", "ok"], status
    assert "Traceback" not in proc.stderr


@pytest.mark.slow
def test_joblib_launcher_runs_two_tiny_runs(tmp_path):
    proc = sweep(tmp_path, "hydra/launcher=local", "+strategy=none,area")
    assert proc.returncode == 0, proc.stderr[-2000:]
    runs = run_dirs(tmp_path)
    assert len(runs) == 2 and all(r["status"] == "ok" for r in runs.values()), runs


@pytest.mark.slow
def test_submitit_local_launcher_runs_a_two_run_sweep(tmp_path):
    """The cluster path (submission, pickling, result collection) through submitit's local executor."""
    proc = sweep(tmp_path, "hydra/launcher=submitit_local", "hydra.launcher.timeout_min=10", "+strategy=none,pocket")
    assert proc.returncode == 0, proc.stderr[-3000:] + proc.stdout[-2000:]
    runs = run_dirs(tmp_path)
    assert len(runs) == 2 and all(r["status"] == "ok" for r in runs.values()), runs
    assert list((tmp_path / "sweep" / ".submitit").iterdir()), "submitit wrote no job folders"
    summary = (tmp_path / "sweep" / "summary.md").read_text()
    assert "| +strategy=none " in summary and "| +strategy=pocket " in summary


@pytest.mark.slow
def test_sweep_ends_with_a_comparison_table_and_progress(tmp_path):
    proc = sweep(tmp_path, "+strategy=none,pocket", "progress=true")
    assert proc.returncode == 0, proc.stderr[-2000:]
    # not a terminal: one line per phase, and the sweep count after each run
    assert proc.stderr.count("frames: 4/4 frames in ") == 2 and proc.stderr.count("evaluate: ") == 2
    assert "sweep: 1/2 runs done" in proc.stderr and "ETA" in proc.stderr and "sweep: 2/2 runs done" in proc.stderr
    table = [ln for ln in proc.stdout.splitlines() if ln.startswith("|")]
    assert len(table) == 4 and "ATE [m]" in table[0]
    assert table[2].startswith("| +strategy=none ") and table[3].startswith("| +strategy=pocket ")
    assert (tmp_path / "sweep" / "summary.md").read_text().count("| +strategy=") == 2
