"""``profiling/loop_profile.py`` runs against today's kernels: its timers wrap functions by name, and a rename
in ``bench/slam/raster_fused/`` once left it failing at import while no test ran it."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_loop_profile_times_each_part_of_an_iteration(tmp_path: Path) -> None:
    overrides = "+experiment=tiny dataset.n_frames=4 slam.refine_iters=5 threads=1 eval.lpips=false"
    proc = subprocess.run(
        [sys.executable, str(REPO / "profiling" / "loop_profile.py"), "--overrides", overrides],
        cwd=tmp_path,
        text=True,
        capture_output=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    out = proc.stdout
    assert "status=ok" in out
    for phase in ("tracking", "mapping", "refine"):
        block = out.split(f"one {phase} iteration", 1)
        assert len(block) == 2, f"no per-iteration table for {phase}:\n{out}"
        rows = dict(re.findall(r"^\s+(raster_fwd|raster_bwd)\s+([\d.]+)", block[1], re.M))
        # the wrapped kernels were hit: a wrapper on a stale name would leave these at zero
        assert float(rows["raster_fwd"]) > 0 and float(rows["raster_bwd"]) > 0, block[1][:600]
