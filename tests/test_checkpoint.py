"""Checkpoints and resume: a run SIGKILLed anywhere and rerun ends exactly as a run never stopped.

The end-to-end cases are real ``python -m bench`` processes at ``+experiment=tiny`` size, one thread.
A run stops itself at a known frame through the test-only ``POCKETBENCH_TEST_SIGNAL_AT``, read by
``tests/hooks/sitecustomize.py`` (it fires only in a run that started at frame 0, so the resumed run
goes through). Where the checkpoints are
is read from the uninterrupted run's ``keyframes.csv``, so the kill points do not depend on how many
keyframes the tiny drive happens to make.
"""

from __future__ import annotations

import csv
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from bench.errors import ConfigError
from bench.run import checkpoint as ckpt
from bench.run.checkpoint import CheckpointConfig
from bench.run.determinism import VOLATILE_KEYFRAME_COLUMNS, VOLATILE_METRICS, repeatable_metrics

REPO = Path(__file__).resolve().parents[1]
HOOKS = Path(__file__).resolve().parent / "hooks"  # its sitecustomize sends the signal
TEST_SIGNAL_ENV = "POCKETBENCH_TEST_SIGNAL_AT"
EVERY = 2  # keyframes between checkpoints: leaves keyframes between two checkpoints to cut on resume
TINY = ["+experiment=tiny", "threads=1", "eval.lpips=false", "progress=false", f"checkpoint.every={EVERY}"]


def bench(args: list[str], cwd: Path, signal_at: str | None = None) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    env.pop(TEST_SIGNAL_ENV, None)
    if signal_at:
        env[TEST_SIGNAL_ENV] = signal_at
        env["PYTHONPATH"] = os.pathsep.join((str(HOOKS), str(REPO)))
    return subprocess.run(
        [sys.executable, "-m", "bench", *args], cwd=cwd, env=env, text=True, capture_output=True, timeout=900
    )


def keyframe_rows(run_dir: Path) -> list[dict[str, str]]:
    with open(run_dir / "keyframes.csv", newline="") as fh:
        return [{k: v for k, v in r.items() if k not in VOLATILE_KEYFRAME_COLUMNS} for r in csv.DictReader(fh)]


def same_results(run_dir: Path, reference: Path) -> None:
    got, want = (json.loads((d / "metrics.json").read_text()) for d in (run_dir, reference))
    assert got["status"] == want["status"] == "ok"
    assert repeatable_metrics(got["metrics"]) == repeatable_metrics(want["metrics"])
    assert keyframe_rows(run_dir) == keyframe_rows(reference)
    assert (run_dir / "traj_est.txt").read_text() == (reference / "traj_est.txt").read_text()


@pytest.fixture(scope="module")
def references(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """One uninterrupted tiny run per strategy (checkpoints written as in the stopped runs)."""
    out = {}
    for strategy in ("none", "pocket"):
        run_dir = tmp_path_factory.mktemp("ref") / strategy
        proc = bench([*TINY, f"+strategy={strategy}", f"hydra.run.dir={run_dir}"], run_dir.parent)
        assert proc.returncode == 0, proc.stderr[-3000:]
        assert not ckpt.exists(run_dir), "a finished run keeps no checkpoint"
        out[strategy] = run_dir
    return out


def checkpoint_frames(reference: Path) -> list[int]:
    """Frames after which the run wrote a checkpoint (every EVERY-th keyframe)."""
    return [int(r["frame"]) for r in keyframe_rows(reference) if (int(r["kf"]) + 1) % EVERY == 0]


@pytest.mark.slow
@pytest.mark.parametrize("where", ["between", "after"])
@pytest.mark.parametrize("strategy", ["none", "pocket"])
def test_sigkilled_run_resumes_to_the_same_results(
    strategy: str, where: str, references: dict[str, Path], tmp_path: Path
) -> None:
    ref = references[strategy]
    at = checkpoint_frames(ref)
    assert len(at) >= 2, f"the tiny drive needs two checkpoints, found them after frames {at}"
    kill = at[1] - 1 if where == "between" else at[0]  # between: keyframes and frames after at[0] are cut
    run_dir = tmp_path / "run"
    args = [*TINY, f"+strategy={strategy}", f"hydra.run.dir={run_dir}"]
    killed = bench(args, tmp_path, signal_at=f"{kill}:KILL")
    assert killed.returncode == -9, killed.stderr[-3000:]
    assert json.loads((run_dir / "metrics.json").read_text())["status"] == "running"
    assert ckpt.data_rows(run_dir / "traj_est.txt", 1) == kill + 1  # rows past the checkpoint when between
    resumed = bench(args, tmp_path)
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    log = resumed.stdout + resumed.stderr
    assert f"resuming {run_dir} from frame {at[0] + 1} (checkpoint of keyframe {EVERY - 1})" in log, log[-3000:]
    same_results(run_dir, ref)
    record = json.loads((run_dir / "metrics.json").read_text())
    assert record["checkpoint"]["resumed_from_frames"] == [at[0] + 1]
    assert not ckpt.exists(run_dir)


@pytest.mark.slow
@pytest.mark.parametrize("bound", ["slam.keyframes.window=2", "slam.keyframes.submap_reset_m=2"])
def test_a_run_with_its_keyframe_store_on_disk_resumes_to_the_same_results(bound: str, tmp_path: Path) -> None:
    """The checkpoint holds the store by frame index (and the submap's first pose); the resume writes its
    files again from the sequence (those written after the checkpoint by the killed run go), and ends as
    the run never stopped."""
    disk = ["slam.keyframes.residency=disk", "slam.keyframes.precision=compact", bound]
    ref = tmp_path / "ref"
    done = bench([*TINY, *disk, f"hydra.run.dir={ref}"], tmp_path)
    assert done.returncode == 0, done.stderr[-3000:]
    assert not (ref / "keyframe_store").exists(), "a finished run removes its on-disk store"
    at = checkpoint_frames(ref)
    run_dir = tmp_path / "run"
    args = [*TINY, *disk, f"hydra.run.dir={run_dir}"]
    killed = bench(args, tmp_path, signal_at=f"{at[1] - 1}:KILL")  # keyframes after the checkpoint are on disk
    assert killed.returncode == -9, killed.stderr[-3000:]
    assert any((run_dir / "keyframe_store").iterdir())  # with a keyframe written past the checkpoint
    resumed = bench(args, tmp_path)
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    assert f"resuming {run_dir} from frame {at[0] + 1}" in resumed.stdout + resumed.stderr
    same_results(run_dir, ref)


@pytest.mark.slow
def test_corrupt_checkpoint_is_one_log_line_and_a_fresh_run(references: dict[str, Path], tmp_path: Path) -> None:
    run_dir = tmp_path / "run"
    args = [*TINY, "+strategy=none", f"hydra.run.dir={run_dir}", "checkpoint.keep=1"]
    kill = checkpoint_frames(references["none"])[0] + 1
    assert bench(args, tmp_path, signal_at=f"{kill}:KILL").returncode == -9
    path = run_dir / "checkpoint.pt"
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])  # truncated, as by a full disk
    again = bench(args, tmp_path)
    assert again.returncode == 0, again.stderr[-3000:]
    lines = [ln for ln in (again.stdout + again.stderr).splitlines() if "checkpoint" in ln.replace(str(tmp_path), "")]
    assert len(lines) == 1, lines
    why = "its checkpoint was not used: checkpoint.pt is unreadable (truncated or corrupt"
    assert f"redoing {run_dir}: {why}" in lines[0]
    assert lines[0].endswith("; starting over from frame 0")
    same_results(run_dir, references["none"])


@pytest.mark.slow
def test_preempted_submitit_job_checkpoints_is_requeued_and_resumes(
    references: dict[str, Path], tmp_path: Path
) -> None:
    """submitit_local sends the preemption signal (USR2) like SLURM: the job finishes its frame, writes
    a checkpoint, is requeued through the launcher's ``checkpoint()``, and the requeued job resumes."""
    preempt_at = checkpoint_frames(references["none"])[0] + 1  # not a checkpoint frame: the signal writes one
    sweep_dir = tmp_path / "sweep"
    args = [
        "--multirun",
        *TINY,
        "+strategy=none",
        "hydra/launcher=submitit_local",
        "hydra.launcher.timeout_min=10",
        f"hydra.sweep.dir={sweep_dir}",
    ]
    proc = bench(args, tmp_path, signal_at=f"{preempt_at}:USR2")
    assert proc.returncode == 0, proc.stderr[-3000:] + proc.stdout[-2000:]
    (run_dir,) = [p.parent for p in sweep_dir.glob("*/metrics.json")]
    logs = "".join(p.read_text(errors="replace") for p in (sweep_dir / ".submitit").rglob("*_log.*"))
    assert "preempted after" in logs and "Requeued job" in logs, logs[-3000:]
    assert f"resuming {run_dir} from frame {preempt_at + 1} (checkpoint of keyframe" in logs, logs[-3000:]
    same_results(run_dir, references["none"])


# ---------------------------------------------------------------------------------------------- unit


KEY = {"config_hash": "abc", "code_version": {"git_commit": "c0", "git_dirty": False}, "inputs": {"f": "1"}}


def _write(tmp_path: Path, **overrides) -> Path:
    payload = {
        "key": KEY,
        "frame": 4,
        "keyframe": 1,
        "system": {},
        "drive": {},
        "rng": {},
        "rows": {"traj": 4, "keyframes": 2},
        "stats": {},
        **overrides,
    }
    ckpt.save(tmp_path, payload, keep=1)
    return tmp_path / "checkpoint.pt"


ROWS = {"traj": 4, "keyframes": 2}


def test_find_accepts_a_matching_checkpoint(tmp_path: Path) -> None:
    _write(tmp_path)
    found, why = ckpt.find(tmp_path, KEY, ROWS)
    assert why == "" and found["frame"] == 4


@pytest.mark.parametrize(
    "damage, reason",
    [
        (lambda p: p.write_bytes(p.read_bytes()[:100]), "checkpoint.pt is unreadable (truncated or corrupt"),
        (lambda p: p.write_bytes(b"not a checkpoint"), "checkpoint.pt is unreadable (truncated or corrupt"),
        (lambda p: torch.save({"format": 0}, p), "checkpoint.pt has format 0, expected 2"),
        (lambda p: torch.save({"format": 1, "obj": object()}, p), "checkpoint.pt is unreadable"),  # not plain values
    ],
)
def test_find_refuses_a_damaged_checkpoint(damage, reason: str, tmp_path: Path) -> None:
    damage(_write(tmp_path))
    found, why = ckpt.find(tmp_path, KEY, ROWS)
    assert found is None and why.startswith(reason), why


@pytest.mark.parametrize(
    "key, reason",
    [
        ({**KEY, "config_hash": "other"}, "checkpoint.pt is foreign: config changed (hash abc -> other)"),
        (
            {**KEY, "code_version": {"git_commit": "c1", "git_dirty": False}},
            "checkpoint.pt is foreign: code version changed (c0 -> c1)",
        ),
        ({**KEY, "inputs": {"f": "2"}}, "checkpoint.pt is foreign: input files changed: f"),
    ],
)
def test_find_refuses_a_foreign_checkpoint(key: dict, reason: str, tmp_path: Path) -> None:
    _write(tmp_path)
    found, why = ckpt.find(tmp_path, key, ROWS)
    assert found is None and why == reason


def test_find_refuses_a_checkpoint_ahead_of_the_flushed_rows(tmp_path: Path) -> None:
    _write(tmp_path)
    found, why = ckpt.find(tmp_path, KEY, {"traj": 3, "keyframes": 2})
    assert found is None and why == "checkpoint.pt counts 4 traj rows but the run dir holds 3"


def test_a_bad_newest_checkpoint_falls_back_to_the_previous_one(tmp_path: Path) -> None:
    payload = {
        "key": KEY,
        "frame": 4,
        "keyframe": 1,
        "system": {},
        "drive": {},
        "rng": {},
        "rows": {"traj": 4, "keyframes": 2},
        "stats": {},
    }
    ckpt.save(tmp_path, payload)
    ckpt.save(tmp_path, {**payload, "frame": 7})
    assert {p.name for p in tmp_path.iterdir()} == {"checkpoint.pt", "checkpoint.prev.pt"}
    (tmp_path / "checkpoint.pt").write_bytes(b"\0" * 10)
    found, why = ckpt.find(tmp_path, KEY, ROWS)
    assert why == "" and found["frame"] == 4


def test_truncate_rows_keeps_the_header_and_the_counted_rows(tmp_path: Path) -> None:
    path = tmp_path / "t.txt"
    path.write_text("# header\n1\n2\n3\n4")  # the last row was cut mid-write
    assert ckpt.data_rows(path, 1) == 3
    ckpt.truncate_rows(path, 1, 2)
    assert path.read_text() == "# header\n1\n2\n"


def test_global_generators_round_trip(tmp_path: Path) -> None:
    import random

    import numpy as np

    state = ckpt.global_rng_state()
    torch.save(state, tmp_path / "rng.pt")
    want = (torch.rand(3), np.random.rand(3), random.random())
    ckpt.set_global_rng_state(torch.load(tmp_path / "rng.pt", weights_only=True))
    got = (torch.rand(3), np.random.rand(3), random.random())
    assert torch.equal(want[0], got[0]) and (want[1] == got[1]).all() and want[2] == got[2]


@pytest.mark.parametrize(
    "every, keep, message",
    [
        (-1, 2, "checkpoint.every: expected an integer >= 0, found -1"),
        (1, 3, "checkpoint.keep: expected an integer in [1, 2], found 3"),
    ],
)
def test_checkpoint_config_is_checked(every: int, keep: int, message: str) -> None:
    with pytest.raises(ConfigError, match=re.escape(message)):
        CheckpointConfig(every=every, keep=keep)


def test_the_docs_list_exactly_what_a_resume_may_change() -> None:
    """The fields the resume tests let differ are the ones docs/cli.md's "Checkpoints" names, no more."""
    text = " ".join((REPO / "docs" / "cli.md").read_text().split())
    said = re.search(r"memory peaks \(metrics `([^`]+)`; `keyframes.csv` `([^`]+)`", text)
    assert said, "docs/cli.md, Checkpoints: the list of what a resumed run may change is gone"
    assert set(said[1].split()) == VOLATILE_METRICS
    assert set(said[2].split()) == VOLATILE_KEYFRAME_COLUMNS


@pytest.mark.slow
def test_a_resumed_run_draws_the_pictures_of_keyframes_before_the_kill(
    references: dict[str, Path], tmp_path: Path
) -> None:
    at = checkpoint_frames(references["pocket"])
    run_dir = tmp_path / "run"
    args = [*TINY, "+strategy=pocket", "viz.pruning=true", "viz.every=1", f"hydra.run.dir={run_dir}"]
    assert bench(args, tmp_path, signal_at=f"{at[1] - 1}:KILL").returncode == -9
    assert not list(run_dir.glob("pruned_kf*.png")) and list(run_dir.glob("pruned_kf*.npz"))
    resumed = bench(args, tmp_path)
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    kfs = [int(r["kf"]) for r in keyframe_rows(references["pocket"]) if int(r["kf"]) > 0]
    assert sorted(p.name for p in run_dir.glob("pruned_kf*.png")) == [f"pruned_kf{k:03d}.png" for k in kfs]


@pytest.mark.slow
def test_a_run_with_map_residency_resumes_to_the_same_results(tmp_path: Path) -> None:
    """The Gaussians on disk at the checkpoint travel in it: killed after the checkpoint that follows an
    eviction, the run resumes (its map_store written again from the checkpoint) and ends as the run never
    stopped, the Gaussians brought back for the evaluation included."""
    args = [*TINY, "slam.residency.policy=distance", "slam.residency.distance_m=1.0"]
    ref = tmp_path / "ref"
    proc = bench([*args, f"hydra.run.dir={ref}"], tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    at = checkpoint_frames(ref)
    evicted = {int(r["frame"]): int(r["n_evicted"]) for r in keyframe_rows(ref)}
    assert evicted[at[0]] > 0, f"the first checkpoint must hold Gaussians on disk, found {evicted}"
    run_dir = tmp_path / "run"
    killed = bench([*args, f"hydra.run.dir={run_dir}"], tmp_path, signal_at=f"{at[1] - 1}:KILL")
    assert killed.returncode == -9, killed.stderr[-3000:]
    (run_dir / "map_store" / next(p.name for p in (run_dir / "map_store").glob("*.pt"))).unlink()  # rewritten
    resumed = bench([*args, f"hydra.run.dir={run_dir}"], tmp_path)
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    assert f"resuming {run_dir} from frame {at[0] + 1}" in resumed.stdout + resumed.stderr
    same_results(run_dir, ref)
    assert (run_dir / "map.ply").read_bytes() == (ref / "map.ply").read_bytes()
    assert not list((run_dir / "map_store").glob("*.pt"))
