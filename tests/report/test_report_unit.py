"""A report folder is replaced as a unit (issue 62, K): a smaller report over a larger one leaves none of the old
one's files, a stopped report leaves the old folder byte for byte, and Ctrl-C / SIGTERM is one line."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from bench.report.__main__ import main
from bench.run.signals import Interrupted
from tests.report.conftest import write_run

REPO = Path(__file__).resolve().parents[2]


def _runs(root: Path, n: int) -> Path:
    """``n`` finished runs: two strategies over sequences and datasets, so each adds tables and figures."""
    places = [("kitti", "06"), ("kitti", "04"), ("synthetic", "0"), ("euroc", "V1_01_micro")]
    for i in range(n):
        dataset, seq = places[(i // 2) % len(places)]
        write_run(root / f"r{i}", strategy=("none", "pocket")[i % 2], seq=seq, dataset=dataset)
    return root


def _tree(path: Path) -> dict[str, bytes]:
    return {str(p.relative_to(path)): p.read_bytes() for p in sorted(path.rglob("*")) if p.is_file()}


def _report(runs: Path, out: Path, capsys) -> tuple[int, str, str]:
    code = main([str(runs), "--out", str(out)])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def test_a_smaller_report_over_a_larger_one_leaves_only_its_own_files(tmp_path: Path, capsys) -> None:
    out = tmp_path / "report"
    assert _report(_runs(tmp_path / "six", 6), out, capsys)[0] == 0
    old = set(_tree(out))
    (out / "README.md").write_text("notes a person wrote beside the report\n")
    (out / "extra").mkdir()
    (out / "extra" / "cost_table.py").write_text("print(1)\n")
    code, stdout, _ = _report(_runs(tmp_path / "two", 2), out, capsys)
    assert code == 0
    new = set(_tree(out))
    written = int(stdout.split("wrote ")[1].split(" files")[0])
    assert len(new) == written + 2  # the report's own files, and what the person put there
    assert {"README.md", "extra/cost_table.py"} <= new and (out / "README.md").read_text().startswith("notes")
    assert old - new, "the six-run report's own files should be gone"
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []  # no temporary folder left


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_a_report_stopped_part_way_leaves_the_old_folder_as_it_was(tmp_path: Path, capsys, monkeypatch, sig) -> None:
    out = tmp_path / "report"
    assert _report(_runs(tmp_path / "six", 6), out, capsys)[0] == 0
    before = _tree(out)
    import bench.report.build as build

    def stopped(*args, **kwargs):
        raise Interrupted(sig)  # as the signal handler raises it, after the tables are written

    monkeypatch.setattr(build, "make_plots", stopped)
    code, _, stderr = _report(_runs(tmp_path / "two", 2), out, capsys)
    assert code == 128 + sig
    assert stderr == f"error: interrupted by {sig.name}; {out} left as it was\n"
    assert _tree(out) == before
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []


@pytest.mark.slow
def test_sigterm_to_a_report_process_is_one_line_and_changes_nothing(tmp_path: Path) -> None:
    out = tmp_path / "report"
    runs = _runs(tmp_path / "six", 6)
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    cmd = [sys.executable, "-m", "bench.report", str(runs), "--out", str(out), "--format", "png,pdf,svg"]
    subprocess.run(cmd, env=env, check=True, capture_output=True, timeout=600)
    before = _tree(out)
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 300
    while not any(p.name.startswith(".report.building-") and any(p.iterdir()) for p in tmp_path.iterdir()):
        assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
        time.sleep(0.01)
    proc.send_signal(signal.SIGTERM)
    _, stderr = proc.communicate(timeout=300)
    assert proc.returncode == 143, stderr
    assert stderr.strip().splitlines()[-1] == f"error: interrupted by SIGTERM; {out} left as it was"
    assert "Traceback" not in stderr
    assert _tree(out) == before
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []
