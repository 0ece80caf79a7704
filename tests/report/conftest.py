"""Fabricated run dirs in the harness's format, small enough to check every figure by hand."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

KF_COLUMNS = (
    "kf,frame,n_gaussians,n_masked,n_added,n_pruned,n_candidates,state_bytes,state_mib,cpu_rss_peak_mib,"
    "torch_live_peak_mib,cuda_alloc_peak_mib,cuda_reserved_peak_mib,track_s,map_s,prune_s"
)


def write_run(
    run_dir: Path,
    *,
    strategy: str,
    seq: str,
    dataset: str = "kitti",
    seed: int = 0,
    keep_ratio: float | None = 0.4,
    status: str = "ok",
    slam_preset: str | None = None,
    **metrics: Any,
) -> Path:
    """One run dir: metrics.json, keyframes.csv, TUM trajectories and density.npz.

    ``metrics`` override the defaults; a 'failed' run gets an empty metrics dict and no other files.
    """
    run_dir.mkdir(parents=True, exist_ok=True)
    values: dict[str, Any] = {
        "ate_rmse_m": 0.1, "ate_alignment": "se3", "ate_num_poses": 20, "psnr_db": 25.0, "ssim": 0.9,
        "lpips": 0.2, "eval_frames": 5, "fps": 1.0, "slam_wall_s": 20.0, "num_frames": 20,
        "num_keyframes": 4, "gaussians_final": 1000, "gaussians_peak": 1200, "state_peak_mib": 3.0,
        "cpu_rss_peak_mib": 900.0, "torch_live_peak_mib": 300.0, "cuda_alloc_peak_mib": None,
        "cuda_reserved_peak_mib": None, "peak_mem_mib": 300.0,
    }  # fmt: skip
    # what the real harness adds beside the documented metrics (bench/run/lifecycle.py)
    values.update(
        peak_mem_source="torch_live",
        ate_mean_m=0.09,
        ate_max_m=0.2,
        ate_max_diff_s=0.01,
        ate_first_frame=0,
        ate_last_frame=19,
        path_length_m=4.1,
        phase_s={"track": 10.0, "map": 8.0},
        memory_method={"cpu_rss": "psutil", "torch_live": True},
        keep_ratio=keep_ratio,
    )
    values.update(metrics)
    if "peak_mem_mib" in metrics:
        values["torch_live_peak_mib"] = metrics["peak_mem_mib"]
    failed = status == "failed"
    doc = {
        "status": status,
        "error": "cuda out of memory" if failed else ("tracking lost at frame 12" if status == "lost" else None),
        "run": dict(
            strategy=strategy,
            dataset=dataset,
            seq=seq,
            seed=seed,
            keep_ratio=keep_ratio,
            config_hash="ab12",
            **({} if slam_preset is None else {"slam_preset": slam_preset}),
        ),
        "metrics": {} if failed else values,
        "provenance": {"git_commit": "abc", "git_dirty": False, "versions": {"torch": "2.3.0"}, "device": "cpu"},
    }
    (run_dir / "metrics.json").write_text(json.dumps(doc), encoding="utf-8")
    if failed:
        return run_dir

    peak = values["peak_mem_mib"] or 100.0
    rows = [KF_COLUMNS]
    for kf in range(4):
        state = 0.5 + kf * 0.5
        rows.append(
            f"{kf},{kf * 5},{1000 + kf * 50},10,60,10,25,{int(state * 2**20)},{state},{900.0},"
            f"{peak * (0.7 + 0.1 * kf):.3f},,,0.10,0.50,0.01"
        )
    (run_dir / "keyframes.csv").write_text("\n".join(rows) + "\n", encoding="utf-8")

    t = np.arange(20) * 0.1
    gt = np.column_stack([t, 2.0 * t, 0.01 * t, np.sin(t), np.zeros((20, 3)), np.ones(20)])
    est = gt.copy()
    est[:, 1:4] = gt[:, 1:4] @ _rot_y(0.3).T + np.array([1.0, 0.0, -0.5]) + 0.01 * (seed + 1)
    header = "timestamp tx ty tz qx qy qz qw"
    np.savetxt(run_dir / "traj_gt.txt", gt, fmt="%.9g", header=header)
    np.savetxt(run_dir / "traj_est.txt", est, fmt="%.9g", header=header)

    rng = np.random.default_rng(seed)
    counts = rng.poisson(2.0 if strategy == "none" else 0.8, size=(12, 16))
    np.savez(run_dir / "density.npz", counts=counts, image=rng.random((12, 16, 3)))
    return run_dir


def _rot_y(angle_rad: float) -> np.ndarray:
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


# (strategy, keep_ratio, seq, seed, status, metrics); values chosen for hand-checked tables.
SWEEP: list[tuple[str, float | None, str, int, str, dict[str, Any]]] = [
    ("none", 1.0, "00", 0, "ok", dict(ate_rmse_m=0.10, psnr_db=25.0, peak_mem_mib=1000.0, fps=1.0)),
    ("none", 1.0, "00", 1, "ok", dict(ate_rmse_m=0.12, psnr_db=26.0, peak_mem_mib=1100.0, fps=1.2)),
    ("none", 1.0, "05", 0, "ok", dict(ate_rmse_m=0.20, psnr_db=24.0, peak_mem_mib=2000.0, fps=0.5)),
    ("none", 1.0, "05", 1, "ok", dict(ate_rmse_m=0.20, psnr_db=24.0, peak_mem_mib=2000.0, fps=0.5)),
    ("pocket", 0.4, "00", 0, "ok", dict(ate_rmse_m=0.09, psnr_db=27.0, peak_mem_mib=400.0, fps=2.0)),
    ("pocket", 0.4, "00", 1, "ok", dict(ate_rmse_m=0.09, psnr_db=27.0, peak_mem_mib=420.0, fps=2.4)),
    ("pocket", 0.4, "05", 0, "ok", dict(ate_rmse_m=0.19, psnr_db=25.0, peak_mem_mib=800.0, fps=1.5)),
    ("pocket", 0.4, "05", 1, "ok", dict(ate_rmse_m=0.21, psnr_db=25.0, peak_mem_mib=800.0, fps=1.5)),
    ("pocket", 0.4, "05", 2, "lost", dict(ate_rmse_m=3.0, psnr_db=9.0, peak_mem_mib=700.0, fps=1.4)),
    ("pocket", 0.2, "00", 0, "ok", dict(ate_rmse_m=0.30, psnr_db=22.0, peak_mem_mib=300.0, fps=2.5)),
    ("opacity", 0.4, "00", 0, "ok", dict(ate_rmse_m=0.50, psnr_db=15.0, lpips=None, peak_mem_mib=500.0, fps=1.5)),
    ("opacity", 0.4, "05", 0, "lost", dict(ate_rmse_m=None, psnr_db=None, peak_mem_mib=600.0, fps=None)),
    ("mask", 0.4, "00", 0, "failed", {}),
    ("mask", 0.4, "05", 0, "ok", dict(ate_rmse_m=0.40, psnr_db=20.0, peak_mem_mib=1500.0, fps=0.6)),
    ("my_prune", 0.5, "00", 0, "ok", dict(ate_rmse_m=0.15, psnr_db=23.0, peak_mem_mib=700.0, fps=1.1)),
]
EUROC: list[tuple[str, float | None, str, int, str, dict[str, Any]]] = [
    ("none", 1.0, "MH_01_easy", 0, "ok", dict(ate_rmse_m=0.05, peak_mem_mib=900.0, fps=1.0)),
    ("pocket", 0.4, "MH_01_easy", 0, "ok", dict(ate_rmse_m=0.06, peak_mem_mib=300.0, fps=3.0)),
]
N_USABLE = len(SWEEP) + len(EUROC) + 1  # + one 'running' run


@pytest.fixture(scope="session")
def sweep_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A Hydra-like multirun tree: DATE/TIME/N/ run dirs, plus one running and one malformed run.

    Scored with ``eval.protocol=splatam``, the masked protocol the paper's rows may stand beside."""
    root = tmp_path_factory.mktemp("multirun")
    for i, (strategy, keep, seq, seed, status, metrics) in enumerate(SWEEP):
        write_run(
            root / "2024-05-01" / "12-00-00" / str(i),
            strategy=strategy,
            seq=seq,
            seed=seed,
            keep_ratio=keep,
            status=status,
            eval_protocol="splatam",
            **metrics,
        )
    for i, (strategy, keep, seq, seed, status, metrics) in enumerate(EUROC):
        write_run(
            root / "2024-05-02" / "09-30-00" / str(i),
            strategy=strategy,
            seq=seq,
            dataset="euroc",
            seed=seed,
            keep_ratio=keep,
            status=status,
            eval_protocol="splatam",
            **metrics,
        )
    write_run(root / "2024-05-03" / "running" / "0", strategy="area", seq="00", status="running")
    bad = root / "2024-05-03" / "broken" / "0"
    bad.mkdir(parents=True)
    (bad / "metrics.json").write_text('{"status": "ok", "run": ', encoding="utf-8")
    return root


@pytest.fixture(scope="session")
def report(sweep_dir: Path, tmp_path_factory: pytest.TempPathFactory):
    """The full report (with paper rows) over ``sweep_dir``, built once for all tests."""
    from bench.report import make_report

    return make_report([sweep_dir], tmp_path_factory.mktemp("report") / "out", paper=True)


@pytest.fixture(scope="session")
def make_run():
    """``write_run`` for tests that need their own small sweep (conftest is not importable)."""
    return write_run


@pytest.fixture(scope="session")
def n_usable() -> int:
    return N_USABLE
