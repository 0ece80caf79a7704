"""eval.protocol end to end: a tiny run scored each masked way records what it scored and how; bad settings refused."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir

from bench.cli.entry import CONF_DIR  # importing the CLI registers the schemas the configs build on
from bench.run.config import to_run_config
from bench.run.lifecycle import run
from tests.test_bad_input import run_cli, tiny

SMALL = [
    "+experiment=tiny",
    "dataset.n_frames=4",
    "slam.tracking_iters=4",
    "slam.mapping_iters=4",
    "slam.refine_iters=0",
    "eval.every=1",
    "eval.lpips=false",
    "eval.at_frames=[3]",
    "progress=false",
]


def _run(tmp_path: Path, overrides: list[str]) -> dict:
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        cfg = compose(config_name="config", overrides=[*SMALL, *overrides])
    result = run(cfg, out_dir=tmp_path)
    assert result.status == "ok", result.error
    return json.loads((tmp_path / "metrics.json").read_text())["metrics"]


@pytest.mark.slow
def test_splatam_protocol_run_records_its_mask(tmp_path: Path) -> None:
    m = _run(tmp_path, ["eval.protocol=splatam"])
    assert m["eval_protocol"] == "splatam"
    assert m["eval_depth_range_m"] == [0.0, None]  # the synthetic scene's range: every pixel with depth
    assert 0 < m["eval_mask_frac"] <= 1 and m["psnr_db"] > 0 and 0 < m["ssim"] <= 1
    assert m["ms_ssim"] is None  # 96x64 px: below the 176 px MS-SSIM needs; the run still scores the rest
    assert m["path_length_ratio"] == pytest.approx(1.0, abs=0.2)
    with open(tmp_path / "milestones.csv", newline="") as fh:
        (row,) = list(csv.DictReader(fh))
    assert row["frames"] == "3" and float(row["path_length_ratio"]) > 0 and row["ms_ssim"] == ""
    with open(tmp_path / "keyframes.csv", newline="") as fh:
        kfs = list(csv.DictReader(fh))
    assert kfs[0]["path_length_ratio"] == kfs[0]["path_length_ratio_prefix"] == ""  # keyframe 0: no path yet
    assert all(float(r["path_length_m"]) > 0 and float(r["path_length_ratio"]) > 0 for r in kfs[1:])
    assert kfs[-1]["frame"] == "3"  # the last frame is a keyframe: its prefix is the whole run's ratio
    assert float(kfs[-1]["path_length_ratio_prefix"]) == pytest.approx(m["path_length_ratio"], abs=1e-4)


@pytest.mark.slow
def test_velocity_starts_are_counted(tmp_path: Path) -> None:
    assert _run(tmp_path / "v", ["slam.tracking_init=velocity"])["tracking_velocity_starts"] == 3  # frames 1-3
    assert _run(tmp_path / "f", ["slam.flow_pnp.min_inliers=100000"])["tracking_velocity_starts"] == 3  # no start
    assert _run(tmp_path / "p", [])["tracking_velocity_starts"] < 3  # flow + PnP starts some frames


@pytest.mark.slow
def test_released_protocol_run_scores_ms_ssim_where_the_image_allows(tmp_path: Path) -> None:
    m = _run(tmp_path, ["eval.protocol=released", "dataset.width=192", "dataset.height=176"])
    assert m["eval_protocol"] == "released" and "eval_depth_range_m" not in m  # the silhouette needs no depth
    assert 0 < m["eval_mask_frac"] <= 1
    assert 0 < m["ms_ssim"] <= 1 and 0 < m["ssim"] <= 1


def test_depth_range_defaults_follow_the_released_configs() -> None:
    def dataset(name: str):
        with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
            return to_run_config(compose(config_name="config", overrides=[f"dataset={name}"])).dataset

    ranges = {
        name: (dataset(name).eval_depth_near_m, dataset(name).eval_depth_far_m)
        for name in ("kitti", "euroc", "tum", "synthetic")
    }
    assert ranges == {"kitti": (0.1, 30.0), "euroc": (0.1, 10.0), "tum": (0.0, None), "synthetic": (0.0, None)}
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        cfg = to_run_config(compose(config_name="config"))
    assert cfg.eval.protocol == "full"  # the default keeps every earlier run's numbers


@pytest.mark.parametrize(
    ("args", "says"),
    [
        (["eval.protocol=paper"], "eval.protocol: expected one of full, splatam, released, found 'paper'"),
        (
            ["dataset=kitti", "dataset.eval_depth_far_m=0.05"],
            "dataset.eval_depth_far_m: expected more than eval_depth_near_m (0.1), found 0.05",
        ),
        (["dataset.eval_depth_near_m=-1"], "dataset.eval_depth_near_m: expected a number >= 0, found -1"),
    ],
)
def test_bad_protocol_settings_are_one_line_exit_2(args: list[str], says: str, tmp_path: Path) -> None:
    res = run_cli([*tiny(args), f"hydra.run.dir={tmp_path}/run", *args])
    assert res.code == 2
    assert says in res.error_line
    assert not (tmp_path / "run").exists()


def test_run_table_names_the_protocol_and_ms_ssim() -> None:
    from bench.sweep.summary import run_table

    text = run_table(
        "ok", Path("/runs/a"), {"eval_protocol": "splatam", "psnr_db": 21.5, "ssim": 0.8, "ms_ssim": None}, None
    )
    rows = {line.split()[0]: line.split(None, 1)[1] for line in text.splitlines()}
    assert rows["protocol"] == "splatam"
    assert rows["MS-SSIM"] == "n/a (images under 176 px on a side)"
    assert "protocol" not in run_table("ok", Path("/runs/a"), {"psnr_db": 21.5}, None)  # a run from before protocols
