"""Tiny runs under each keyframe-store policy (slam.keyframes.*): where the store's bytes live, per keyframes.csv."""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from pathlib import Path

import pytest

from bench import schema

REPO = Path(__file__).resolve().parents[1]
TINY = ["+experiment=tiny", "threads=1", "eval.lpips=false", "progress=false"]
POLICIES = {
    "today": [],
    "compact": ["slam.keyframes.precision=compact"],
    "window": ["slam.keyframes.window=2"],
    "disk": ["slam.keyframes.residency=disk"],
}
POSE_BYTES = 64  # a keyframe's float32 [4, 4] pose: in memory under every policy


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    out = {}
    for name, args in POLICIES.items():
        run_dir = tmp_path_factory.mktemp("kfstore") / name
        proc = subprocess.run(
            [sys.executable, "-m", "bench", *TINY, *args, f"hydra.run.dir={run_dir}"],
            cwd=run_dir.parent,
            text=True,
            capture_output=True,
            timeout=900,
        )
        assert proc.returncode == 0, proc.stderr[-3000:]
        assert json.loads((run_dir / schema.METRICS_FILE).read_text())["status"] == "ok"
        out[name] = run_dir
    return out


def rows(run_dir: Path) -> list[dict[str, float]]:
    with open(run_dir / schema.KEYFRAMES_FILE, newline="") as fh:
        return [
            {k: float(v) for k, v in r.items() if v not in ("", None) and k != "score_views"}
            for r in csv.DictReader(fh)
        ]


def store_bytes(n_held: int, bytes_per_px: int) -> float:
    """MiB of ``n_held`` keyframes at ``bytes_per_px`` (colour + depth) plus their poses."""
    h, w = 64, 96  # +experiment=tiny
    return n_held * (bytes_per_px * h * w + POSE_BYTES) / schema.MIB


@pytest.mark.slow
def test_each_policy_holds_the_keyframe_bytes_it_names(runs: dict[str, Path]) -> None:
    last = {name: rows(d)[-1] for name, d in runs.items()}
    n_kf = int(last["today"]["kf"]) + 1
    assert last["today"]["mem_keyframes_mib"] == pytest.approx(store_bytes(n_kf, 16), abs=1e-3)
    # uint8 colour + float16 depth: 5 of float32's 16 bytes a pixel
    assert last["compact"]["mem_keyframes_mib"] == pytest.approx(store_bytes(n_kf, 5), abs=1e-3)
    assert last["window"]["mem_keyframes_mib"] == pytest.approx(store_bytes(2, 16), abs=1e-3)
    assert last["disk"]["mem_keyframes_mib"] == pytest.approx(n_kf * POSE_BYTES / schema.MIB, abs=1e-3)
    for name in ("today", "compact", "window"):
        assert all(r["disk_total_mib"] == 0 for r in rows(runs[name]))
    assert last["disk"]["disk_keyframes_mib"] > store_bytes(n_kf, 16) - 1e-3  # files hold the images


@pytest.mark.slow
def test_live_and_disk_parts_add_up_to_their_totals(runs: dict[str, Path]) -> None:
    for name, run_dir in runs.items():
        record = json.loads((run_dir / schema.METRICS_FILE).read_text())["metrics"]
        for r in rows(run_dir):
            live = sum(r[c] for c in schema.MEMORY_PART_COLUMNS)
            assert live == pytest.approx(r["torch_live_peak_mib"], abs=5e-3), name
            assert r["disk_state_mib"] + r["disk_keyframes_mib"] == pytest.approx(r["disk_total_mib"], abs=2e-6)
        assert record["disk_peak_mib"] == max(r["disk_total_mib"] for r in rows(run_dir))


@pytest.mark.slow
def test_disk_residency_changes_where_the_store_lives_not_the_results(runs: dict[str, Path]) -> None:
    """float32 images read back from disk are the same tensors: the drive repeats bit for bit."""
    for name in ("traj_est.txt", "map.ply"):
        assert (runs["disk"] / name).read_bytes() == (runs["today"] / name).read_bytes()
    assert not (runs["disk"] / "keyframe_store").exists()
