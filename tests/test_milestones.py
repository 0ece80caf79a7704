"""Milestones (``eval.at_frames``): one long run scored as if it had ended at each given frame count.

They must not touch the drive: the trajectory and keyframe rows are bit-identical with and without
them, and a run killed between checkpoints resumes to the same milestone rows, none lost or repeated.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pandas as pd
import pytest

from bench.errors import ConfigError
from bench.run.config import EvalConfig
from tests.test_checkpoint import TINY, bench, checkpoint_frames, keyframe_rows

AT = [3, 4, 5, 6, 7, 8, 9, 10, 11, 12]  # every frame of the tiny drive from 3 on: a kill lands between rows


VOLATILE = {"eval_s", "peak_mem_mib"}  # times, and peaks read from the live count (as keyframes.csv's)


def milestone_rows(run_dir: Path, keep: set[str] = frozenset()) -> list[dict[str, str]]:
    with open(run_dir / "milestones.csv", newline="") as fh:
        return [{k: v for k, v in r.items() if k not in VOLATILE - keep} for r in csv.DictReader(fh)]


@pytest.mark.parametrize("bad", [[5, 3], [2, 4], [4, 4], [True]])
def test_at_frames_must_be_increasing_counts(bad: list) -> None:
    with pytest.raises(ConfigError, match=r"eval.at_frames: expected increasing frame counts >= 3"):
        EvalConfig(at_frames=bad)


@pytest.fixture(scope="module")
def pair(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """The same tiny pocket run without and with milestones."""
    root = tmp_path_factory.mktemp("ms")
    dirs = []
    for name, extra in (("plain", []), ("milestones", [f"eval.at_frames=[{','.join(map(str, AT))}]"])):
        run_dir = root / name
        proc = bench([*TINY, "+strategy=pocket", f"hydra.run.dir={run_dir}", *extra], root)
        assert proc.returncode == 0, proc.stderr[-3000:]
        dirs.append(run_dir)
    return dirs[0], dirs[1]


@pytest.mark.slow
def test_milestones_leave_the_drive_bit_identical(pair: tuple[Path, Path]) -> None:
    plain, with_ms = pair
    assert (plain / "traj_est.txt").read_text() == (with_ms / "traj_est.txt").read_text()
    assert keyframe_rows(plain) == keyframe_rows(with_ms)  # memory peaks included: the pause hides the renders
    assert not (plain / "milestones.csv").exists()
    rows = milestone_rows(with_ms, keep={"peak_mem_mib"})
    metrics = json.loads((with_ms / "metrics.json").read_text())["metrics"]
    assert [int(r["frames"]) for r in rows] == [n for n in AT if n <= metrics["num_frames"]]
    last = rows[-1]
    assert int(last["frames"]) == metrics["num_frames"]
    assert float(last["ate_rmse_m"]) == metrics["ate_rmse_m"]  # the whole drive: the same ATE as the run's
    assert float(last["path_length_m"]) == metrics["path_length_m"]
    peaks = [float(r["peak_mem_mib"]) for r in rows]
    assert peaks == sorted(peaks)  # a running maximum
    assert all(float(r["psnr_db"]) > 5 for r in rows)


@pytest.mark.slow
def test_killed_run_resumes_to_the_same_milestone_rows(pair: tuple[Path, Path], tmp_path: Path) -> None:
    _, with_ms = pair
    at = checkpoint_frames(with_ms)
    kill = at[1] - 1  # after the first checkpoint, rows of later milestones are on disk and must be cut
    run_dir = tmp_path / "run"
    args = [*TINY, "+strategy=pocket", f"hydra.run.dir={run_dir}", f"eval.at_frames=[{','.join(map(str, AT))}]"]
    assert bench(args, tmp_path, signal_at=f"{kill}:KILL").returncode == -9
    assert len(milestone_rows(run_dir)) == sum(1 for n in AT if n <= kill + 1)
    resumed = bench(args, tmp_path)
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    assert "resuming" in resumed.stdout + resumed.stderr
    assert milestone_rows(run_dir) == milestone_rows(with_ms)


@pytest.mark.slow
def test_report_of_milestone_runs_has_the_scale_section_and_redraws(pair: tuple[Path, Path], tmp_path: Path) -> None:
    from bench.report.build import make_report, redraw

    plain, with_ms = pair
    out = tmp_path / "report"
    result = make_report([plain, with_ms], out)
    names = {p.name for p in result.files}
    assert {"milestones.csv", "scale.md"} <= names
    assert any(n.startswith("memory_vs_distance_") for n in names)
    assert any(n.startswith("accuracy_vs_distance_") for n in names)
    assert any(n.startswith("pose_error_vs_distance_") for n in names)  # from the trajectories, not redrawn
    text = (out / "scale.md").read_text()
    assert "Gaussians / 100 m" in text and "Ours (w/ Tile Budget)" in text
    assert "No baseline runs at the milestones" in text  # pocket only: no answer is made up
    stored = pd.read_csv(out / "milestones.csv")
    assert len(stored) == len(milestone_rows(with_ms))
    for path in (out / "memory_vs_distance_synthetic_0.png", out / "accuracy_vs_distance_synthetic_0.png"):
        path.unlink()
    redrawn = {p.name for p in redraw(out).files}  # from the folder alone: keyframes.csv and milestones.csv
    assert {"memory_vs_distance_synthetic_0.png", "accuracy_vs_distance_synthetic_0.png"} <= redrawn
