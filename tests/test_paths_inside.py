"""Paths that stay inside (issue 62, M): sweep and study names are names, run files are not written through a
planted symlink, a study file holds only what a study needs; and ``inf`` is refused in accurate words."""

from __future__ import annotations

from pathlib import Path

import pytest

from bench.errors import ConfigError
from bench.run.record import write_text
from bench.run.rows import FlushedRows
from tests.test_bad_input import run_cli
from tests.test_faults import call, one_line


@pytest.mark.parametrize("name", ["../../x", "/tmp/x", "a/b", ".."])
def test_a_sweep_name_that_is_a_path_is_refused_before_any_dir(name: str, tmp_path: Path, monkeypatch) -> None:
    work = tmp_path / "a" / "b"
    work.mkdir(parents=True)
    monkeypatch.chdir(work)
    got = run_cli(["-m", "+experiment=tiny", "seed=0,1", f"sweep_name={name}"])
    assert got.code == 2
    assert f"sweep_name: expected a name (one folder: no '/', not '.' or '..'), found '{name}'" in got.error_line
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["a", "b"]  # nothing written, inside or out


STUDIES = {
    "sweep-path": (
        "hydra:\n  sweeper:\n    study:\n      sweeps: {'../../x': [seed=0]}\n",
        "study 'bad' sweep name: expected a name (one folder: no '/', not '.' or '..'), found '../../x'",
    ),
    "sweep-name-path": (
        "sweep_name: /tmp/x\nhydra:\n  sweeper:\n    study:\n      sweeps: {a: [seed=0]}\n",
        "study 'bad' sweep_name: expected a name",
    ),
    "callbacks": (
        "hydra:\n  callbacks:\n    evil: {_target_: os.system, command: 'touch pwned'}\n"
        "  sweeper:\n    study:\n      sweeps: {a: [seed=0]}\n",
        "hydra: expected only sweeper, found callbacks",
    ),
    "target": (
        "_target_: os.system\nhydra:\n  sweeper:\n    study:\n      sweeps: {a: [seed=0]}\n",
        "keys: expected only defaults, sweep_name, hydra, found _target_",
    ),
    "run-setting": (
        "seed: 3\nhydra:\n  sweeper:\n    study:\n      sweeps: {a: [seed=0]}\n",
        "keys: expected only defaults, sweep_name, hydra, found seed",
    ),
    "defaults": (
        "defaults:\n  - override /hydra/job_logging: none\n"
        "hydra:\n  sweeper:\n    study:\n      sweeps: {a: [seed=0]}\n",
        "defaults: expected 'override /hydra/launcher: NAME' only",
    ),
    "hydra-override": (
        "hydra:\n  sweeper:\n    study:\n      sweeps: {a: [seed=0, 'hydra.callbacks.x._target_=os.getcwd']}\n",
        "sweep 'a': expected run settings, found 'hydra.callbacks.x._target_=os.getcwd'",
    ),
    "target-node": (
        "hydra:\n  sweeper:\n    study:\n      sweeps: {a: [seed=0, '+slam.x._target_=os.getcwd']}\n",
        "sweep 'a': expected run settings, found '+slam.x._target_=os.getcwd'",
    ),
}


def test_a_setting_named_like_target_is_a_run_setting() -> None:
    """prune.n_target_per_mpx holds "_target_" in its name, not as a node: the regime study sets it."""
    from bench.sweep.study import load

    assert any("prune.n_target_per_mpx=166223" in o for o in load("regime")[0].sweeps["regime_7scenes_pair"])


@pytest.mark.parametrize("case", sorted(STUDIES))
def test_a_study_file_holds_only_what_a_study_needs(case: str, tmp_path: Path, monkeypatch, capsys) -> None:
    from bench.sweep.study import main

    text, says = STUDIES[case]
    (tmp_path / "conf" / "study").mkdir(parents=True)
    (tmp_path / "conf" / "study" / "bad.yaml").write_text("# @package _global_\n" + text)
    monkeypatch.chdir(tmp_path)
    assert says in one_line(call(main, ["bad"], capsys))
    assert says in one_line(run_cli(["--multirun", "+study=bad"]))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["conf"]  # no multirun/, no pwned


def test_a_study_name_is_a_name(tmp_path: Path, monkeypatch, capsys) -> None:
    from bench.sweep.study import main

    monkeypatch.chdir(tmp_path)
    assert "study: expected a name" in one_line(call(main, ["../study/x"], capsys))


def test_a_symlink_planted_in_a_fresh_run_dir_is_refused_and_its_target_untouched(tmp_path: Path) -> None:
    victim = tmp_path / "victim.txt"
    victim.write_text("precious\n")
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    (run_dir / "keyframes.csv").symlink_to(victim)
    got = run_cli(["+experiment=tiny", "max_frames=2", f"hydra.run.dir={run_dir}"])
    assert got.code == 2
    assert f"run file {run_dir / 'keyframes.csv'}: expected a file the run writes itself, found a symlink to" in (
        got.error_line
    )
    assert victim.read_text() == "precious\n"
    assert sorted(p.name for p in run_dir.iterdir()) == ["keyframes.csv"]


def test_run_files_are_not_written_through_a_link(tmp_path: Path) -> None:
    victim = tmp_path / "victim.txt"
    victim.write_text("precious\n")
    rows = tmp_path / "rows.csv"
    rows.symlink_to(victim)
    with pytest.raises(ConfigError, match="found a symlink to"), FlushedRows(rows, ["a"], append=True):
        pass
    (tmp_path / "metrics.json.tmp").symlink_to(victim)  # where the atomic write makes its temporary file
    write_text(tmp_path / "metrics.json", "{}")
    assert (tmp_path / "metrics.json").read_text() == "{}" and victim.read_text() == "precious\n"


def test_inf_is_refused_as_not_finite(tmp_path: Path) -> None:
    got = run_cli(["+experiment=tiny", "dataset.speed_m_per_frame=inf", f"hydra.run.dir={tmp_path / 'run'}"])
    assert got.code == 2
    assert got.error_line.endswith("speed_m_per_frame: expected a finite number (a number > 0), found inf"), (
        got.error_line
    )
