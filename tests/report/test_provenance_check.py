"""``bench.report --study`` refuses runs from a dirty tree or a foreign commit; ``--allow-dirty`` stamps the report."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import pandas as pd
import pytest

from bench.errors import ReportError
from bench.report import provenance_check
from bench.report.__main__ import main as report

REPO = Path(__file__).resolve().parents[2]
HEAD = subprocess.run(["git", "rev-parse", "HEAD"], cwd=REPO, capture_output=True, text=True).stdout.strip()


def _full_history() -> bool:
    """Whether REPO is a git checkout with its whole history (the commits the committed runs name)."""
    out = subprocess.run(["git", "rev-parse", "--is-shallow-repository"], cwd=REPO, capture_output=True, text=True)
    return out.returncode == 0 and out.stdout.strip() == "false"


NEEDS_HISTORY = pytest.mark.skipif(not _full_history(), reason="needs a git checkout with its full history")
pytestmark = pytest.mark.skipif(not HEAD, reason="needs a git checkout: runs are checked against its history")
STUDY = """\
# @package _global_
sweep_name: study_prov
hydra:
  sweeper:
    study:
      report: {out: reports/prov}
      sweeps:
        prov_none: ["+strategy=none", "seed=0,1"]
        prov_pocket: ["+strategy=pocket", "seed=0,1"]
"""


@pytest.fixture
def study(tmp_path, monkeypatch, make_run):
    """A user study whose four run dirs hold fabricated runs at HEAD; ``set_runs`` changes their provenance."""
    from bench.sweep.study import load

    (tmp_path / "conf" / "study").mkdir(parents=True)
    (tmp_path / "conf" / "study" / "prov.yaml").write_text(STUDY)
    monkeypatch.chdir(tmp_path)
    _, jobs = load("prov")
    for job in jobs:
        strategy = "pocket" if "pocket" in job.sweep else "none"
        seed = int(next(o for o in job.overrides if o.startswith("seed=")).split("=")[1])
        make_run(job.run_dir, strategy=strategy, seq="06", seed=seed)

    def set_runs(dirty: int = 0, foreign: int = 0) -> None:
        for i, job in enumerate(jobs):
            path = job.run_dir / "metrics.json"
            doc = json.loads(path.read_text())
            doc["provenance"]["git_dirty"] = i < dirty
            doc["provenance"]["git_commit"] = "0" * 40 if len(jobs) - i <= foreign else HEAD
            path.write_text(json.dumps(doc))

    set_runs()
    return tmp_path, set_runs


def test_clean_runs_report_without_a_stamp(study, capsys):
    tmp_path, _ = study
    assert report(["--study", "prov"]) == 0
    assert "Provenance" not in (tmp_path / "reports" / "prov" / "tables.md").read_text()


def test_dirty_runs_are_refused_in_one_line(study, capsys):
    tmp_path, set_runs = study
    set_runs(dirty=3)
    assert report(["--study", "prov"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("error: study 'prov': expected runs from a clean tree")
    assert "found 3 of 4 made with uncommitted changes and 0 at a commit not in its history" in err
    assert "prov_none" in err and "--allow-dirty" in err
    assert not (tmp_path / "reports" / "prov").exists()  # refused before anything was written


def test_runs_at_a_foreign_commit_are_refused(study, capsys):
    _, set_runs = study
    set_runs(foreign=1)
    assert report(["--study", "prov"]) == 2
    assert "found 0 of 4 made with uncommitted changes and 1 at a commit not in its history" in capsys.readouterr().err


def test_allow_dirty_stamps_every_table_and_the_readme(study, capsys):
    tmp_path, set_runs = study
    out = tmp_path / "reports" / "prov"
    out.mkdir(parents=True)
    (out / "README.md").write_text("# Prov\n\nThe answer.\n")
    set_runs(dirty=3)
    assert report(["--study", "prov", "--allow-dirty"]) == 0
    stamp = "made from runs with uncommitted changes: 3 of 4"
    assert stamp in capsys.readouterr().err
    readme = (out / "README.md").read_text()
    assert readme.startswith(f"# Prov\n\n{provenance_check.STAMP_BEGIN}\n**Provenance: {stamp}**")
    assert readme.endswith("The answer.\n")
    assert stamp in (out / "tables.md").read_text().splitlines()[1]
    tex = sorted(out.glob("*.tex"))
    assert tex and all(p.read_text().startswith(f"% provenance: {stamp}\n") for p in tex)
    set_runs()  # the runs made again from a clean tree: the stamp goes
    assert report(["--study", "prov"]) == 0
    assert (out / "README.md").read_text() == "# Prov\n\nThe answer.\n"
    assert "Provenance" not in (out / "tables.md").read_text()


def test_plain_run_dirs_are_reported_as_before(study, capsys):
    tmp_path, set_runs = study
    set_runs(dirty=4)
    assert report([str(tmp_path / "multirun"), "--out", str(tmp_path / "plain")]) == 0
    assert "Provenance" not in (tmp_path / "plain" / "tables.md").read_text()


def test_provenance_reads_runs_csv():
    runs = pd.DataFrame(
        {
            "path": ["a", "b", "c", "d"],
            "git_dirty": [True, False, "True", None],
            "git_commit": [HEAD, HEAD, "f" * 40, None],
        }
    )
    prov = provenance_check.provenance(runs)
    assert prov.dirty == ("a", "c") and prov.foreign == ("c", "d")
    assert provenance_check.stamp_text(prov) == (
        "made from runs with uncommitted changes: 2 of 4; "
        "made from runs at a commit not in this repository's history: 2 of 4"
    )
    with pytest.raises(ReportError, match="found 2 of 4 made with uncommitted changes and 2 at"):
        provenance_check.check("x", runs, allow_dirty=False)


COMMITTED = sorted(p.parent for p in (REPO / "reports").glob("*/runs.csv"))


@NEEDS_HISTORY
@pytest.mark.parametrize("folder", COMMITTED, ids=lambda p: p.name)
def test_every_committed_report_carries_the_stamp_its_runs_give(folder):
    runs = pd.read_csv(folder / "runs.csv", low_memory=False)
    expected = provenance_check.stamp_text(provenance_check.provenance(runs))
    assert provenance_check.stamp_of(folder) == expected, f"run: python -m bench.report.committed {folder}"
    for tex in folder.glob("*.tex"):
        assert tex.read_text().startswith(f"% provenance: {expected}\n") == (expected is not None)
