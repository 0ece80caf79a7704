"""Seed statistics in the report: confidence intervals, Welch's test, the noise marker, 1-seed sweeps."""

from __future__ import annotations

import math

import pandas as pd
import pytest

from bench.report import make_report
from bench.report.stats import confidence_interval, welch_p, within_noise


def test_confidence_interval_by_hand():
    lo, hi = confidence_interval([0.10, 0.11, 0.12])
    half = 4.302652729911275 * 0.01 / math.sqrt(3)  # t(0.975, 2) x s / sqrt(n)
    assert (lo, hi) == pytest.approx((0.11 - half, 0.11 + half))
    assert confidence_interval([0.1]) is None


def test_welch_p_against_scipy_and_edge_cases():
    # Welch's test by hand: t = (mean_a - mean_b) / sqrt(s_a^2/n_a + s_b^2/n_b), Welch-Satterthwaite df
    a, b = [1.0, 2.0, 3.0, 4.0], [2.0, 4.0, 6.0]
    va, vb = 1.6666666666666667 / 4, 4.0 / 3
    t = (2.5 - 4.0) / math.sqrt(va + vb)
    df = (va + vb) ** 2 / (va**2 / 3 + vb**2 / 2)
    from scipy.stats import t as student

    assert welch_p(a, b) == pytest.approx(2 * student.sf(abs(t), df))
    assert welch_p([1.0], [1.0, 2.0]) is None  # no variance estimate on one side
    assert welch_p([5.0, 5.0], [5.0, 5.0]) == 1.0  # a metric that does not move with the seed
    assert welch_p([5.0, 5.0], [6.0, 6.0]) == 0.0
    assert within_noise(0.3) and not within_noise(0.01) and not within_noise(None)


@pytest.fixture(scope="module")
def noise_report(tmp_path_factory, make_run):
    """Three seeds of a baseline, a strategy clearly apart from it and one inside its spread."""
    root = tmp_path_factory.mktemp("noise")
    ate = {"none": (0.10, 0.11, 0.12), "pocket": (0.30, 0.31, 0.32), "area": (0.105, 0.115, 0.11)}
    for strategy, values in ate.items():
        for seed, value in enumerate(values):
            make_run(
                root / f"{strategy}_{seed}",
                strategy=strategy,
                seq="00",
                seed=seed,
                keep_ratio=None if strategy == "none" else 0.4,
                ate_rmse_m=value,
                peak_mem_mib=1000.0 - 100 * (strategy != "none") + seed,
                fps=1.0 + 0.1 * seed,
            )
    return make_report([root], tmp_path_factory.mktemp("noise_out"))


def _cell(report, block_title: str, label: str, column: str = "00"):
    tab = next(t for t in report.tables if any(b.title == block_title for b in t.blocks))
    block = next(b for b in tab.blocks if b.title == block_title)
    row = next(r for r in block.rows if r.label == label)
    return row.cells[tab.columns.index(column)], tab


def test_cells_within_seed_noise_are_marked_and_footnoted(noise_report):
    near, acc = _cell(noise_report, "ATE [m]", "Ours (w/o Tile Budget)")
    far, _ = _cell(noise_report, "ATE [m]", "Ours (w/ Tile Budget)")
    base, _ = _cell(noise_report, "ATE [m]", "LSG-SLAM baseline")
    assert near.noise and near.p_value == pytest.approx(welch_p([0.105, 0.115, 0.11], [0.10, 0.11, 0.12]))
    assert not far.noise and far.p_value < 0.05
    assert not base.noise and base.p_value is None  # the baseline is not tested against itself
    md = (noise_report.out / "tables.md").read_text(encoding="utf-8")
    assert "| **0.110 ± 0.005**† |" in md and "| 0.310 ± 0.010 |" in md
    assert any("Welch's t-test" in n and "Seeds per cell: 3" in n for n in acc.notes)
    assert "$^\\dagger$" in (noise_report.out / "accuracy_kitti.tex").read_text(encoding="utf-8")
    # the relative blocks carry their metric's verdict: memory 999-1001 vs 899-901 is no noise
    mem_rel, _ = _cell(noise_report, "Memory vs baseline", "Ours (w/o Tile Budget)")
    fps_rel, _ = _cell(noise_report, "FPS vs baseline", "Ours (w/o Tile Budget)")
    assert not mem_rel.noise and fps_rel.noise


def test_stats_csv_has_ci_and_welch_per_cell(noise_report):
    stats = pd.read_csv(noise_report.out / "stats.csv")
    row = stats[(stats.metric == "ate_rmse_m") & (stats.strategy == "none") & (stats.seq == "00")].iloc[0]
    assert row.n_seeds == 3 and row.seeds == "0 1 2"
    assert (row.ci95_low, row.ci95_high) == pytest.approx(confidence_interval([0.10, 0.11, 0.12]))
    assert pd.isna(row.p_welch)
    area = stats[(stats.metric == "ate_rmse_m") & (stats.strategy == "area") & (stats.seq == "Avg")].iloc[0]
    assert area.within_noise and area.baseline == "none" and area.n_seeds == 3


def test_a_single_seed_sweep_says_it_has_no_noise_estimate(tmp_path, make_run):
    for strategy in ("none", "pocket"):
        make_run(
            tmp_path / "runs" / strategy, strategy=strategy, seq="00", keep_ratio=None if strategy == "none" else 0.4
        )
    report = make_report([tmp_path / "runs"], tmp_path / "out")
    for table in report.tables:
        assert "1 seed: no noise estimate; a difference from the baseline may be seed noise." in table.notes
        assert not any(c.noise for b in table.blocks for r in b.rows for c in r.cells)
    stats = pd.read_csv(tmp_path / "out" / "stats.csv")
    assert stats.ci95_low.isna().all() and stats.p_welch.isna().all()


def test_per_seed_points_average_the_same_sequences_as_the_mean(report):
    from bench.report.figures.ratio import per_seed_average
    from bench.report.variants import variant_runs, variants

    kitti = report.runs[report.runs["dataset"] == "kitti"]
    none = next(v for v in variants(kitti) if v.strategy == "none")
    per_seed = per_seed_average(variant_runs(kitti, none), "ate_rmse_m")
    assert per_seed.to_dict() == pytest.approx({0: 0.15, 1: 0.16})  # (0.10 + 0.20) / 2, (0.12 + 0.20) / 2


def test_pareto_and_memory_figures_are_written_with_seeds(noise_report):
    names = {p.name for p in noise_report.files}
    assert {"pareto_kitti.png", "memory_per_keyframe_kitti_00.png", "stats.csv"} <= names
