"""One writer per run dir: a second run into a dir a live process writes is refused in one line naming its pid.

The quick cases hold the dir's lock from a helper process, as a live run does; the slow one starts the
same command twice, as a user would.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from tests.test_bad_input import run_cli
from tests.test_stopped_runs import TINY, one_error_line, run, start, wait_for_frames

REPO = Path(__file__).resolve().parents[1]
HOLD = "import sys; from pathlib import Path; from bench.run.lock import run_dir_lock\n" \
    "with run_dir_lock(Path(sys.argv[1])):\n    print('held', flush=True); sys.stdin.read()\n"  # fmt: skip


def holder(run_dir: Path) -> subprocess.Popen:
    """A process that holds ``run_dir``'s lock until its stdin closes."""
    run_dir.mkdir(parents=True, exist_ok=True)
    proc = subprocess.Popen(
        [sys.executable, "-c", HOLD, str(run_dir)],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONPATH": str(REPO)},
    )
    assert proc.stdout is not None and proc.stdout.readline() == "held\n", proc.communicate()
    return proc


def release(proc: subprocess.Popen) -> None:
    proc.communicate("")


def test_a_run_into_a_dir_another_process_writes_is_refused_naming_it(tmp_path: Path) -> None:
    run_dir = tmp_path / "run"
    proc = holder(run_dir)
    try:
        before = sorted(p.name for p in run_dir.iterdir())
        got = run_cli([*TINY, f"hydra.run.dir={run_dir}"])
        after = sorted(p.name for p in run_dir.iterdir())
    finally:
        release(proc)
    assert got.code == 2
    assert f"found process {proc.pid} running in it" in got.error_line, got.stderr
    assert after == before and not (run_dir / "metrics.json").exists()  # nothing of its own written
    assert list(run_dir.iterdir()) == []  # the holder let go: no lock file left


def test_a_sweep_job_into_a_busy_dir_is_recorded_failed_and_the_sweep_goes_on(tmp_path: Path) -> None:
    sweep = tmp_path / "sweep"
    busy = sweep / "+experiment=tiny,eval.lpips=False,max_frames=2,seed=1,threads=1"  # Hydra's name of job 1
    proc = holder(busy)
    try:
        got = run_cli(["-m", *TINY, "max_frames=2", "seed=0,1", f"hydra.sweep.dir={sweep}"])
    finally:
        release(proc)
    assert got.code == 0, got.stderr
    assert f"found process {proc.pid} running in it" in got.stderr
    assert json.loads((sweep / busy.name.replace("seed=1", "seed=0") / "metrics.json").read_text())["status"] == "ok"
    assert not (busy / "metrics.json").exists()
    summary = (sweep / "summary.md").read_text()
    assert "2 jobs: 1 ok, 1 failed" in summary, summary


def test_a_lock_left_by_a_dead_process_is_taken_over(tmp_path: Path) -> None:
    run_dir = tmp_path / "run"
    proc = holder(run_dir)
    proc.kill()
    proc.communicate()
    (run_dir / ".pocketbench.lock").write_text(f"{proc.pid} here\n")  # as a killed holder leaves it
    got = run_cli([*TINY, "max_frames=2", f"hydra.run.dir={run_dir}"])
    assert got.code == 0, got.stderr
    assert json.loads((run_dir / "metrics.json").read_text())["status"] == "ok"
    assert not (run_dir / ".pocketbench.lock").exists()


@pytest.mark.slow
def test_the_same_command_twice_runs_once(tmp_path: Path) -> None:
    """The second start of a command whose first is still in its frame loop is refused; the first goes on."""
    run_dir = tmp_path / "run"
    args = [*TINY, "dataset.n_frames=2000", f"hydra.run.dir={run_dir}"]  # long enough to be alive throughout
    first = start(args, tmp_path)
    try:
        wait_for_frames(first, run_dir, 2)
        second = run(args, tmp_path)
        assert first.poll() is None  # still running when the second one gave up
        first.send_signal(signal.SIGINT)
        _, stderr = first.communicate(timeout=600)
    finally:
        first.kill()
    assert second.returncode == 2
    line = one_error_line(second.stderr)
    assert line.startswith(f"error: run dir {run_dir}: expected no other run writing there, found process {first.pid}")
    assert "redoing" not in second.stdout + second.stderr
    assert first.returncode == 130, stderr
    record = json.loads((run_dir / "metrics.json").read_text())
    assert record["status"] == "interrupted" and record["metrics"]["num_frames"] >= 2  # the first run's own record
    assert not (run_dir / ".pocketbench.lock").exists()
