"""``python -m bench.report``: known failures are one line and exit 2; success prints a summary."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from bench.report.__main__ import main

REPO = Path(__file__).resolve().parents[2]


def run_cli(*args: str | Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "bench.report", *map(str, args)], cwd=REPO, capture_output=True, text=True, timeout=60
    )


def test_empty_dir_is_one_line_exit_2(tmp_path: Path) -> None:
    proc = run_cli(tmp_path, "--out", tmp_path / "out")
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr
    assert proc.stderr.strip().count("\n") == 0
    assert proc.stderr.startswith("error: no run dirs found")
    assert not (tmp_path / "out").exists()


def test_only_malformed_runs_is_one_line_exit_2(tmp_path: Path) -> None:
    (tmp_path / "0").mkdir()
    (tmp_path / "0" / "metrics.json").write_text("{not json")
    proc = run_cli(tmp_path, "--out", tmp_path / "out")
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr
    assert proc.stderr.strip().count("\n") == 0
    assert str(tmp_path / "0" / "metrics.json") in proc.stderr


def test_success_prints_summary_and_warnings(tmp_path: Path, make_run, capsys: pytest.CaptureFixture[str]) -> None:
    make_run(tmp_path / "sweep" / "0", strategy="none", seq="00")
    make_run(tmp_path / "sweep" / "1", strategy="pocket", seq="00")
    (tmp_path / "sweep" / "2").mkdir()
    (tmp_path / "sweep" / "2" / "metrics.json").write_text("{}")
    out = tmp_path / "reports" / "smoke"
    assert main([str(tmp_path / "sweep"), "--out", str(out), "--paper"]) == 0
    captured = capsys.readouterr()
    assert "2 runs, 1 malformed skipped" in captured.out
    assert "warning: skipped malformed run" in captured.err
    assert (out / "runs.csv").is_file() and (out / "tables.md").is_file()
    assert "(paper) Ours" in (out / "tables.md").read_text()
