"""Fixtures for the real-data loader tests: conf/dataset/*.yaml overrides, tmp depth caches."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import yaml

REPO = Path(__file__).resolve().parents[2]


def load_cfg(name: str, **overrides: Any) -> dict[str, Any]:
    """bench/conf/dataset/<name>.yaml's own values (the loader's dataclass fills the rest) with ``overrides``."""
    cfg = yaml.safe_load((REPO / "bench" / "conf" / "dataset" / f"{name}.yaml").read_text()) or {}
    cfg.pop("defaults", None)
    cfg.update(overrides)
    return cfg


@pytest.fixture(scope="session")
def cfg_of():
    """The ``load_cfg`` helper (test modules cannot import conftest under --import-mode=importlib)."""
    return load_cfg


@pytest.fixture(scope="session")
def depth_cache(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One depth cache for the session, so each (frame, parameters) is matched only once."""
    return tmp_path_factory.mktemp("depth_cache")


@pytest.fixture
def kitti_cfg(shared: Path, depth_cache: Path) -> dict[str, Any]:
    return load_cfg("kitti", root=str(shared / "data" / "kitti"), seq="06", cache_dir=str(depth_cache))


@pytest.fixture
def euroc_cfg(shared: Path, depth_cache: Path) -> dict[str, Any]:
    return load_cfg("euroc", root=str(shared / "data" / "euroc"), seq="V1_01_micro", cache_dir=str(depth_cache))
