"""The ``pocketbench`` command: help, shell completion, and configs found from a wheel install."""

from __future__ import annotations

import os
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest
import yaml

from bench.cli.help import help_groups
from bench.conf import CONF_DIR
from tests.conftest import make_venv

REPO = Path(__file__).resolve().parents[1]


def repo_env() -> dict[str, str]:
    """Subprocesses import this checkout's ``bench``, not whichever one is installed."""
    return {**os.environ, "PYTHONPATH": f"{REPO}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}


def test_help_lists_choices_and_examples_not_internal_groups(tmp_path):
    proc = subprocess.run(
        [sys.executable, "-m", "bench", "--help"],
        cwd=tmp_path,
        env=repo_env(),
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    out = proc.stdout
    assert out.startswith("pocketbench: benchmark Gaussian-pruning strategies")
    assert "powered by Hydra" not in out and "slam_dataset" not in out
    strategy_line = next(ln for ln in out.splitlines() if ln.strip().startswith("strategy:"))
    assert all(name in strategy_line for name in ("none", "pocket", "area", "opacity", "gradient", "mask"))
    assert "submitit_local" in out and "pocketbench +experiment=tiny" in out


def test_help_groups_include_installed_plugins(monkeypatch):
    monkeypatch.setattr("bench.slam.strategy.available", lambda: ["pocket", "zz_plugin"])
    assert "zz_plugin" in next(ln for ln in help_groups().splitlines() if "strategy:" in ln)


def test_launcher_configs_share_their_settings():
    slurm = yaml.safe_load((CONF_DIR / "hydra" / "launcher" / "slurm.yaml").read_text())
    local = yaml.safe_load((CONF_DIR / "hydra" / "launcher" / "submitit_local.yaml").read_text())
    for key in ("timeout_min", "cpus_per_task", "tasks_per_node", "mem_gb", "nodes"):
        assert slurm[key] == local[key], key


@pytest.fixture(scope="module")
def wheel_venv(tmp_path_factory) -> Path:
    """A venv holding this checkout built as a wheel, alone (its dependencies come from this run's site)."""
    root = tmp_path_factory.mktemp("wheel")
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
            str(root / "dist"),
            str(REPO),
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert build.returncode == 0, build.stderr[-2000:]
    make_venv(root / "venv")
    wheel = next((root / "dist").glob("pocketbench-*.whl"))
    with zipfile.ZipFile(wheel) as zf:  # the packages only: no profiling/, tests/ or reports/
        top = {name.split("/", 1)[0] for name in zf.namelist()}
    assert top - {"bench", "strategies", "hydra_plugins"} == {f"pocketbench-{wheel.name.split('-')[1]}.dist-info"}, top
    install = subprocess.run(
        [str(root / "venv" / "bin" / "python"), "-m", "pip", "install", "-q", "--no-deps", str(wheel)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert install.returncode == 0, install.stderr[-2000:]
    return root / "venv"


def _venv_env(venv: Path) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    env["PATH"] = f"{venv / 'bin'}{os.pathsep}{env.get('PATH', '')}"
    return env


@pytest.mark.slow
def test_wheel_install_finds_its_configs(wheel_venv, tmp_path):
    env = _venv_env(wheel_venv)
    where = subprocess.run(
        [str(wheel_venv / "bin" / "python"), "-c", "import bench.conf; print(bench.conf.CONF_DIR)"],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert where.stdout.strip().startswith(str(wheel_venv)), where.stdout + where.stderr
    cfg = subprocess.run(
        ["pocketbench", "+strategy=pocket", "dataset=kitti", "--cfg", "job"],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert cfg.returncode == 0, cfg.stderr[-2000:]
    composed = yaml.safe_load(cfg.stdout)
    assert composed["strategy"]["name"] == "pocket" and composed["dataset"]["name"] == "kitti"
    # a user's ./conf is searched ahead of the installed configs (hydra_plugins/pocketbench_searchpath)
    (tmp_path / "conf" / "dataset").mkdir(parents=True)
    (tmp_path / "conf" / "dataset" / "kitti.yaml").write_text(
        "defaults:\n  - /schema/dataset/kitti@_here_\n  - _self_\nroot: /data/my_kitti\n"
    )
    cfg = subprocess.run(
        ["pocketbench", "dataset=kitti", "--cfg", "job"],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert cfg.returncode == 0, cfg.stderr[-2000:]
    assert yaml.safe_load(cfg.stdout)["dataset"]["root"] == "/data/my_kitti"


@pytest.mark.slow
def test_bash_completion_of_the_installed_command(wheel_venv, tmp_path):
    script = (
        'eval "$(pocketbench -sc install=bash)"\n'
        'COMP_LINE="pocketbench +strategy=po"; COMP_POINT=${#COMP_LINE}; COMP_CWORD=1\n'
        "hydra_bash_completion\n"
        'printf "%s\\n" "${COMPREPLY[@]}"\n'
    )
    proc = subprocess.run(
        ["bash", "-c", script], cwd=tmp_path, env=_venv_env(wheel_venv), capture_output=True, text=True, timeout=120
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.split() == ["+strategy=pocket"], proc.stdout + proc.stderr
