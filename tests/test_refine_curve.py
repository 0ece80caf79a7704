"""The final refinement's curve (``eval.at_refine_iters``): the map scored part-way through the refinement.

The curve must not touch the refinement: the map it ends with, and every metric, are bit-identical with and
without it, and its last row is the run's own image score when it names the last iteration.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

from bench.errors import ConfigError
from bench.run.config import EvalConfig, compose, to_run_config
from tests.test_checkpoint import TINY, bench

AT = [5, 17, 30]  # the tiny preset refines 30 iterations


def curve_rows(run_dir: Path) -> list[dict[str, str]]:
    with open(run_dir / "refine_curve.csv", newline="") as fh:
        return list(csv.DictReader(fh))


@pytest.mark.parametrize("bad", [[5, 3], [0, 4], [4, 4], [True]])
def test_at_refine_iters_must_be_increasing_counts(bad: list) -> None:
    with pytest.raises(ConfigError, match=r"eval.at_refine_iters: expected increasing iteration counts >= 1"):
        EvalConfig(at_refine_iters=bad)


def test_at_refine_iters_cannot_pass_the_refinement() -> None:
    with pytest.raises(ConfigError, match=r"up to slam.refine_iters=30, found \[10, 40\]"):
        to_run_config(compose(["+experiment=tiny", "eval.at_refine_iters=[10,40]"]))


@pytest.fixture(scope="module")
def pair(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """The same tiny run without and with the curve."""
    root = tmp_path_factory.mktemp("rc")
    dirs = []
    for name, extra in (("plain", []), ("curve", [f"eval.at_refine_iters=[{','.join(map(str, AT))}]"])):
        run_dir = root / name
        proc = bench([*TINY, "checkpoint.every=0", f"hydra.run.dir={run_dir}", *extra], root)
        assert proc.returncode == 0, proc.stderr[-3000:]
        dirs.append(run_dir)
    return dirs[0], dirs[1]


@pytest.mark.slow
def test_the_curve_leaves_the_refined_map_bit_identical(pair: tuple[Path, Path]) -> None:
    plain, curve = pair
    assert (plain / "map.ply").read_bytes() == (curve / "map.ply").read_bytes()
    got, want = (json.loads((d / "metrics.json").read_text())["metrics"] for d in (curve, plain))
    for key in ("psnr_db", "ssim", "ate_rmse_m", "gaussians_final"):
        assert got[key] == want[key], key
    assert not (plain / "refine_curve.csv").exists()


@pytest.mark.slow
def test_one_row_per_entry_and_the_last_is_the_runs_score(pair: tuple[Path, Path]) -> None:
    _, curve = pair
    rows = curve_rows(curve)
    metrics = json.loads((curve / "metrics.json").read_text())["metrics"]
    assert [int(r["refine_iters"]) for r in rows] == AT
    assert float(rows[-1]["psnr_db"]) == pytest.approx(metrics["psnr_db"], abs=1e-12)
    assert float(rows[-1]["ssim"]) == pytest.approx(metrics["ssim"], abs=1e-12)
    assert int(rows[-1]["eval_frames"]) == metrics["eval_frames"]
    assert float(rows[0]["psnr_db"]) != float(rows[-1]["psnr_db"])  # the map moved between them
    times = [float(r["refine_s"]) for r in rows]
    assert times == sorted(times) and times[-1] <= metrics["refine_s"] + 1e-3
