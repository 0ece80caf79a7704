"""A full SLAM run on the shipped KITTI 06 frames, at a reduced resolution, finishes with status ok."""

from __future__ import annotations

import pytest
from hydra import compose, initialize_config_dir

from bench.cli.entry import CONF_DIR
from bench.run.lifecycle import run


@pytest.mark.slow
def test_kitti06_short_run(shared, tmp_path):
    overrides = [
        "dataset=kitti",
        "seq=06",
        f"dataset.root={shared}/data/kitti",
        f"dataset.cache_dir={tmp_path}/cache",
        "dataset.downscale=8",
        "dataset.last=9",
        "slam.tracking_iters=15",
        "slam.mapping_iters=20",
        "slam.refine_iters=20",
        "progress=false",
        "eval.every=3",
        "eval.lpips=false",
    ]
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        cfg = compose(config_name="config", overrides=overrides)
    res = run(cfg, out_dir=tmp_path / "run")
    assert res.status == "ok", res.error
    m = res.metrics
    assert m["num_frames"] == 10 and m["ate_num_poses"] == 10
    assert m["ate_rmse_m"] < 0.1 * m["path_length_m"], m  # a tracker that stood still would be ~30% off
    assert m["psnr_db"] > 15, m
