"""A third-party package adds a strategy (entry point) and its config (Hydra SearchPathPlugin)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

PLUGIN = '''
from dataclasses import dataclass
from typing import ClassVar

from bench.slam.strategy import Strategy, top_k_keep


@dataclass
class KeepNearest(Strategy):
    """Keeps the Gaussians nearest the camera: a toy third-party rule."""

    description: ClassVar[str] = "toy plugin: keep the nearest Gaussians"
    flip: bool = False

    def after_mapping(self, ctx):
        score = -ctx.raster.depths if not self.flip else ctx.raster.depths
        return top_k_keep(score, ctx.candidates, ctx.n_target)
'''

SEARCH_PATH = """
from hydra.core.config_search_path import ConfigSearchPath
from hydra.plugins.search_path_plugin import SearchPathPlugin


class NearestSearchPath(SearchPathPlugin):
    def manipulate_search_path(self, search_path: ConfigSearchPath) -> None:
        search_path.append(provider="nearest-plugin", path="pkg://nearest_conf")
"""


@pytest.mark.slow
def test_third_party_strategy_with_its_own_config(tmp_path):
    root = tmp_path / "site"
    (root / "nearest_conf" / "strategy").mkdir(parents=True)
    (root / "nearest_conf" / "__init__.py").write_text("")
    (root / "nearest_conf" / "strategy" / "nearest.yaml").write_text("name: nearest\nparams:\n  flip: false\n")
    (root / "nearest_plugin.py").write_text(textwrap.dedent(PLUGIN))
    (root / "hydra_plugins" / "nearest_searchpath").mkdir(parents=True)
    (root / "hydra_plugins" / "nearest_searchpath" / "__init__.py").write_text(textwrap.dedent(SEARCH_PATH))
    dist = root / "nearest_plugin-0.1.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: nearest-plugin\nVersion: 0.1\n")
    (dist / "entry_points.txt").write_text("[pocketbench.strategies]\nnearest = nearest_plugin:KeepNearest\n")
    repo = Path(__file__).resolve().parents[2]  # this checkout's bench, not whichever one is installed
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(root), str(repo), os.environ.get("PYTHONPATH", "")])}
    listed = subprocess.run(
        [sys.executable, "-m", "bench.list_strategies"], env=env, capture_output=True, text=True, timeout=120
    )
    assert "nearest" in listed.stdout and "nearest-plugin" in listed.stdout, listed.stdout + listed.stderr
    run = subprocess.run(
        [
            sys.executable,
            "-m",
            "bench",
            "+strategy=nearest",
            "strategy.params.flip=true",
            "dataset.width=48",
            "dataset.height=32",
            "dataset.n_frames=4",
            "slam.tracking_iters=4",
            "slam.mapping_iters=4",
            "progress=false",
            "eval.lpips=false",
            f"hydra.run.dir={tmp_path}/run",
        ],
        env=env,
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert run.returncode == 0, run.stderr[-2000:]
    stored = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert stored["status"] == "ok" and stored["run"]["strategy"] == "nearest"
    assert "flip: true" in Path(tmp_path / "run" / "config.yaml").read_text()
