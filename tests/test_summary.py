"""The end-of-run table, the sweep comparison table and the sweep progress record."""

from __future__ import annotations

import io
import json
import os
from pathlib import Path

from bench.measure.progress import Phase, format_duration
from bench.sweep.summary import (
    JOBS_ENV,
    JOBS_FILE,
    SweepSummary,
    record_job,
    run_table,
    sweep_table,
    varying_overrides,
)

METRICS = {
    "ate_rmse_m": 0.0917408946107419,
    "psnr_db": 23.613324956248807,
    "ssim": 0.81234,
    "lpips": None,
    "fps": 0.4123,
    "peak_mem_mib": 101.25,
    "peak_mem_source": "torch_live",
    "gaussians_peak": 5210,
    "gaussians_final": 5000,
    "slam_wall_s": 30.5,
    "refine_s": 12.25,
}


def test_run_table_is_aligned_with_units_and_short_numbers():
    lines = run_table("ok", Path("/runs/a"), METRICS, 75.0).splitlines()
    column = {ln.index(ln.split()[-1 if ln.split()[0] == "status" else 1]) for ln in lines[:2]}
    assert len(column) == 1  # values start at one offset
    offset = column.pop()
    values = {ln[:offset].strip(): ln[offset:] for ln in lines}
    assert values["status"] == "ok" and values["ATE"] == "0.0917 m" and values["PSNR"] == "23.61 dB"
    assert values["peak memory"] == "101.2 MiB (torch_live)"
    assert values["Gaussians"] == "5210 peak, 5000 final"
    assert "eval.lpips_weights" in values["LPIPS"]  # the notice names the setting that fixes it
    assert values["wall time"] == "1m15s (SLAM 30.5 s, refine 12.2 s)"
    assert values["run dir"] == "/runs/a"


def test_sweep_table_shows_only_the_swept_overrides():
    names = ["+strategy=none,dataset.n_frames=4,seed=0", "+strategy=pocket,dataset.n_frames=4,seed=0"]
    short, shared = varying_overrides(names)
    assert short == ["+strategy=none", "+strategy=pocket"]
    assert shared == ["dataset.n_frames=4", "seed=0"]
    jobs = [
        {"num": 1, "name": names[1], "status": "failed", "metrics": {}, "wall_s": None},
        {"num": 0, "name": names[0], "status": "ok", "metrics": METRICS, "wall_s": 61.0},
    ]
    table = sweep_table(jobs).splitlines()
    assert table[0].startswith("| run") and "ATE [m]" in table[0] and "peak [MiB]" in table[0]
    assert table[2].startswith("| +strategy=none ") and "0.0917" in table[2] and "1m01s" in table[2]
    assert table[3].startswith("| +strategy=pocket") and "failed" in table[3]
    assert len({len(ln) for ln in table}) == 1  # padded: every row as wide as the header


def test_sweep_progress_and_summary_file(tmp_path, monkeypatch):
    monkeypatch.delenv(JOBS_ENV, raising=False)
    cfg = _sweep_cfg(tmp_path, ["+strategy=none,pocket,area", "seed=0"])
    callback = SweepSummary()
    callback.on_multirun_start(cfg)
    line = record_job(
        tmp_path, {"num": 0, "name": "+strategy=none,seed=0", "status": "ok", "metrics": METRICS, "wall_s": 5.0}
    )
    assert line.startswith("sweep: 1/3 runs done in ") and "ETA" in line
    last = record_job(
        tmp_path, {"num": 2, "name": "+strategy=area,seed=0", "status": "lost", "metrics": {}, "wall_s": 4.0}
    )
    assert last.startswith("sweep: 2/3 runs done") and "ETA" in last
    callback.on_multirun_end(cfg)
    summary = (tmp_path / "summary.md").read_text()
    assert "3 jobs: 1 ok, 1 not run, 1 lost" in summary and "`seed=0`" in summary
    assert "| +strategy=pocket | not run " in summary  # a planned job that never recorded is listed too
    assert not (tmp_path / JOBS_FILE).exists() and JOBS_ENV not in os.environ


def _sweep_cfg(sweep_dir: Path, task: list[str]):
    from omegaconf import OmegaConf, open_dict

    from bench.cli.entry import compose

    cfg = compose([], hydra=True)
    with open_dict(cfg):
        cfg.hydra.sweep.dir = str(sweep_dir)
        cfg.hydra.overrides.task = task
    OmegaConf.resolve(cfg.hydra.job)
    return cfg


def test_phase_prints_one_line_when_not_a_terminal():
    stream = io.StringIO()
    with Phase("refine", 3, "iteration", stream=stream) as phase:
        for _ in range(3):
            phase.update(1, gaussians=10)
    assert stream.getvalue().count("\n") == 1
    assert stream.getvalue().startswith("refine: 3/3 iterations in ") and "gaussians=10" in stream.getvalue()
    silent = io.StringIO()
    with Phase("frames", 2, "frame", enabled=False, stream=silent) as phase:
        phase.update(2)
    assert silent.getvalue() == ""


def test_format_duration():
    assert [format_duration(s) for s in (4.04, 75, 3725)] == ["4.0 s", "1m15s", "1h02m"]


def test_jobs_record_survives_a_cut_line(tmp_path):
    (tmp_path / JOBS_FILE).write_text(json.dumps({"start": 1.0, "total": 2}) + '\n{"num": 0, "sta')
    line = record_job(tmp_path, {"num": 1, "name": "x=1", "status": "ok", "metrics": {}, "wall_s": 1.0})
    assert line.startswith("sweep: 1/2 runs done")
