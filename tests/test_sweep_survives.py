"""Sweep summaries that survive (issue 62, C and D): the summary sits in the sweep dir whatever the override
values hold, a job that raises is recorded failed while the sweep goes on, and an empty sweep says so."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tests.test_bad_input import run_cli

TINY = ["+experiment=tiny", "threads=1", "eval.lpips=false", "max_frames=2"]


def _route(path: Path) -> Path:
    """A straight route along the ground (KITTI pose lines), enough poses for the tiny scene."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("".join(f"1 0 0 0 0 1 0 0 0 0 1 {0.1 * i:.1f}\n" for i in range(20)))
    return path


def test_a_value_with_a_slash_leaves_the_summary_in_the_sweep_dir(tmp_path: Path) -> None:
    a, b = _route(tmp_path / "routes" / "a.txt"), _route(tmp_path / "routes" / "b.txt")
    sweep = tmp_path / "sweep"
    got = run_cli(["-m", *TINY, f"dataset.route_file={a},{b}", f"hydra.sweep.dir={sweep}"])
    assert got.code == 0, got.stderr
    summaries = sorted(sweep.rglob("summary.md"))
    assert summaries == [sweep / "summary.md"], summaries
    assert "2 jobs: 2 ok" in summaries[0].read_text()
    assert not (sweep / ".pocketbench_jobs.jsonl").exists()


def test_a_job_that_raises_is_recorded_failed_and_the_sweep_goes_on(tmp_path: Path, monkeypatch) -> None:
    import bench.run.lifecycle as lifecycle

    real = lifecycle._run_locked

    def buggy(cfg, out, built):
        if built.config.seed == 1:
            raise RuntimeError("a bug in job 1")
        return real(cfg, out, built)

    monkeypatch.setattr(lifecycle, "_run_locked", buggy)
    sweep = tmp_path / "sweep"
    got = run_cli(["-m", *TINY, "seed=0,1,2", f"hydra.sweep.dir={sweep}"])
    assert got.code == 0, got.stderr
    assert "error: job 1 raised RuntimeError: a bug in job 1 (a bug; traceback above); the sweep goes on" in got.stderr
    assert "sweep: 3/3 runs done" in got.stderr
    summary = (sweep / "summary.md").read_text()
    assert "3 jobs: 2 ok, 1 failed" in summary, summary
    statuses = sorted(json.loads(p.read_text())["status"] for p in sweep.rglob("metrics.json"))
    assert statuses == ["ok", "ok"]  # job 1 raised before its record: the summary holds its failure


@pytest.mark.parametrize("sweep_arg", ["seed=range(0,0)", "seed=range(3,3)"])
def test_an_empty_sweep_says_so_and_leaves_nothing(sweep_arg: str, tmp_path: Path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    got = run_cli(["-m", "+experiment=tiny", sweep_arg])
    assert got.code == 2
    assert got.error_line == f"error: sweep: expected at least one job, found none ({sweep_arg} is empty)"
    assert list(tmp_path.iterdir()) == []
