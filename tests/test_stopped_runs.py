"""Runs stopped part-way keep what they computed: signals, a corrupt frame, a killed process, a changed input.

Each case is a real ``python -m bench`` process on the smallest run that reaches the frame loop
(``+experiment=tiny``, a few frames, one thread). The signal is sent once the trajectory file
holds three tracked frames, so ATE is defined on the frames done.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from bench.report.collect import read_run

REPO = Path(__file__).resolve().parents[1]
TINY = ["+experiment=tiny", "threads=1", "eval.lpips=false"]


def _env() -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(REPO)}  # this checkout's bench, wherever the process runs


def start(args: list[str], cwd: Path) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "bench", *args],
        cwd=cwd,
        env=_env(),
        text=True,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )


def run(args: list[str], cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "bench", *args], cwd=cwd, env=_env(), text=True, capture_output=True, timeout=600
    )


def tracked(run_dir: Path) -> int:
    try:
        return sum(1 for ln in (run_dir / "traj_est.txt").read_text().splitlines() if not ln.startswith("#"))
    except OSError:
        return 0


def wait_for_frames(proc: subprocess.Popen, run_dir: Path, n: int, timeout_s: float = 540) -> None:
    deadline = time.monotonic() + timeout_s
    while tracked(run_dir) < n:
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline, "the run did not reach the frame loop"
        time.sleep(0.2)


def one_error_line(stderr: str) -> str:
    lines = [ln for ln in stderr.splitlines() if ln.startswith("error:")]
    assert len(lines) == 1 and "Traceback" not in stderr, stderr
    return lines[0]


@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_signal_ends_the_run_as_interrupted_with_partial_metrics(sig: signal.Signals, tmp_path: Path) -> None:
    run_dir = tmp_path / "run"
    proc = start([*TINY, f"hydra.run.dir={run_dir}"], tmp_path)
    wait_for_frames(proc, run_dir, 3)
    proc.send_signal(sig)
    _, stderr = proc.communicate(timeout=300)
    assert proc.returncode == 128 + sig, stderr
    line = one_error_line(stderr)
    record = json.loads((run_dir / "metrics.json").read_text())
    n = record["metrics"]["num_frames"]
    assert line == f"error: interrupted by {sig.name} after {n} frames; partial results in {run_dir}"
    assert record["status"] == "interrupted" and record["error"] == f"interrupted by {sig.name} after {n} frames"
    m = record["metrics"]
    assert n >= 3 and tracked(run_dir) == n  # every tracked frame is on disk
    assert m["ate_num_poses"] == n and m["ate_rmse_m"] > 0 and m["num_keyframes"] >= 1
    assert m["slam_wall_s"] > 0 and m["peak_mem_mib"] > 0 and m["gaussians_final"] > 0
    assert m["psnr_db"] is None  # no rendering after a stop
    assert "owner" not in record
    assert (run_dir / "keyframes.csv").read_text().count("\n") == 1 + m["num_keyframes"]
    assert read_run(run_dir)["status"] == "interrupted"


@pytest.mark.slow
def test_killed_run_is_reported_interrupted_by_the_next_run(tmp_path: Path) -> None:
    run_dir = tmp_path / "run"
    proc = start([*TINY, f"hydra.run.dir={run_dir}"], tmp_path)
    wait_for_frames(proc, run_dir, 2)
    proc.kill()
    proc.communicate()
    left = json.loads((run_dir / "metrics.json").read_text())
    assert left["status"] == "running" and left["owner"]["pid"] == proc.pid
    assert read_run(run_dir)["status"] == "interrupted"  # the report sees through the leftover
    again = run([*TINY, "max_frames=2", "slam.refine_iters=0", "eval.every=1", f"hydra.run.dir={run_dir}"], tmp_path)
    assert again.returncode == 0, again.stderr
    assert f"{run_dir}: the previous run was killed while running (pid {proc.pid}); recorded as interrupted" in (
        again.stdout + again.stderr
    )
    # another config: its checkpoint does not fit, so the run starts over (tests/test_checkpoint.py resumes one)
    assert f"redoing {run_dir}: its checkpoint was not used: checkpoint.pt is foreign: config changed" in again.stdout
    assert "starting over from frame 0" in again.stdout
    assert json.loads((run_dir / "metrics.json").read_text())["status"] == "ok"


def _tree(run_dir: Path) -> dict[str, bytes]:
    """Every file of the run dir but a redo's staging dir and the lock of the process at work there, by path."""
    return {
        str(p.relative_to(run_dir)): p.read_bytes()
        for p in sorted(run_dir.rglob("*"))
        if p.is_file() and ".redo" not in p.relative_to(run_dir).parts and p.name != ".pocketbench.lock"
    }


@pytest.mark.slow
def test_a_redo_replaces_a_finished_run_only_when_it_finishes(tmp_path: Path) -> None:
    """A redo of a finished run (another config, or new code, in the same dir) works in the dir's
    ``.redo/``: stopped part-way, it leaves the finished run's files byte for byte; finished, its
    files replace the old ones, leftovers of the old run included."""
    run_dir = tmp_path / "run"
    first = run([*TINY, "max_frames=4", f"hydra.run.dir={run_dir}"], tmp_path)
    assert first.returncode == 0, first.stderr
    (run_dir / "stale_from_old_run.txt").write_text("x")
    finished = _tree(run_dir)
    redo = [*TINY, "max_frames=40", f"hydra.run.dir={run_dir}"]
    proc = start(redo, tmp_path)
    wait_for_frames(proc, run_dir / ".redo", 3)
    assert _tree(run_dir) == finished  # at work: the finished run untouched, cli.log and .hydra/ included
    proc.send_signal(signal.SIGINT)
    _, stderr = proc.communicate(timeout=300)
    assert proc.returncode == 128 + signal.SIGINT, stderr
    assert f"partial results in {run_dir / '.redo'}" in one_error_line(stderr)
    assert _tree(run_dir) == finished  # stopped: still the finished run
    assert json.loads((run_dir / ".redo" / "metrics.json").read_text())["status"] == "interrupted"
    assert read_run(run_dir)["status"] == "ok"
    done = run([*redo[:-2], "max_frames=6", redo[-1]], tmp_path)  # another redo, which finishes
    assert done.returncode == 0, done.stderr
    record = json.loads((run_dir / "metrics.json").read_text())
    assert record["status"] == "ok" and record["metrics"]["num_frames"] == 6
    assert not (run_dir / ".redo").exists() and not (run_dir / "stale_from_old_run.txt").exists()
    assert tracked(run_dir) == 6 and "max_frames=6" in (run_dir / ".hydra" / "overrides.yaml").read_text()


def _kitti_args(root: Path, tmp_path: Path) -> list[str]:
    # not +experiment=tiny: its dataset.width/height are synthetic-only settings
    return [
        "threads=1",
        "eval.lpips=false",
        "slam.mapping_iters=30",
        "dataset=kitti",
        "seq=6",
        f"dataset.root={root}",
        "dataset.downscale=8",
        f"dataset.cache_dir={tmp_path / 'cache'}",
        "slam.refine_iters=0",
        "eval.every=5",
    ]


@pytest.mark.slow
def test_corrupt_frame_mid_run_keeps_the_partial_record_as_failed(make_kitti_copy, tmp_path: Path) -> None:
    root = make_kitti_copy(6)
    bad = root / "sequences" / "06" / "image_0" / "000003.png"
    bad.unlink()
    bad.write_bytes(b"\x89PNG\r\n\x1a\n" + b"\x00" * 40)
    run_dir = tmp_path / "run"
    proc = run([*_kitti_args(root, tmp_path), f"hydra.run.dir={run_dir}"], tmp_path)
    assert proc.returncode == 2, proc.stderr
    line = one_error_line(proc.stderr)
    record = json.loads((run_dir / "metrics.json").read_text())
    assert record["status"] == "failed" and line == f"error: {record['error']}"
    assert "image unreadable" in line and "000003.png" in line and line.endswith("(after 3 frames)")
    m = record["metrics"]
    assert m["num_frames"] == 3 and tracked(run_dir) == 3 and m["ate_num_poses"] == 3 and m["num_keyframes"] >= 1
    assert record["run"]["seq"] == "06"  # seq=6 is recorded under its one name


@pytest.mark.slow
def test_rerun_after_an_input_file_changed_is_redone_and_says_why(make_kitti_copy, tmp_path: Path) -> None:
    root = make_kitti_copy(6)
    args = [*_kitti_args(root, tmp_path), "max_frames=3", "hydra.run.dir=" + str(tmp_path / "run")]
    first = run(args, tmp_path)
    assert first.returncode == 0, first.stderr
    again = run(args, tmp_path)
    assert "skipping" in again.stdout and again.returncode == 0
    times = root / "sequences" / "06" / "times.txt"
    times.write_text(times.read_text().replace("0.000000e+00", "1.000000e-06", 1))
    third = run(args, tmp_path)
    assert third.returncode == 0, third.stderr
    assert f"redoing {tmp_path / 'run'}: input files changed: sequences/06/times.txt" in third.stdout
    shutil.rmtree(tmp_path / "cache", ignore_errors=True)


def test_the_report_leaves_a_redos_staging_dir_out(tmp_path: Path) -> None:
    from bench.report.collect import find_run_dirs

    for d in (tmp_path / "a", tmp_path / "a" / ".redo"):
        d.mkdir(parents=True)
        (d / "metrics.json").write_text("{}")
    assert find_run_dirs([tmp_path]) == [tmp_path / "a"]


def test_a_signal_reported_as_an_extensions_own_error_is_still_a_stop() -> None:
    """A signal that lands while numba runs Python code of its own (its unpickler inside a jitted call)
    comes back as ``SystemError`` with the ``Interrupted`` as its cause: the run is stopped, not failed."""
    from bench.run.signals import Interrupted, signal_behind

    stop = Interrupted(signal.SIGTERM)
    try:
        try:
            raise stop
        except Interrupted as inner:
            raise SystemError(
                "CPUDispatcher(<function tile_schedule>) returned a result with an exception set"
            ) from inner
    except SystemError as exc:
        assert signal_behind(exc) is stop
    assert signal_behind(RuntimeError("a real bug")) is None
    assert signal_behind(stop) is stop


def test_a_stop_during_the_image_metrics_keeps_what_the_run_computed(tmp_path: Path, monkeypatch) -> None:
    """Scoring images takes minutes at full resolution (float64 SSIM on the CPU): a stop there must not
    throw away the frame rate, memory, map size and ATE that the run already has."""
    from hydra import compose, initialize_config_dir

    import bench.metrics.protocol as protocol
    from bench.cli.entry import CONF_DIR
    from bench.run.lifecycle import run as run_in_process
    from bench.run.signals import Interrupted

    def stopped(*args, **kwargs):
        raise Interrupted(signal.SIGTERM)

    monkeypatch.setattr(protocol, "frame_metrics", stopped)
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        cfg = compose(config_name="config", overrides=["+experiment=tiny", "dataset.n_frames=4", "progress=false"])
    with pytest.raises(Interrupted):
        run_in_process(cfg, out_dir=tmp_path)
    stored = json.loads((tmp_path / "metrics.json").read_text())
    m = stored["metrics"]
    assert stored["status"] == "interrupted"
    assert m["num_frames"] == 4
    for key in ("fps", "slam_wall_s", "gaussians_final", "peak_mem_mib", "ate_rmse_m", "path_length_ratio"):
        assert m.get(key) is not None, key
    assert m.get("psnr_db") is None  # never computed
