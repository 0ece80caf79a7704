"""metrics.json reads consistently: keep ratio, phase times against the SLAM wall time, ATE frames, run times."""

from __future__ import annotations

import json

import pytest
from hydra import compose, initialize_config_dir

from bench.cli.entry import CONF_DIR  # importing the CLI registers the schemas the configs build on
from bench.run.lifecycle import run

TINY = [
    "dataset.width=48",
    "dataset.height=32",
    "dataset.n_frames=4",
    "slam.tracking_iters=4",
    "slam.mapping_iters=4",
    "slam.refine_iters=3",
    "eval.lpips=false",
    "progress=false",
]


@pytest.mark.slow
def test_metrics_json_times_and_keys_agree(tmp_path):
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        cfg = compose(config_name="config", overrides=TINY)
    result = run(cfg, out_dir=tmp_path)
    assert result.status == "ok", result.error
    stored = json.loads((tmp_path / "metrics.json").read_text())
    m = stored["metrics"]
    assert stored["run"]["keep_ratio"] is None and m["keep_ratio"] is None  # nothing pruned: one meaning
    assert "refine" not in m["phase_s"] and m["refine_s"] > 0
    loop = m["slam_wall_s"] + m["warmup_s"]
    assert sum(m["phase_s"].values()) <= loop + 1e-3  # the loop's phases fit in the loop's time
    assert (m["ate_first_frame"], m["ate_last_frame"]) == (0, m["num_frames"] - 1)
    assert "ate_frames" not in m
    assert m["eval_s"] > 0 and m["wall_s"] >= loop + m["refine_s"] + m["eval_s"]
    # the regime descriptors, from the run's own counts
    mpx = 48 * 32 / 1e6
    expected = m["gaussians_added_total"] / m["num_keyframes"] / mpx
    assert m["gaussians_added_per_kf_mpx"] == pytest.approx(expected, abs=0.1)
    assert m["state_per_gaussian_bytes"] > 0 and m["store_per_keyframe_bytes"] > 0
    assert 0 < m["gaussian_share_of_peak"] <= 1


@pytest.mark.slow
def test_peaks_count_the_frames_after_the_last_keyframe(tmp_path, monkeypatch):
    """The frames after the last keyframe form a window no keyframes.csv row closes; the run's peaks
    must still see it: a 64 MiB buffer held during the last (non-key) frame is in peak_mem_mib."""
    import csv

    import torch

    from bench.slam.system import System

    step, big_mib = System.step, 64

    def step_then_hold(self, frame):
        res = step(self, frame)
        if frame.index == 5 and not res.is_keyframe:
            held = torch.ones(big_mib * 2**20 // 4)  # [n] float32, live for a moment, then freed
            del held
        return res

    monkeypatch.setattr(System, "step", step_then_hold)
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        cfg = compose(
            config_name="config", overrides=[*TINY, "dataset.n_frames=6", "slam.kf_every=4", "slam.refine_iters=0"]
        )
    result = run(cfg, out_dir=tmp_path)
    assert result.status == "ok", result.error
    m = json.loads((tmp_path / "metrics.json").read_text())["metrics"]
    with open(tmp_path / "keyframes.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert int(rows[-1]["frame"]) < 5  # frame 5 is after the last keyframe
    assert max(float(r["torch_live_peak_mib"]) for r in rows) < big_mib
    assert m["peak_mem_mib"] >= big_mib
    assert m["gaussians_peak"] >= m["gaussians_final"]


def test_fps_slam_counts_tracking_mapping_and_pruning_only():
    """fps_slam is frames / (tracking + mapping + pruning + residency s), the released code's FPS: frame loading,
    refinement and evaluation are not in it, and no SLAM phase gives None."""
    from bench.run.evaluation import fps_slam

    phases = {"tracking": 2.0, "mapping": 5.0, "pruning": 1.0, "refine": 100.0, "densification": 50.0}
    assert fps_slam(phases, 16) == 2.0
    assert fps_slam({"refine": 3.0}, 10) is None
    assert fps_slam({"tracking": 1.0, "residency": 1.0}, 0) is None
    assert fps_slam({"tracking": 1.0, "residency": 1.0}, 3) == 1.5
