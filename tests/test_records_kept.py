"""A refused run never touches a previous run's record (issue 40, class A).

A refusal for a passing reason (no CUDA on this node, a route file briefly missing or empty, a data
folder unreachable) used to replace a finished run's ``metrics.json`` by a ``failed`` one, and its
``config.yaml`` too; the finished run was then redone instead of skipped. These tests fake the
finished record (no SLAM run is needed to show it is kept) and run the CLI in this process.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tests.test_bad_input import run_cli

FINISHED = {
    "status": "ok",
    "error": None,
    "run": {"strategy": "none", "dataset": "synthetic", "seed": 0},
    "metrics": {"ate_rmse_m": 0.05},
    "provenance": {},
}


def finished_dir(path: Path, status: str = "ok") -> dict[str, bytes]:
    """A run dir holding a finished record and its config; returns the bytes of every file in it."""
    path.mkdir(parents=True)
    (path / "metrics.json").write_text(json.dumps({**FINISHED, "status": status}))
    (path / "config.yaml").write_text("seed: 0\n")
    (path / "keyframes.csv").write_text("kf,frame\n0,0\n")
    return {p.name: p.read_bytes() for p in path.iterdir()}


def files(path: Path) -> dict[str, bytes]:
    """Every file under the run dir, Hydra's log (``cli.log``) and ``.hydra/`` included: Hydra writes
    them only for a job that does work (``bench.run.job_outputs``)."""
    return {str(p.relative_to(path)): p.read_bytes() for p in sorted(path.rglob("*")) if p.is_file()}


@pytest.mark.parametrize("status", ["ok", "lost", "interrupted"])
@pytest.mark.parametrize("route", ["missing", "empty"])
def test_refused_run_keeps_the_previous_record(tmp_path: Path, status: str, route: str) -> None:
    run_dir = tmp_path / "run"
    before = finished_dir(run_dir, status)
    route_file = tmp_path / "route.txt"
    if route == "empty":
        route_file.write_text("")
    res = run_cli(["+experiment=tiny", f"dataset.route_file={route_file}", f"hydra.run.dir={run_dir}"])
    assert res.code == 2, res.stderr
    assert "route_file" in res.error_line
    if route == "empty":  # a missing file is a bad setting, refused before Hydra; an empty one, when opened
        assert f"keeps its {status} record" in res.error_line
    assert files(run_dir) == before  # metrics.json and config.yaml untouched, nothing added


def test_refused_run_in_a_fresh_dir_is_recorded_failed(tmp_path: Path) -> None:
    """Where no previous run left a record, the refusal is recorded as before (docs/cli.md, Errors)."""
    run_dir = tmp_path / "run"
    (tmp_path / "empty.txt").write_text("")
    res = run_cli(["+experiment=tiny", f"dataset.route_file={tmp_path}/empty.txt", f"hydra.run.dir={run_dir}"])
    assert res.code == 2
    record = json.loads((run_dir / "metrics.json").read_text())
    assert record["status"] == "failed" and f"error: {record['error']}" == res.error_line
    assert (run_dir / "config.yaml").is_file() and not list(run_dir.glob("*.tmp"))


def test_missing_device_is_a_bad_setting_refused_before_any_dir(tmp_path: Path, monkeypatch) -> None:
    """``device=cuda`` on a machine without CUDA is refused before Hydra makes a run dir."""
    import torch

    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    fresh, finished = tmp_path / "fresh", tmp_path / "finished"
    before = finished_dir(finished)
    for run_dir in (fresh, finished):
        res = run_cli(["+experiment=tiny", "device=cuda", f"hydra.run.dir={run_dir}"])
        assert res.code == 2 and "device 'cuda'" in res.error_line, res.stderr
        assert res.stderr.strip() == res.error_line
    assert not fresh.exists()
    assert files(finished) == before


def test_refused_sweep_job_keeps_the_finished_record(tmp_path: Path, monkeypatch) -> None:
    """A finished sweep rerun while its route file is empty (being rewritten): both finished runs are
    kept, each job says so in its one line, and the sweep goes on."""
    monkeypatch.chdir(tmp_path)  # a relative route file keeps the run dir names flat
    (tmp_path / "route.txt").write_text("")
    sweep = tmp_path / "sweep"
    dirs = {s: sweep / f"+experiment=tiny,dataset.route_file=route.txt,seed={s}" for s in (0, 1)}
    before = {s: finished_dir(d) for s, d in dirs.items()}
    res = run_cli(
        ["--multirun", "+experiment=tiny", "dataset.route_file=route.txt", "seed=0,1", f"hydra.sweep.dir={sweep}"]
    )
    assert "Traceback" not in res.stderr, res.stderr
    assert res.stderr.count("keeps its ok record") == 2, res.stderr
    for s, d in dirs.items():
        assert files(d) == before[s]


def test_skipped_rerun_leaves_the_finished_dir_byte_for_byte(tmp_path: Path) -> None:
    """A rerun whose finished results match is skipped and writes nothing: not its metrics, not
    Hydra's ``cli.log`` or ``.hydra/`` (which Hydra used to append to and rewrite at job start)."""
    run_dir = tmp_path / "run"
    args = ["+experiment=tiny", "max_frames=4", f"hydra.run.dir={run_dir}"]
    first = run_cli(args)
    assert first.code == 0, first.stderr
    done = files(run_dir)
    assert {".hydra/config.yaml", ".hydra/hydra.yaml", ".hydra/overrides.yaml", "cli.log"} <= set(done), sorted(done)
    assert b"max_frames=4" in done[".hydra/overrides.yaml"] and done["cli.log"].strip()
    again = run_cli(args)
    assert again.code == 0, again.stderr
    assert files(run_dir) == done


def test_a_run_that_works_writes_hydras_files(tmp_path: Path) -> None:
    """A job that records something keeps Hydra's files: its config as composed, and its log, the
    lines logged before it decided to work included."""
    run_dir = tmp_path / "run"
    (tmp_path / "empty.txt").write_text("")
    res = run_cli(["+experiment=tiny", f"dataset.route_file={tmp_path}/empty.txt", f"hydra.run.dir={run_dir}"])
    assert res.code == 2
    written = files(run_dir)
    assert "empty.txt" in written[".hydra/config.yaml"].decode()
    assert "empty.txt" in written[".hydra/overrides.yaml"].decode()
    assert {"metrics.json", "config.yaml", "cli.log", ".hydra/hydra.yaml"} <= set(written), sorted(written)
