"""Studies by name (``conf/study/NAME.yaml``) and a user's ``./conf`` searched ahead of the package.

Each committed study file must list exactly the runs behind its report folder's ``runs.csv``: the
same run dirs, strategies, presets, seeds and harness settings. A mini study in a temporary
``./conf`` runs end to end through the CLI, resumes, and writes its report folder.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import pandas as pd
import pytest
import yaml

from bench.cli import entry as cli
from bench.config.settings import plain
from bench.names import synthetic_drive
from bench.report.settings import SETTING_KEYS, _lookup
from bench.run.config import to_run_config
from bench.run.identity import run_keys
from bench.sweep.study import load

REPO = Path(__file__).resolve().parents[1]
STUDIES = sorted(p.stem for p in (REPO / "conf" / "study").glob("*.yaml"))
KEYS = ("strategy", "dataset", "seq", "seed", "keep_ratio", "slam_preset")


@pytest.fixture
def at_repo(monkeypatch: pytest.MonkeyPatch) -> Path:
    monkeypatch.chdir(REPO)  # ./conf is found in the current directory, as a user runs it
    return REPO


def _planned(name: str) -> bool:
    """A study committed before its runs (``report: {planned: true}``): it has no report folder yet."""
    return bool(load(name)[0].report.get("planned"))


def test_every_report_folder_has_a_study():
    folders = sorted(p.parent.name for p in (REPO / "reports").glob("*/runs.csv"))
    assert [s for s in STUDIES if not _planned(s)] == folders
    for name in STUDIES:
        if _planned(name):
            assert not (REPO / "reports" / name / "runs.csv").exists(), f"{name} has its runs: drop planned"


def _same(expected: object, found: object) -> bool:
    """A runs.csv cell (read as text) against a composed value."""
    if expected is None or (isinstance(expected, float) and math.isnan(expected)):
        return True  # not recorded (a report from before runs recorded their settings)
    if isinstance(found, bool):
        return str(expected).lower() == str(found).lower()
    if isinstance(found, (int, float)):
        return float(expected) == float(found)
    return str(expected) == str(found)


def _run_key(path: str | Path) -> tuple[str, ...]:
    """A run dir by its parts below ``multirun/`` (sweep dir, run dir). An override value with a slash
    (``dataset.route_file=datasets/routes/kitti_06.txt``) nests the run dir one level deeper, so the
    last two parts alone would name several runs alike."""
    parts = Path(path).parts
    return parts[parts.index("multirun") + 1 :] if "multirun" in parts else parts[-2:]


def _recorded(name: str) -> tuple[list, dict[tuple[str, str], dict]]:
    """The study's runs, and its report's runs.csv rows by run dir (sweep dir name, run dir name)."""
    study, jobs = load(name)
    if study.report.get("planned"):
        pytest.skip(f"study {name} is planned: no report folder yet")
    runs = pd.read_csv(REPO / study.report["out"] / "runs.csv", dtype=str, keep_default_na=False)
    rows = [{k: (v if v != "" else None) for k, v in row.items()} for row in runs.to_dict("records")]
    return jobs, {_run_key(row["path"]): row for row in rows}


@pytest.mark.parametrize("name", STUDIES)
def test_study_lists_exactly_the_run_dirs_of_its_report(name, at_repo):
    jobs, recorded = _recorded(name)
    assert sorted(_run_key(job.run_dir) for job in jobs) == sorted(recorded)  # none more, none less


@pytest.mark.slow
@pytest.mark.parametrize("name", STUDIES)
def test_study_runs_have_the_recorded_keys_and_settings(name, at_repo):
    """Each run as the study composes it today: the strategy, preset, seed and settings its report recorded."""
    jobs, recorded = _recorded(name)
    for job in jobs:
        row = recorded[_run_key(job.run_dir)]
        cfg = cli.compose(list(job.overrides))
        keys, tree = run_keys(to_run_config(cfg)), plain(cfg)
        if keys["dataset"] == "synthetic":  # the report names a synthetic drive by its route too
            route, route_file = _lookup(tree, "dataset.route"), _lookup(tree, "dataset.route_file")
            keys["seq"] = synthetic_drive(keys["seq"], route, route_file)
        for key in KEYS:
            if key == "keep_ratio" and (keys["strategy"] == "none" or keys["keep_ratio"] is None):
                continue  # unused without pruning or with an absolute target (older records wrote the ratio)
            assert _same(row[key], keys[key]), (job.run_dir, key, row[key], keys[key])
        for key in SETTING_KEYS:
            if key not in row:
                continue  # a setting column added after this table was recorded (max_frames)
            value = _lookup(tree, key)
            if key == "slam.raster_backend" and value == "auto":
                value = "auto (fused)"  # as the report writes it for a CPU run
            assert _same(row.get(key), value), (job.run_dir, key, row.get(key), value)


def _tiny(job_overrides: tuple[str, ...], kitti_root: Path | None) -> list[str]:
    """One study point at CI size: the synthetic scene through +experiment=tiny, a real one cut to 3 frames."""
    overrides = [o for o in job_overrides if not o.startswith(("threads=", "progress="))]
    small = [
        "threads=1",
        "progress=false",
        "eval.lpips=false",
        "slam.mapping_iters=4",
        "slam.tracking_iters=4",
        "slam.refine_iters=0",
    ]
    if kitti_root is not None:
        overrides = [f"dataset.root={kitti_root}" if o.startswith("dataset.root=") else o for o in overrides]
        return [*overrides, *small, "max_frames=3"]
    return ["+experiment=tiny", *overrides, *small, "dataset.n_frames=3"]


@pytest.mark.slow
@pytest.mark.parametrize("name", STUDIES)
def test_one_point_of_each_study_runs_at_tiny_size(name, at_repo, tmp_path, request):
    from bench.run.lifecycle import run

    _, jobs = load(name)
    job = jobs[0]
    real = next((o[8:] for o in job.overrides if o in ("dataset=kitti", "dataset=sevenscenes")), None)
    root = request.getfixturevalue("shared") / "data" / real if real else None  # skips without the data
    result = run(cli.compose(_tiny(job.overrides, root)), out_dir=tmp_path / "run")
    assert result.status == "ok", result.error


def _run_cli(args: list[str]) -> tuple[int, str]:
    from tests.test_bad_input import run_cli  # the CLI in this process, as the reliability matrix runs it

    res = run_cli(args)
    return res.code, res.stderr


MINI = """\
# @package _global_
sweep_name: study_mini
hydra:
  sweeper:
    study:
      report: {out: reports/mini}
      sweeps:
        mini_none: ["+strategy=none", "seed=0", progress=false]
        mini_pocket: ["+strategy=pocket", "seed=0", progress=false]
"""
TINY = [
    "+experiment=tiny",
    "dataset.n_frames=3",
    "slam.mapping_iters=2",
    "slam.tracking_iters=2",
    "slam.refine_iters=0",
    "eval.lpips=false",
    "threads=1",
]


@pytest.mark.slow
def test_a_user_study_in_conf_runs_resumes_and_reports(tmp_path, monkeypatch):
    """./conf/study/mini.yaml and ./conf/dataset/synthetic.yaml, no change to the package."""
    (tmp_path / "conf" / "study").mkdir(parents=True)
    (tmp_path / "conf" / "dataset").mkdir()
    (tmp_path / "conf" / "study" / "mini.yaml").write_text(MINI)
    shipped = (cli.CONF_DIR / "dataset" / "synthetic.yaml").read_text()
    (tmp_path / "conf" / "dataset" / "synthetic.yaml").write_text(shipped + "sway_m: 0.5\n")  # the user's own
    monkeypatch.chdir(tmp_path)
    code, err = _run_cli(["--multirun", "+study=mini", *TINY])
    assert code == 0, err
    dirs = {name: next((tmp_path / "multirun" / name).glob("*/metrics.json")) for name in ("mini_none", "mini_pocket")}
    for path in dirs.values():
        record = json.loads(path.read_text())
        assert record["status"] == "ok", record
        assert record["provenance"]["config_files"]["dataset"] == str(tmp_path / "conf" / "dataset" / "synthetic.yaml")
        assert "sway_m: 0.5" in (path.parent / "config.yaml").read_text()  # the user's file changed the run
    # named as Hydra's basic sweeper names a job of the same command line (bools as Python writes them)
    assert (
        dirs["mini_none"].parent.name == "+experiment=tiny,+strategy=none,dataset.n_frames=3,eval.lpips=False,"
        "seed=0,slam.mapping_iters=2,slam.refine_iters=0,slam.tracking_iters=2,threads=1"
    )
    stamp = {name: path.stat().st_mtime_ns for name, path in dirs.items()}
    code, err = _run_cli(["--multirun", "+study=mini", *TINY])  # again: both resumed, nothing rerun
    assert code == 0, err
    assert {name: path.stat().st_mtime_ns for name, path in dirs.items()} == stamp
    from bench.report.__main__ import main as report

    # the runs of the study as it ran, with the same overrides (--allow-dirty: a developer's tree may be dirty)
    assert report(["--study", "mini", "--allow-dirty", *TINY]) == 0
    written = pd.read_csv(tmp_path / "reports" / "mini" / "runs.csv")
    assert sorted(written["strategy"]) == ["none", "pocket"]


def test_the_launchers_settings_stay_out_of_a_studys_jobs():
    """``+study=NAME hydra.launcher.n_jobs=1``: a job is composed without the study file whose defaults chose the
    launcher, so the launcher's settings there named no setting and every job failed; they configure the multirun."""
    from omegaconf import OmegaConf

    from bench.sweep.plan import multirun_only, planned

    config = OmegaConf.create(
        {
            "sweep_name": "study_mini",
            "hydra": {
                "sweeper": {"study": yaml.safe_load(MINI)["hydra"]["sweeper"]["study"]},
                "sweep": {"dir": "multirun/${sweep_name}", "subdir": "${hydra:job.override_dirname}"},
                "job": {"config": {"override_dirname": {"exclude_keys": [], "item_sep": ",", "kv_sep": "="}}},
            },
        }
    )
    jobs = planned(config, ["+study=mini", "hydra.launcher.n_jobs=1", "seed=3", "hydra.sweeper.max_batch_size=2"])
    assert len(jobs) == 2
    for job in jobs:
        assert "seed=3" in job
        assert not [o for o in job if o.startswith(("hydra.launcher", "hydra.sweeper"))], job
    assert multirun_only("hydra/launcher=slurm") and multirun_only("hydra.launcher.n_jobs=1")
    assert not multirun_only("hydra.sweep.dir=x") and not multirun_only("hydra.launcher_x=1")
