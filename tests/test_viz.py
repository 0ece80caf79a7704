"""viz.pruning: pictures of what a prune removed, without changing what the run computes."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest
from hydra import compose, initialize_config_dir

from bench.cli.entry import CONF_DIR  # importing bench.cli.entry registers the config schemas
from bench.run.lifecycle import run

TINY = [
    "dataset.width=48",
    "dataset.height=32",
    "dataset.n_frames=9",
    "slam.tracking_iters=4",
    "slam.mapping_iters=4",
    "slam.refine_iters=0",
    "eval.lpips=false",
    "progress=false",
    "threads=1",
    "+strategy=pocket",
]


def run_tiny(tmp_path, name, extra):
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        cfg = compose(config_name="config", overrides=[*TINY, *extra])
    result = run(cfg, out_dir=tmp_path / name)
    assert result.status == "ok", result.error
    return tmp_path / name


@pytest.mark.slow
def test_pruning_pictures_match_the_prune_and_leave_the_run_alone(tmp_path):
    plain = run_tiny(tmp_path, "plain", [])
    shown = run_tiny(tmp_path, "viz", ["viz.pruning=true", "viz.every=1"])
    assert not list(plain.glob("pruned_kf*"))  # off by default
    rows = {int(r["kf"]): r for r in csv.DictReader(open(shown / "keyframes.csv"))}
    npzs = sorted(shown.glob("pruned_kf*.npz"))
    assert [int(p.stem[-3:]) for p in npzs] == [k for k in sorted(rows) if k > 0]
    for path in npzs:
        assert path.with_suffix(".png").is_file()
        with np.load(path) as r:
            assert int(r["n_pruned"]) == int(rows[int(r["kf"])]["n_pruned"])
            assert len(r["uv"]) == len(r["coverage"]) <= int(r["n_pruned"])
            assert r["image"].shape == r["before"].shape == r["after"].shape == (32, 48, 3)
            if int(r["n_pruned"]):
                assert (r["coverage"] > 0).all()
    assert any(int(np.load(p)["n_pruned"]) for p in npzs)
    # the hook renders and reads, never writes: the same numbers with and without it
    a, b = (json.loads((d / "metrics.json").read_text())["metrics"] for d in (plain, shown))
    for key in ("ate_rmse_m", "psnr_db", "gaussians_final", "gaussians_pruned_total"):
        assert a[key] == b[key], key
