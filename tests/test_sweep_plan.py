"""A sweep's jobs, planned once (issue 40, classes B, C and D).

B: two jobs that differ in any setting never share a run dir, a setting left out of dir names
included. C: the summary and the progress line account for every planned job, a job that cannot
be composed and a study's jobs included. D: a bad setting every job shares is refused before the
sweep, in one line, with no dir.

The sweeps run through the CLI in this process with ``bench.run.lifecycle.run`` replaced by a stand-in that
validates the job as a run does and writes an ``ok`` record: what is tested is where each job
writes and what the sweep says about it, not the SLAM run.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from bench.cli import entry as cli
from bench.errors import ConfigError
from tests.test_bad_input import run_cli

# two values for every key Hydra leaves out of a sweep job's dir name (hydra.* keys cannot be swept)
LEFT_OUT_VALUES = {
    "sweep_name": "a,b",
    "progress": "true,false",
    "resume": "true,false",
    "checkpoint.every": "1,2",
    "checkpoint.keep": "1,2",
    "dataset.root": "/data/a,/data/b",
}


@pytest.fixture
def runs(monkeypatch: pytest.MonkeyPatch) -> list[Path]:
    """Replace the SLAM run by a stand-in; returns the run dirs it was given, in order."""
    from bench.run import lifecycle as run_module
    from bench.run.validate import validate

    dirs: list[Path] = []

    def fake_run(cfg, out_dir=None, built=None):
        out = Path(out_dir).resolve()
        dirs.append(out)
        try:
            validate(cfg)
        except ConfigError as exc:
            return run_module._refused(out, str(exc), {})
        out.mkdir(parents=True, exist_ok=True)
        metrics = {"fps": float(len(dirs))}
        (out / "metrics.json").write_text(json.dumps({"status": "ok", "error": None, "metrics": metrics}))
        return run_module.RunResult("ok", out, metrics)

    monkeypatch.setattr(run_module, "run", fake_run)
    return dirs


def table_rows(stdout: str) -> list[list[str]]:
    rows = [ln for ln in stdout.splitlines() if ln.startswith("|")][2:]
    return [[c.strip() for c in ln.strip("|").split("|")] for ln in rows]


def test_every_left_out_key_is_covered() -> None:
    """A key added to exclude_keys needs a pair of values here, so the test below covers it."""
    od = cli.compose([], hydra=True).hydra.job.config.override_dirname
    assert {k for k in od.exclude_keys if not k.startswith("hydra.")} == set(LEFT_OUT_VALUES)


@pytest.mark.parametrize("key", sorted(LEFT_OUT_VALUES))
def test_jobs_that_differ_in_a_left_out_key_get_their_own_dirs(key: str, tmp_path: Path, runs: list[Path]) -> None:
    on = ["dataset=kitti"] if key.startswith("dataset.") else ["+experiment=tiny"]  # a dataset with a root
    res = run_cli(["--multirun", *on, f"{key}={LEFT_OUT_VALUES[key]}", f"hydra.sweep.dir={tmp_path}"])
    assert res.code == 0, res.stderr
    assert len(runs) == 2 and len(set(runs)) == 2, runs
    assert all(d.parent == tmp_path.resolve() for d in runs), runs  # one level below the sweep dir, a path too
    assert [r[1] for r in table_rows(res.stdout)] == ["ok", "ok"]
    assert len({r[0] for r in table_rows(res.stdout)}) == 2  # the summary tells the jobs apart


def test_a_failed_job_does_not_overwrite_a_sibling_that_differs_in_a_left_out_key(
    tmp_path: Path, runs: list[Path]
) -> None:
    """``checkpoint.every=2,-1,0``: three dirs; the refused middle job leaves the first job's record."""
    res = run_cli(["--multirun", "+experiment=tiny", "checkpoint.every=2,-1,0", f"hydra.sweep.dir={tmp_path}"])
    assert res.code == 0, res.stderr
    assert len(set(runs)) == 3
    status = [json.loads((d / "metrics.json").read_text())["status"] for d in runs]
    assert status == ["ok", "failed", "ok"]
    assert [r[:2] for r in table_rows(res.stdout)] == [
        ["checkpoint.every=2", "ok"],
        ["checkpoint.every=-1", "failed"],
        ["checkpoint.every=0", "ok"],
    ]


def test_identical_jobs_keep_hydras_dir_name(tmp_path: Path, runs: list[Path]) -> None:
    res = run_cli(["--multirun", "+experiment=tiny", "seed=0,1", "progress=false", f"hydra.sweep.dir={tmp_path}"])
    assert res.code == 0, res.stderr
    assert [d.name for d in runs] == ["+experiment=tiny,seed=0", "+experiment=tiny,seed=1"]


def test_summary_and_progress_count_a_job_that_cannot_be_composed(tmp_path: Path, runs: list[Path]) -> None:
    res = run_cli(["--multirun", "+experiment=tiny", "seed=0,abc,1", f"hydra.sweep.dir={tmp_path}"])
    assert res.code == 0, res.stderr
    progress = [ln.split(" runs done")[0] for ln in res.stderr.splitlines() if ln.startswith("sweep: ")]
    assert progress == ["sweep: 1/3", "sweep: 2/3", "sweep: 3/3"], res.stderr
    assert [r[:2] for r in table_rows(res.stdout)] == [["seed=0", "ok"], ["seed=abc", "failed"], ["seed=1", "ok"]]
    summary = (tmp_path / "summary.md").read_text()
    assert "3 jobs: 2 ok, 1 failed" in summary and "| seed=abc " in summary


def test_jobs_keep_their_numbers_when_one_before_them_is_refused(tmp_path: Path, runs: list[Path]) -> None:
    """With a subdir by job number, the refused job's record and a later job's run never share a dir."""
    res = run_cli(
        [
            "--multirun",
            "+experiment=tiny",
            "seed=abc,0",
            f"hydra.sweep.dir={tmp_path}",
            "hydra.sweep.subdir=${hydra.job.num}",
        ]
    )
    assert res.code == 0, res.stderr
    assert runs == [tmp_path.resolve() / "1"]
    assert json.loads((tmp_path / "0" / "metrics.json").read_text())["status"] == "failed"


STUDY = """# @package _global_
hydra:
  sweeper:
    study:
      sweeps:
        plan_a: ["seed=0,1", progress=false]
        plan_b: ["seed=0", progress=false]
"""


def test_a_study_sweep_lists_every_job(tmp_path: Path, runs: list[Path], monkeypatch: pytest.MonkeyPatch) -> None:
    (tmp_path / "conf" / "study").mkdir(parents=True)
    (tmp_path / "conf" / "study" / "plan.yaml").write_text(STUDY)
    monkeypatch.chdir(tmp_path)
    res = run_cli(["--multirun", "+study=plan", "+experiment=tiny"])
    assert res.code == 0, res.stderr
    progress = [ln.split(" runs done")[0] for ln in res.stderr.splitlines() if ln.startswith("sweep: ")]
    assert progress == ["sweep: 1/3", "sweep: 2/3", "sweep: 3/3"], res.stderr
    rows = table_rows(res.stdout)
    assert [r[1] for r in rows] == ["ok", "ok", "ok"] and len({r[0] for r in rows}) == 3, res.stdout
    assert [d.parent.name for d in runs] == ["plan_a", "plan_a", "plan_b"]
    assert "2 jobs: 2 ok" in (tmp_path / "multirun" / "plan_a" / "summary.md").read_text()
    assert "1 job: 1 ok" in (tmp_path / "multirun" / "plan_b" / "summary.md").read_text()


@pytest.mark.parametrize(
    ("args", "says"),
    [
        (["+experiment=tiny", "threads=0", "seed=0,1"], "threads: expected an integer >= 1 or null, found 0"),
        (["+study=nonexistent"], "unknown study 'nonexistent': expected a file conf/study/nonexistent.yaml"),
        (["+experiment=tiny", "dataset.route_file=/no/such/route.txt", "seed=0,1"], "dataset.route_file: expected"),
    ],
)
def test_a_bad_setting_every_job_shares_is_refused_before_the_sweep(
    args: list[str], says: str, tmp_path: Path, runs: list[Path]
) -> None:
    res = run_cli(["--multirun", *args, f"hydra.sweep.dir={tmp_path}/sweep"])
    assert res.code == 2, res.stderr
    assert res.stderr.strip() == res.error_line and says in res.error_line
    assert not (tmp_path / "sweep").exists() and runs == []


def test_a_job_whose_dir_name_is_too_long_for_the_file_system_gets_a_short_one(
    tmp_path: Path, runs: list[Path]
) -> None:
    """Many settings name a dir longer than the 255 bytes a file name may hold: the job still runs, in a
    dir of its own whose name is the long name cut and a hash of the whole, the same on every rerun."""
    from bench.sweep.plan import NAME_MAX_BYTES

    milestones = "eval.at_frames=[" + ",".join(str(n) for n in range(3, 102)) + "]"  # 300 bytes in the name
    args = ["--multirun", "+experiment=tiny", "seed=0,1", milestones, f"hydra.sweep.dir={tmp_path}"]
    res = run_cli(args)
    assert res.code == 0, res.stderr
    assert len(runs) == 2 and len(set(runs)) == 2, runs
    for d in runs:
        assert len(d.name.encode()) <= NAME_MAX_BYTES and "~" in d.name, d.name
        assert d.parent == tmp_path.resolve() and (d / "metrics.json").is_file()
    first = list(runs)
    runs.clear()
    assert run_cli(args).code == 0
    assert runs == first  # the same dirs on a rerun


def test_a_rerun_refused_for_every_job_says_the_dirs_keep_their_runs(
    tmp_path: Path, runs: list[Path], monkeypatch: pytest.MonkeyPatch
) -> None:
    """A sweep rerun whose every job is refused before any work (data briefly unreachable, say) leaves
    the finished runs in their dirs, and its summary says so instead of listing them as failed runs."""
    from bench.run import lifecycle as run_module

    argv = ["--multirun", "+experiment=tiny", "seed=0,1", f"hydra.sweep.dir={tmp_path}"]
    assert run_cli(argv).code == 0
    first = list(runs)

    def refuse(cfg, out_dir=None, built=None):
        return run_module._refused(Path(out_dir).resolve(), "dataset root: expected a directory, found none", {})

    monkeypatch.setattr(run_module, "run", refuse)
    res = run_cli(argv)
    assert res.code == 0, res.stderr
    assert [json.loads((d / "metrics.json").read_text())["status"] for d in first] == ["ok", "ok"]
    assert [r[:2] for r in table_rows(res.stdout)] == [
        ["seed=0", "failed (keeps its ok run)"],
        ["seed=1", "failed (keeps its ok run)"],
    ]
    assert "2 jobs: 2 failed (keeps its ok run)" in (tmp_path / "summary.md").read_text()
