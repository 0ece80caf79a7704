"""The regime study's report (bench/report/growth.py): ratios against the right baseline, the paper's prediction."""

from __future__ import annotations

import pandas as pd
import pytest

from bench.names import method_name
from bench.report import growth
from bench.report.figures.make import regime_plots


def _run(strategy: str, seed: int, peak: float, pruning: str = "", status: str = "ok", **extra) -> dict:
    row = {
        "strategy": strategy,
        "keep_ratio": None,
        "slam_preset": "faithful_fit",
        "memory_policy": "",
        "pruning": pruning,
        "status": status,
        "dataset": "sevenscenes",
        "seq": "seq",
        "seed": seed,
        "dataset.downscale": 4,
        "dataset.width": None,
        "dataset.height": None,
        "dataset.stride": 3,
        "num_frames": 334,
        "num_keyframes": 334,
        "gaussians_added_total": 334 * 1_000,
        "gaussians_added_per_kf_mpx": 1_000 / 0.0192,  # 160x120
        "state_per_gaussian_bytes": 1_000.0,
        "store_per_keyframe_bytes": 0.0192e6 * 20,  # 20 B a pixel
        "gaussian_share_of_peak": 0.5,
        "gaussians_peak": 300_000,
        "peak_mem_mib": peak,
        "peak_mem_source": "torch_live",
        "ate_rmse_m": 0.05,
        "psnr_db": 20.0,
        "fps": 0.3,
        "path": f"runs/{strategy}{pruning}/{extra.get('dataset.downscale', 4)}/{seed}",
    }
    row.update(extra)
    return row


@pytest.fixture
def runs() -> pd.DataFrame:
    return pd.DataFrame(
        [
            _run("none", 0, 200.0),
            _run("none", 1, 220.0),
            _run("pocket", 0, 100.0, "N_tar 166223/Mpx, floor 1/px"),
            _run("pocket", 1, 121.0, "N_tar 166223/Mpx, floor 1/px"),
            _run("pocket", 0, 150.0, "N_tar 166223/Mpx, floor 1/px, rank=random", ate_rmse_m=0.2),
            _run("pocket", 0, 30.0, "N_tar 166223/Mpx", status="lost"),
            _run("none", 0, 999.0, **{"dataset.downscale": 2}),  # another cell: never a baseline of the others
        ]
    )


def test_each_run_is_read_against_its_cell_and_seed(runs):
    table = growth.run_table(runs).set_index("path")
    assert table.loc["runs/pocketN_tar 166223/Mpx, floor 1/px/4/0", "peak_ratio"] == pytest.approx(0.5)
    assert table.loc["runs/pocketN_tar 166223/Mpx, floor 1/px/4/1", "peak_ratio"] == pytest.approx(0.55)
    assert table.loc["runs/none/4/0", "peak_ratio"] == 1.0 and table.loc["runs/none/2/0", "peak_ratio"] == 1.0
    assert pd.isna(table.loc["runs/pocketN_tar 166223/Mpx/4/0", "peak_ratio"])  # lost: a part of a run, no ratio
    # the two budgets and the chance rank are three rows, not seeds of one
    pocket = method_name("pocket")
    assert set(table.loc[table["strategy"] == "pocket", "label"]) == {
        f"{pocket} (N_tar 166223/Mpx, floor 1/px)",
        f"{pocket} (N_tar 166223/Mpx)",
        f"{pocket} (N_tar 166223/Mpx, floor 1/px, rank=random)",
    }


def test_the_summary_pools_seeds_and_tests_against_the_baseline(runs):
    s = growth.summary(growth.run_table(runs)).set_index("label")
    pocket = method_name("pocket")
    floored = s.loc[f"{pocket} (N_tar 166223/Mpx, floor 1/px)"]
    assert floored["seeds"] == 2 and floored["peak_ratio"].startswith("0.525 ± ")
    assert floored["p_peak_mem_mib"] != "—"  # two seeds a side
    assert s.loc[f"{pocket} (N_tar 166223/Mpx)", "lost"] == 1
    assert s.loc[f"{pocket} (N_tar 166223/Mpx, floor 1/px, rank=random)", "p_ate_rmse_m"] == "—"  # one seed


def test_the_papers_run_is_predicted_from_our_bytes(runs):
    run = growth.paper_run()["run"]
    pred = growth.prediction(growth.run_table(runs), run)
    assert pred["bytes_per_gaussian_low"] == 1_000.0
    assert pred["keyframe_bytes_per_px"] == pytest.approx(20.0)
    kf_gib = run["keyframes"] * 20.0 * 752 * 480 / 1024**3
    assert pred["none_gib_low"] == pytest.approx(8_510_000 * 1_000 / 1024**3 + kf_gib)
    assert pred["ratio_low"] == pytest.approx((55_900 * 1_000 / 1024**3 + kf_gib) / pred["none_gib_low"])
    # high: the Gaussians' share of the peak per Gaussian, the median over every baseline run (200, 220, 999 MiB)
    assert pred["bytes_per_gaussian_high"] == pytest.approx(0.5 * 220 * 2**20 / 300_000)
    assert pred["reported_ratio"] == pytest.approx(5.0 / 11.1)
    assert growth.paper_density(run) == pytest.approx(8_510_000 / 441 / (752 * 480 / 1e6))


def test_keyframe_ratios_follow_the_peak_so_far(runs, tmp_path):
    def kf(peaks):
        return pd.DataFrame(
            {"kf": range(len(peaks)), "n_kf_held": range(1, len(peaks) + 1), "torch_live_peak_mib": peaks}
        )

    keyframes = {
        "runs/none/4/0": kf([10.0, 20.0, 15.0]),
        "runs/pocketN_tar 166223/Mpx, floor 1/px/4/0": kf([10.0, 5.0, 12.0]),
    }
    curves = growth.keyframe_ratios(runs, keyframes)
    assert curves["ratio"].tolist() == pytest.approx([1.0, 0.5, 0.6])  # 10/10, 10/20, 12/20
    assert curves["n_kf_held"].tolist() == [1, 2, 3]
    written = regime_plots(runs, keyframes, tmp_path)
    assert sorted(p.name for p in written) == ["regime_ratio_vs_density.png", "regime_ratio_vs_keyframes.png"]
    text = growth.regime_markdown(runs)
    assert "## 7-Scenes seq, 1/4, stride 3" in text and "x0.450" in text


def test_the_pruning_label_names_what_differs_from_the_usual_schedule():
    from bench.report.settings import pruning_label

    usual = {"target": "ratio", "keep_ratio": 0.4, "every": "keyframe", "grad_source": "params_last"}
    pocket = {"name": "pocket", "params": {"budget_min": 5, "budget_max": 200, "rank": "area"}}
    assert pruning_label({"strategy": pocket, "prune": usual}) == ""
    budget = {**usual, "target": "absolute", "n_target_per_mpx": 166223.0, "n_target_floor_per_px": 1.0}
    chance = {**pocket, "params": {**pocket["params"], "rank": "random"}}
    assert pruning_label({"strategy": chance, "prune": budget}) == "N_tar 166223/Mpx, floor 1/px, rank=random"
    released = {**usual, "target": "absolute", "n_target": 80000, "every": "frame"}
    assert pruning_label({"strategy": pocket, "prune": released}) == "N_tar 80000, every=frame"
    assert pruning_label({"strategy": {"name": "none"}, "prune": budget}) == ""  # none prunes nothing


def test_the_prunable_share_reads_candidates_against_the_old_map(runs):
    # keyframe 0 has no prune; keyframe 1: 100 old Gaussians (120 after it, 30 pruned, 50 added), 40 in view;
    # keyframe 2: 200 old (230 + 0 - 30), 50 in view -> mean of 0.4 and 0.25
    kf = pd.DataFrame(
        {
            "kf": [0, 1, 2],
            "n_gaussians": [80, 120, 230],
            "n_pruned": [0, 30, 0],
            "n_added": [80, 50, 30],
            "n_candidates": [0, 40, 50],
        }
    )
    assert growth.in_view_share(kf) == pytest.approx((0.4 + 0.25) / 2)
    assert growth.in_view_share(kf.drop(columns="n_candidates")) is None
    assert growth.in_view_share(None) is None
    path = str(runs["path"].iloc[2])
    table = growth.run_table(runs, keyframes={path: kf}).set_index("path")
    assert table.loc[path, "in_view_share"] == pytest.approx(0.325)
    assert pd.isna(table.loc[str(runs["path"].iloc[0]), "in_view_share"])
    assert "prunable share" in growth.regime_markdown(runs, keyframes={path: kf})


def test_a_shorter_window_is_another_cell(runs):
    """The same sequence cut to its first 100 frames (``max_frames``) is its own cell, read against its own
    baseline, never against the whole sequence's."""
    short = pd.DataFrame(
        [
            _run("none", 0, 80.0, max_frames=100, path="runs/short/none"),
            _run("pocket", 0, 60.0, "N_tar 166223/Mpx, floor 1/px", max_frames=100, path="runs/short/pocket"),
        ]
    )
    table = growth.run_table(pd.concat([runs, short], ignore_index=True)).set_index("path")
    assert table.loc["runs/short/pocket", "peak_ratio"] == pytest.approx(0.75)  # 60 / 80, not 60 / 200
    assert table.loc["runs/short/pocket", "baseline_path"] == "runs/short/none"
    assert table.loc["runs/short/pocket", "cell"] == "7-Scenes seq, 1/4, stride 3, 100 frames"
    assert table.loc["runs/pocketN_tar 166223/Mpx, floor 1/px/4/0", "peak_ratio"] == pytest.approx(0.5)
