"""Bad inputs and faults of issue 62's own round that needed a fix (each fails on c26b028)."""

from __future__ import annotations

import errno
from pathlib import Path

import pytest

from tests.test_bad_input import run_cli
from tests.test_faults import call, one_line

Q = ["+experiment=tiny", "threads=1", "eval.lpips=false", "max_frames=3"]


def test_a_study_override_naming_a_path_as_sweep_name_is_refused(tmp_path: Path, monkeypatch, capsys) -> None:
    from bench.sweep.study import main

    (tmp_path / "conf" / "study").mkdir(parents=True)
    (tmp_path / "conf" / "study" / "s.yaml").write_text(
        "# @package _global_\nhydra:\n  sweeper:\n    study:\n      sweeps: {a: [seed=0, 'sweep_name=../x']}\n"
    )
    monkeypatch.chdir(tmp_path)
    line = one_line(call(main, ["s"], capsys))
    assert "study 's' sweep 'a' sweep_name: expected a name (one folder: no '/', not '.' or '..'), found '../x'" in line
    line = one_line(call(main, ["s", "sweep_name=/tmp/y"], capsys))  # the command line's, over the study's
    assert "found '/tmp/y'" in line


@pytest.mark.parametrize("where", ["runs", "parent", "cwd"])
def test_a_report_out_that_holds_the_run_dirs_is_refused(where: str, tmp_path: Path, monkeypatch, capsys) -> None:
    from bench.report.__main__ import main
    from tests.report.conftest import write_run

    runs = tmp_path / "runs"
    write_run(runs / "a", strategy="none", seq="06")
    write_run(runs / "b", strategy="pocket", seq="06")
    monkeypatch.chdir(tmp_path)
    out = {"runs": runs, "parent": tmp_path, "cwd": Path(".")}[where]
    line = one_line(call(main, [str(runs), "--out", str(out)], capsys))
    assert line.startswith("error: --out: expected a report folder apart from the run dirs and the current dir")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["runs"]
    assert sorted(p.name for p in (runs / "a").iterdir()) == sorted(p.name for p in (runs / "b").iterdir())


@pytest.mark.parametrize("name", ["metrics.json", "config.yaml", "keyframes.csv", "map.ply"])
def test_a_directory_where_the_record_or_the_map_goes_is_refused_before_any_work(name: str, tmp_path: Path) -> None:
    run_dir = tmp_path / "run"
    (run_dir / name).mkdir(parents=True)
    got = run_cli([*Q, f"hydra.run.dir={run_dir}"])
    assert got.code == 2
    assert got.error_line == f"error: run dir {run_dir}: expected {name} to be a file or nothing, found a directory"
    assert sorted(p.name for p in run_dir.iterdir()) == [name]


def test_a_file_system_without_locks_runs_unguarded_with_a_warning(tmp_path: Path, monkeypatch, caplog) -> None:
    import fcntl

    from bench.run.lock import run_dir_lock

    def no_locks(fd: int, op: int) -> None:
        raise OSError(errno.ENOLCK, "No locks available")

    monkeypatch.setattr(fcntl, "flock", no_locks)
    with run_dir_lock(tmp_path):
        pass
    assert "the file system cannot lock it" in caplog.text
    assert list(tmp_path.iterdir()) == []


def test_a_png_with_bytes_after_its_end_is_still_read(tmp_path: Path) -> None:
    import cv2
    import numpy as np

    from bench.datasets.realio import read_image

    path = tmp_path / "f.png"
    cv2.imwrite(str(path), np.full((8, 8), 7, np.uint8))
    path.write_bytes(path.read_bytes() + b"\0" * 300)  # some writers pad a file
    assert read_image(path, "kitti", "gray").mean() == 7


def test_a_strategy_setting_without_a_strategy_is_one_line(tmp_path: Path) -> None:
    got = run_cli([*Q, "+strategy.params.area=analytic", f"hydra.run.dir={tmp_path / 'run'}"])
    assert got.code == 2
    assert got.error_line == (
        "error: strategy.params.area: expected +strategy=NAME first (strategy is not chosen, so it has no settings), "
        "found +strategy.params.area=analytic"
    )
    assert not (tmp_path / "run").exists()


def test_a_swept_strategy_setting_without_a_strategy_is_recorded_per_job(tmp_path: Path) -> None:
    sweep = tmp_path / "sweep"
    got = run_cli(["-m", *Q, "strategy.params.area=analytic,x", f"hydra.sweep.dir={sweep}"])
    assert got.code == 0, got.stderr
    assert "2 jobs: 2 failed" in (sweep / "summary.md").read_text()
