"""The CLI forms, composed through Hydra's compose API, plus real subprocess runs."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from omegaconf import DictConfig

from bench.cli.entry import CONF_DIR, check_overrides
from bench.errors import StrategyError
from bench.run.lifecycle import run

REPO = Path(__file__).resolve().parents[1]


def compose_cfg(*overrides: str) -> DictConfig:
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        return compose(config_name="config", overrides=list(overrides))


def test_default_is_synthetic_without_pruning():
    cfg = compose_cfg()
    assert cfg.dataset.name == "synthetic"
    assert cfg.strategy is None


def test_paper_command_form_parses():
    cfg = compose_cfg("+strategy=pocket", "dataset=kitti", "seq=10")
    assert cfg.strategy.name == "pocket"
    assert cfg.dataset.name == "kitti"
    assert str(cfg.seq) == "10"


@pytest.mark.parametrize(
    ("overrides", "refine_iters", "tracking_iters"),
    [
        ((), 200, 20),  # synthetic: specialised on
        (("dataset=kitti",), 0, 20),  # real data: off
        (("dataset=euroc", "slam=paper"), 0, 50),  # survives another slam choice
        (("slam=paper",), 200, 50),
        (("dataset=kitti", "slam.refine_iters=7"), 7, 20),  # the command line wins
        (("slam.refine_iters=0",), 0, 20),
    ],
)
def test_final_refinement_is_specialised_per_dataset(overrides, refine_iters, tracking_iters):
    cfg = compose_cfg(*overrides)
    assert cfg.slam.refine_iters == refine_iters
    assert cfg.slam.tracking_iters == tracking_iters


@pytest.mark.parametrize("seq", ["00", "05", "10"])
def test_seq_is_kept_as_written(seq):
    from bench.run.config import to_run_config
    from bench.run.identity import run_keys

    cfg = to_run_config(compose_cfg("dataset=kitti", f"seq={seq}"))
    assert run_keys(cfg)["seq"].zfill(2) == seq


def test_unknown_strategy_is_one_line_with_suggestion():
    with pytest.raises(StrategyError) as err:
        check_overrides(["+strategy=pockt"])
    msg = str(err.value)
    assert msg.startswith("unknown strategy 'pockt'; did you mean 'pocket'? available: ")
    assert "\n" not in msg
    check_overrides(["+strategy=none,pocket,area,opacity,gradient,mask"])  # all known


def _run_cli(args: list[str], cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": f"{REPO}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}  # this checkout
    return subprocess.run(
        [sys.executable, "-m", "bench", *args], cwd=cwd, capture_output=True, text=True, timeout=600, env=env
    )


def test_missing_kitti_is_one_line_error(tmp_path):
    proc = _run_cli(
        [
            "+strategy=pocket",
            "dataset=kitti",
            "seq=10",
            f"dataset.root={tmp_path}/nokitti",
            f"hydra.run.dir={tmp_path}/run",
        ],
        tmp_path,
    )
    assert proc.returncode != 0
    assert "Traceback" not in proc.stderr
    err_lines = [ln for ln in proc.stderr.splitlines() if ln.startswith("error:")]
    assert len(err_lines) == 1 and "kitti" in err_lines[0] and "not found" in err_lines[0], proc.stderr
    stored = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert stored["status"] == "failed"


def test_unknown_strategy_cli(tmp_path):
    proc = _run_cli(["+strategy=pockt"], tmp_path)
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines() == [proc.stderr.strip()]
    assert "did you mean 'pocket'" in proc.stderr


@pytest.mark.slow
def test_subprocess_tiny_run(tmp_path):
    # out_dir= takes precedence over Hydra's run dir (which then holds only Hydra's own files)
    proc = _run_cli(
        [
            "+experiment=tiny",
            "dataset.n_frames=6",
            "slam.mapping_iters=10",
            "slam.tracking_iters=10",
            f"hydra.run.dir={tmp_path}/hydra",
            f"out_dir={tmp_path}/run",
        ],
        tmp_path,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    stored = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert stored["status"] == "ok"
    assert (tmp_path / "run" / "keyframes.csv").read_text().count("\n") >= 2
    # stderr is not a terminal here: one line per phase (tiny runs show progress too)
    phases = [ln.split(":")[0] for ln in proc.stderr.splitlines() if " in " in ln and ln.split(":")[0].isalpha()]
    assert phases == ["frames", "refine", "evaluate"], proc.stderr
    assert "frames: 6/6 frames in " in proc.stderr and "refine: 30/30 iterations in " in proc.stderr
    # and the run ends with the aligned summary table
    lines = proc.stdout.splitlines()
    start = lines.index(f"[ok] {tmp_path / 'run'}")
    table = {ln.split()[0]: ln for ln in lines[start + 1 :]}
    for label in ("ATE", "PSNR", "SSIM", "LPIPS", "FPS", "peak", "Gaussians", "wall", "run"):
        assert label in table, proc.stdout
    assert table["ATE"].endswith(" m") and " dB" in table["PSNR"] and "MiB" in table["peak"]
    assert not (tmp_path / "hydra" / "metrics.json").exists()


@pytest.mark.slow
def test_end_to_end_tiny_run_is_accurate(tmp_path):
    """Bounds a broken tracker (ATE) or mapper (PSNR) would fail, relative to what the run itself can see."""
    cfg = compose_cfg("+experiment=tiny")
    res = run(cfg, out_dir=tmp_path)
    m = res.metrics
    assert res.status == "ok", res.error
    assert m["num_frames"] == 12
    # a tracker that stands still is off by about half the path; mapping must beat the map as seeded
    assert m["ate_rmse_m"] < 0.03 * m["path_length_m"], m
    unmapped = run(
        compose_cfg("+experiment=tiny", "slam.mapping_iters=0", "slam.refine_iters=0"), out_dir=tmp_path / "unmapped"
    ).metrics
    assert m["psnr_db"] > unmapped["psnr_db"] + 0.5, (m["psnr_db"], unmapped["psnr_db"])
    # the run directory follows bench.schema
    from bench import schema

    assert set(m) <= set(schema.METRIC_NAMES), sorted(set(m) - set(schema.METRIC_NAMES))
    assert m["gaussians_peak"] > 0 and m["state_peak_mib"] > 0
    for name in ("metrics.json", "keyframes.csv", "traj_est.txt", "traj_gt.txt", "config.yaml", "memory.png"):
        assert (tmp_path / name).exists(), name
    # per-window rows move with the Gaussian count: more Gaussians, more exact state bytes
    import csv

    rows = list(csv.DictReader((tmp_path / "keyframes.csv").open()))
    assert list(rows[0]) == schema.KEYFRAME_COLUMNS
    assert len(rows) == m["num_keyframes"] >= 2
    counts = [int(r["n_gaussians"]) for r in rows]
    state = [int(r["state_bytes"]) for r in rows]
    assert counts[-1] > counts[0] and state[-1] > state[0]
    assert all((c2 > c1) == (s2 > s1) for c1, c2, s1, s2 in zip(counts, counts[1:], state, state[1:], strict=False))
    assert all(float(r["torch_live_peak_mib"]) > 0 and float(r["cpu_rss_peak_mib"]) > 0 for r in rows)
    # resume: the same config is skipped, a changed one is not
    again = run(cfg, out_dir=tmp_path)
    assert again.skipped and again.metrics == m


@pytest.mark.slow
def test_a_single_run_is_validated_and_built_once(tmp_path, monkeypatch):
    """The CLI's check before Hydra starts builds the run (config, strategy); ``bench.run.lifecycle`` uses that."""
    import contextlib
    import io

    import bench.run.validate
    from bench.cli import entry as cli

    conversions = []
    convert = bench.run.validate.to_run_config
    monkeypatch.setattr(bench.run.validate, "to_run_config", lambda cfg: conversions.append(1) or convert(cfg))
    monkeypatch.setattr(
        sys,
        "argv",
        [
            "bench",
            "+experiment=tiny",
            "+strategy=pocket",
            "dataset.n_frames=3",
            "slam.mapping_iters=2",
            "slam.tracking_iters=2",
            "slam.refine_iters=0",
            "eval.lpips=false",
            "progress=false",
            f"hydra.run.dir={tmp_path}",
        ],
    )
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()) as err:
        assert cli.main() == 0, err.getvalue()
    assert json.loads((tmp_path / "metrics.json").read_text())["status"] == "ok"
    assert len(conversions) == 1  # one conversion: every rule run once, the strategy built once
