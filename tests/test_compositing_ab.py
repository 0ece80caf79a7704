"""``profiling/compositing_ab.py`` compares today's compositing kernels with a revision's, call by call in one process:
it must run against today's kernel signatures (a change to them would otherwise surface only when someone measures)."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_compositing_ab_compares_today_with_head(tmp_path: Path) -> None:
    head = subprocess.run(["git", "-C", str(REPO), "rev-parse", "HEAD"], capture_output=True, text=True)
    if head.returncode != 0:
        pytest.skip("not a git checkout")
    proc = subprocess.run(
        [
            sys.executable,
            str(REPO / "profiling" / "compositing_ab.py"),
            "--old",
            head.stdout.strip(),
            "--points",
            "300x48x32",
            "--scenes",
            "aniso",
            "--calls",
            "2",
        ],
        cwd=tmp_path,
        text=True,
        capture_output=True,
        timeout=900,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert re.search(r"^aniso 300 48x32: forward x[\d.]+ .* backward x[\d.]+", proc.stdout, re.M), proc.stdout
    assert "forward outputs: acc " in proc.stdout and "backward per-pair gradients: " in proc.stdout, proc.stdout
