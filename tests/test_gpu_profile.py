"""``profiling/gpu_profile.py``: its phase arithmetic (nested ranges, each phase's exclusive time, which phase a
moment falls in), and one real run on the CPU through it, so a rename in the run's modules cannot leave the GPU
check's profile failing unseen (the script patches ``PhaseTimer.phase``, ``loop.run_frames`` and
``evaluation.evaluate`` by name)."""

from __future__ import annotations

import csv
import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def _module():
    spec = importlib.util.spec_from_file_location("gpu_profile", REPO / "profiling" / "gpu_profile.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_nested_phases_bill_their_time_once():
    iv = _module().Intervals([("evaluation", 100.0, 200.0), ("load", 120.0, 130.0), ("tracking", 0.0, 50.0)])
    assert iv.phase_of(125.0) == "load"  # the innermost range
    assert iv.phase_of(150.0) == "evaluation"  # back in the outer one after the inner ended
    assert iv.phase_of(75.0) == "outside phases"
    excl = iv.exclusive_s()
    assert excl["evaluation"] == pytest.approx(90e-6) and excl["load"] == pytest.approx(10e-6)
    assert excl["tracking"] == pytest.approx(50e-6)


@pytest.mark.slow
def test_a_cpu_run_through_the_profile_writes_its_tables(tmp_path: Path) -> None:
    proc = subprocess.run(
        [sys.executable, str(REPO / "profiling" / "gpu_profile.py"), "--out", str(tmp_path / "prof"), "--",
         "+experiment=tiny", "max_frames=4", "threads=1", "eval.lpips=false"],
        cwd=REPO, text=True, capture_output=True, timeout=600,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-3000:]
    rows = {r["phase"]: r for r in csv.DictReader((tmp_path / "prof" / "profile_phases.csv").open())}
    assert {"tracking", "mapping", "load", "evaluation"} <= set(rows)
    assert float(rows["tracking"]["wall_s"]) > 0 and int(rows["tracking"]["host_syncs"]) > 0  # item() on a CPU too
    summary = json.loads((tmp_path / "prof" / "profile_summary.json").read_text())
    assert summary["metrics"]["status"] == "ok" and summary["metrics"]["fps_slam"] > 0
