"""reports/README.md is generated (bench/report/index.py) and lists every folder under reports/."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

from bench.errors import ReportError
from bench.report import index
from bench.report.__main__ import main as report

REPO = Path(__file__).resolve().parents[2]
REPORTS = REPO / "reports"


def _full_history() -> bool:
    """Whether REPO is a git checkout with its whole history (the commits the committed runs name)."""
    out = subprocess.run(["git", "rev-parse", "--is-shallow-repository"], cwd=REPO, capture_output=True, text=True)
    return out.returncode == 0 and out.stdout.strip() == "false"


NEEDS_HISTORY = pytest.mark.skipif(not _full_history(), reason="needs a git checkout with its full history")


@NEEDS_HISTORY  # the index dates each folder's runs by their commits
def test_the_committed_index_is_what_the_generator_makes():
    assert (REPORTS / "README.md").read_text(encoding="utf-8") == index.render(REPORTS), (
        "reports/README.md is stale: run python -m bench.report --index"
    )


def test_every_folder_has_an_entry():
    text = (REPORTS / "README.md").read_text(encoding="utf-8")
    for folder in index.folders(REPORTS):
        assert f"## [{folder.name}/]({folder.name}/README.md): " in text, f"no index entry for reports/{folder.name}"


def _copy(tmp_path: Path, *names: str) -> Path:
    root = tmp_path / "reports"
    for name in names:
        shutil.copytree(REPORTS / name, root / name)
    return root


def test_a_new_folder_without_a_readme_fails_the_index(tmp_path):
    root = _copy(tmp_path, "noise")
    (root / "new_study").mkdir()
    with pytest.raises(ReportError, match="expected a README.md in '.*new_study'") as caught:
        index.render(root, REPO / "conf" / "study")
    assert "\n" not in str(caught.value)


def test_a_readme_without_an_answer_fails_the_index(tmp_path):
    root = _copy(tmp_path, "noise")
    readme = root / "noise" / "README.md"
    readme.write_text(readme.read_text().replace("**Answer.**", "Answer:"))
    with pytest.raises(ReportError, match=r"expected an \*\*Answer\.\*\* paragraph for the index"):
        index.render(root, REPO / "conf" / "study")


@NEEDS_HISTORY
def test_an_entry_reads_the_folder(tmp_path, monkeypatch):
    root = _copy(tmp_path, "noise", "gpu", "criteria")
    monkeypatch.chdir(tmp_path)
    assert report(["--index"]) == 0
    text = (root / "README.md").read_text()
    assert "## [noise/](noise/README.md): none against pocket" in text
    assert "- **Runs.** 6 in `runs.csv`, at dd5bd5f (" in text
    assert "- **Provenance.** made from runs with uncommitted changes: 2 of 6." in text
    assert "- **Answer.** On ATE and PSNR yes (p = 0.017 and 0.003)," in text  # claims taken out
    assert "- **Runs.** 4 in `runs.csv`, at abd6fac (" in text  # gpu/: a check's runs, brought back from the GPU
    assert "- **Recorded.** 2026-11-26 at fe65fab (no committed runs" in text  # criteria/: a script's record
    assert "- **Study.** `conf/study/noise.yaml`" not in text  # no conf/study beside this copy
