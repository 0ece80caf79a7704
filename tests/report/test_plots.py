"""Figures are written, and the pieces behind them (alignment, peak probe) are right."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bench.report.collect import collect
from bench.report.plots import make_plots

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
