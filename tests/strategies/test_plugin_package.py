"""The example plugin of docs/writing-a-strategy.md, installed as a package, runs by name without a config file."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from tests.conftest import make_venv

REPO = Path(__file__).resolve().parents[2]
EXAMPLE = REPO / "examples" / "pocketbench-nearest"
TINY = ["dataset.width=48", "dataset.height=32", "dataset.n_frames=4", "slam.tracking_iters=4",
        "slam.mapping_iters=4", "slam.refine_iters=0", "eval.lpips=false"]  # fmt: skip


def test_docs_show_the_example_plugin_verbatim():
    page = (REPO / "docs" / "writing-a-strategy.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", page, flags=re.S)
    assert (EXAMPLE / "nearest_pruning.py").read_text() in blocks
    entry = re.search(r'\[project.entry-points."pocketbench.strategies"\]\nnearest = "[^"]+"', page)
    assert entry and entry.group(0) in (EXAMPLE / "pyproject.toml").read_text()


@pytest.mark.slow
def test_installed_plugin_runs_by_name_without_yaml(tmp_path):
    python = str(make_venv(tmp_path / "venv"))  # sees this run's packages; the plugin is installed on its own
    # built with this interpreter's setuptools (a fresh venv's own may lack bdist_wheel), installed in the venv
    build = subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "wheel",
            "-q",
            "--no-deps",
            "--no-build-isolation",
            "-w",
            str(tmp_path / "dist"),
            str(EXAMPLE),
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert build.returncode == 0, build.stderr[-2000:]
    wheel = next((tmp_path / "dist").glob("pocketbench_nearest-*.whl"))
    install = subprocess.run([python, "-m", "pip", "install", "-q", "--no-deps", str(wheel)], capture_output=True,
                             text=True, timeout=300)  # fmt: skip
    assert install.returncode == 0, install.stderr[-2000:]
    env = {**os.environ, "PYTHONPATH": str(REPO)}  # this checkout's bench; the plugin comes from the venv
    listed = subprocess.run([python, "-m", "bench.list_strategies"], env=env, capture_output=True, text=True,
                            timeout=120, cwd=tmp_path)  # fmt: skip
    assert "nearest" in listed.stdout and "pocketbench-nearest" in listed.stdout, listed.stdout + listed.stderr
    helped = subprocess.run([python, "-m", "bench", "--help"], env=env, capture_output=True, text=True, timeout=120,
                            cwd=tmp_path)  # fmt: skip
    assert "nearest" in next(ln for ln in helped.stdout.splitlines() if "strategy:" in ln)
    run = subprocess.run([python, "-m", "bench", "+strategy=nearest", "strategy.params.depth_power=2.0", *TINY,
                          f"hydra.run.dir={tmp_path}/run"], env=env, cwd=tmp_path, capture_output=True, text=True,
                         timeout=600)  # fmt: skip
    assert run.returncode == 0, run.stderr[-2000:]
    stored = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert stored["status"] == "ok" and stored["run"]["strategy"] == "nearest"
    config = (tmp_path / "run" / "config.yaml").read_text()
    assert "name: nearest" in config and "depth_power: 2.0" in config
