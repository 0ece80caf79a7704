"""``profiling/score_protocols.py`` rescores a finished run from its run dir alone: its ``full`` score must be the
run's own (else the renders are not the run's), and ``--per-frame`` rows must average to the table's mean."""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from pathlib import Path

import pytest

from tests.test_checkpoint import TINY, bench

REPO = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_rescoring_reproduces_the_run_and_its_frames_average_to_it(tmp_path: Path) -> None:
    run_dir = tmp_path / "run"
    proc = bench([*TINY, "checkpoint.every=0", "dataset.n_frames=4", f"hydra.run.dir={run_dir}"], tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    table, frames = tmp_path / "scores.csv", tmp_path / "frames.csv"
    proc = subprocess.run(
        [sys.executable, str(REPO / "profiling" / "score_protocols.py"), str(run_dir), "--csv", str(table),
         "--per-frame", str(frames)],
        cwd=tmp_path, text=True, capture_output=True, timeout=600,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-3000:]
    stored = json.loads((run_dir / "metrics.json").read_text())["metrics"]
    with table.open(newline="") as fh:
        means = {row["protocol"]: row for row in csv.DictReader(fh)}
    with frames.open(newline="") as fh:
        per_frame = list(csv.DictReader(fh))
    assert set(means) == {"full", "splatam", "released"}
    assert float(means["full"]["psnr_db"]) == pytest.approx(stored["psnr_db"], abs=1e-4)  # map.ply round trip
    for protocol, row in means.items():
        rows = [r for r in per_frame if r["protocol"] == protocol]
        assert len(rows) == int(row["eval_frames"]) >= 2
        mean = sum(float(r["psnr_db"]) for r in rows) / len(rows)
        assert mean == pytest.approx(float(row["psnr_db"]), rel=1e-9), protocol
