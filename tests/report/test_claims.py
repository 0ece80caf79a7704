"""The READMEs under reports/ print figures their committed data give (bench/report/claims.py)."""

from __future__ import annotations

import itertools
import shutil
from pathlib import Path

import pandas as pd
import pytest

from bench.errors import ReportError
from bench.report import claims

REPO = Path(__file__).resolve().parents[2]
REPORTS = REPO / "reports"
READMES = claims.readmes(REPORTS)


@pytest.mark.parametrize("readme", READMES, ids=lambda p: str(p.relative_to(REPORTS)))
def test_every_claimed_figure_is_what_its_data_give(readme):
    assert claims.check_file(readme) == []


def test_every_report_folder_with_data_has_claims():
    folders = [p.parent for p in REPORTS.glob("*/runs.csv") if (p.parent / "README.md").is_file()]
    assert folders
    bare = [f.name for f in folders if not claims.parse(f / "README.md")]
    assert bare == [], f"READMEs with data and no claim: {bare}"


def _memory_copy(tmp_path: Path) -> Path:
    """reports/memory/README.md beside a copy of every folder's runs.csv (its claims read other folders' too)."""
    for runs in REPORTS.glob("*/runs.csv"):
        (tmp_path / runs.parent.name).mkdir()
        shutil.copy(runs, tmp_path / runs.parent.name / "runs.csv")
    readme = tmp_path / "memory" / "README.md"
    shutil.copy(REPORTS / "memory" / "README.md", readme)
    return readme


def test_a_figure_changed_by_hand_fails(tmp_path):
    """The audit's slip (Welch p = 0.69 where the data give 0.66) put back by hand."""
    readme = _memory_copy(tmp_path)
    assert claims.check_file(readme) == []
    text = readme.read_text(encoding="utf-8")
    assert text.count("Welch p = 0.66<!--") == 1
    readme.write_text(text.replace("Welch p = 0.66<!--", "Welch p = 0.69<!--"), encoding="utf-8")
    problems = claims.check_file(readme)
    assert len(problems) == 1
    assert "printed 0.69, the data give 0.66" in problems[0]
    assert claims.main([str(readme)]) == 1


def test_data_changed_under_a_figure_fails(tmp_path):
    readme = _memory_copy(tmp_path)
    runs = pd.read_csv(readme.parent / "runs.csv", low_memory=False)
    runs.loc[runs["path"].str.contains("memory_mix_none/"), "peak_mem_mib"] *= 2
    runs.to_csv(readme.parent / "runs.csv", index=False)
    assert any("printed x0.21" in p or "printed 0.21" in p for p in claims.check_file(readme))


def _one_claim(tmp_path: Path, line: str) -> Path:
    pd.DataFrame({"strategy": ["none", "none", "pocket", "pocket"], "peak_mem_mib": [10.0, 12.0, 7.0, 8.0]}).to_csv(
        tmp_path / "runs.csv", index=False
    )
    readme = tmp_path / "README.md"
    readme.write_text(f"# t\n\n{line}\n", encoding="utf-8")
    return readme


@pytest.mark.parametrize(
    ("line", "expected"),
    [
        (
            "peak 11.0 MiB<!-- claim: {csv: runs.csv, where: \"strategy == 'none'\", col: peak_mem_mib, stat: mean, "
            "round: 1} -->",
            [],
        ),
        (
            "a x0.68<!-- claim: {csv: runs.csv, where: \"strategy == 'pocket'\", vs: \"strategy == 'none'\", "
            "col: peak_mem_mib, stat: ratio, round: 2} --> peak",
            [],
        ),
        ("from 7-8<!-- claim: {csv: runs.csv, col: peak_mem_mib, stat: min, round: 0} --> MiB", ["printed 8"]),
        (
            "−3.5<!-- claim: {csv: runs.csv, where: \"strategy == 'pocket'\", vs: \"strategy == 'none'\", "
            "col: peak_mem_mib, stat: diff, round: 1} --> MiB",
            [],
        ),
        ("4<!-- claim: {csv: runs.csv, col: peak_mem_mib, stat: count, round: 0} --> runs", []),
    ],
)
def test_figures_are_read_as_printed(tmp_path, line, expected):
    problems = claims.check_file(_one_claim(tmp_path, line))
    assert len(problems) == len(expected)
    for problem, text in zip(problems, expected, strict=True):
        assert text in problem


@pytest.mark.parametrize(
    ("line", "message"),
    [
        ("1.0<!-- claim: {csv: runs.csv, col: peak_mem_mib, stat: mode, round: 1} -->", "expected a stat among"),
        ("1.0<!-- claim: {csv: runs.csv, col: peak_mem_mib, stat: mean} -->", "expected claim keys"),
        ("1.0<!-- claim: {csv: runs.csv, col: peak_mem_mib, stat: ratio, round: 1} -->", "expected 'vs'"),
        ("none<!-- claim: {csv: runs.csv, col: peak_mem_mib, stat: mean, round: 1} -->", "expected a figure"),
        ("1.0<!-- claim: {csv: other.csv, col: peak_mem_mib, stat: mean, round: 1} -->", "found no such file"),
        ("1.0<!-- claim: {csv: runs.csv, col: fps, stat: mean, round: 1} -->", "expected a column 'fps'"),
        (
            '1.0<!-- claim: {csv: runs.csv, where: "seed == 3", col: peak_mem_mib, stat: mean, round: 1} -->',
            "cannot select rows",
        ),
    ],
)
def test_a_bad_claim_is_one_line(tmp_path, line, message):
    with pytest.raises(ReportError, match=message) as caught:
        claims.check_file(_one_claim(tmp_path, line))
    assert "\n" not in str(caught.value)
    assert "README.md:3" in str(caught.value)


def _run_sets() -> dict[str, pd.DataFrame]:
    return {p.parent.name: pd.read_csv(p, low_memory=False) for p in sorted(REPORTS.glob("*/runs.csv"))}


def test_folders_that_share_run_dirs_but_not_runs_say_so():
    """Two folders that list one run dir made at two commits (or configs) hold different runs: each README says so."""
    runs = _run_sets()
    for a, b in itertools.combinations(runs, 2):
        both = runs[a].merge(runs[b], on="path", suffixes=("_a", "_b"))
        if both.empty:
            continue
        same = (both["config_hash_a"] == both["config_hash_b"]) & (both["git_commit_a"] == both["git_commit_b"])
        if same.all():
            continue
        for name, other in ((a, b), (b, a)):
            readme = REPORTS / name / "README.md"
            if readme.is_file():
                text = readme.read_text(encoding="utf-8")
                assert f"<!-- other runs: {other} -->" in text, f"{name}/README.md: runs of {other}'s dirs, not said"
