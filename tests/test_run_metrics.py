"""metrics.json reads consistently: keep ratio, phase times against the SLAM wall time, ATE frames, run times."""

from __future__ import annotations

import json

import pytest
from hydra import compose, initialize_config_dir

from bench.cli import CONF_DIR  # importing the CLI registers the schemas the configs build on
from bench.run import run

TINY = ["dataset.width=48", "dataset.height=32", "dataset.n_frames=4", "slam.tracking_iters=4",
        "slam.mapping_iters=4", "slam.refine_iters=3", "eval.lpips=false", "progress=false"]  # fmt: skip


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
