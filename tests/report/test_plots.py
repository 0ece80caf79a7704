"""Figures are written, and the pieces behind them (alignment, peak probe) are right."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from bench.report.collect import collect
from bench.report.plots import aligned_positions, make_plots, peak_column, umeyama

PNG = b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize(
    "name",
    [
        "memory_per_keyframe_kitti_00.png",
        "memory_per_keyframe_kitti_05.png",
        "memory_per_keyframe_euroc_MH_01_easy.png",
        "ratio_kitti.png",
        "density_kitti_00.png",
        "density_euroc_MH_01_easy.png",
        "trajectory_kitti_00.png",
        "trajectory_kitti_05.png",
        "pareto_kitti.png",
        "pareto_euroc.png",
    ],
)
def test_plot_is_written(report, name: str) -> None:
    path = report.out / name
    assert path in report.files
    assert path.stat().st_size > 1000
    assert path.read_bytes()[:8] == PNG


def test_ratio_plot_needs_two_ratios_of_one_strategy(report) -> None:
    assert not (report.out / "ratio_euroc.png").exists()  # one keep ratio per strategy there


def _rot(axis: np.ndarray, angle: float) -> np.ndarray:
    axis = axis / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * k @ k


def test_umeyama_recovers_a_similarity() -> None:
    rng = np.random.default_rng(0)
    src = rng.normal(size=(30, 3))
    rot, t, s = _rot(np.array([0.2, 1.0, -0.3]), 0.7), np.array([1.0, -2.0, 0.5]), 1.7
    dst = s * src @ rot.T + t
    s_hat, rot_hat, t_hat = umeyama(src, dst, with_scale=True)
    assert s_hat == pytest.approx(s)
    np.testing.assert_allclose(rot_hat, rot, atol=1e-9)
    np.testing.assert_allclose(t_hat, t, atol=1e-9)


def test_estimate_is_aligned_onto_ground_truth_by_timestamp() -> None:
    t = np.arange(25) * 0.1
    gt_xyz = np.column_stack([t, np.sin(t), 0.3 * t**2])
    gt = np.column_stack([t, gt_xyz, np.zeros((25, 3)), np.ones(25)])
    est = gt[::2].copy()  # fewer poses than the ground truth
    est[:, 0] += 0.005  # stamps within the association window
    est[:, 1:4] = est[:, 1:4] @ _rot(np.array([0.0, 1.0, 0.0]), 1.0).T + 3.0
    np.testing.assert_allclose(aligned_positions(est, gt, "se3"), gt_xyz[::2], atol=1e-9)
    np.testing.assert_allclose(aligned_positions(est, gt, "none"), est[:, 1:4])


def test_peak_column_is_the_one_behind_the_headline() -> None:
    kf = pd.DataFrame({"state_mib": [1.0], "cpu_rss_peak_mib": [900.0], "torch_live_peak_mib": [300.0],
                       "cuda_alloc_peak_mib": [None]})  # fmt: skip
    run = pd.Series({"peak_mem_mib": 900.0, "cpu_rss_peak_mib": 900.0, "torch_live_peak_mib": 300.0})
    assert peak_column(run, kf) == "cpu_rss_peak_mib"
    assert peak_column(pd.Series({"peak_mem_mib": None}), kf) == "torch_live_peak_mib"


def test_bad_run_files_cost_a_warning_not_the_report(tmp_path: Path, make_run) -> None:
    run = make_run(tmp_path / "sweep" / "0", strategy="none", seq="00")
    make_run(tmp_path / "sweep" / "1", strategy="pocket", seq="00")
    (run / "traj_est.txt").write_text("not a trajectory\n")
    (run / "keyframes.csv").write_text("a,b\n1,2\n")
    np.savez(run / "density.npz", counts=np.zeros(3))
    warnings: list[str] = []
    written = make_plots(collect([tmp_path / "sweep"]).runs, tmp_path / "out", warnings.append)
    assert {p.name for p in written} >= {"trajectory_kitti_00.png", "memory_per_keyframe_kitti_00.png"}
    for name in ("traj_est.txt", "keyframes.csv", "density.npz"):
        assert any(name in w and "expected" in w for w in warnings), name
