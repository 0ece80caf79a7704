"""Shared fixtures: the read-only real data beside the checkout, and tiny configs."""

from __future__ import annotations

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared"


@pytest.fixture(scope="session")
def shared() -> Path:
    """``../shared`` (real KITTI/EuRoC frames, trajectories, paper tables); skip if absent."""
    if not (SHARED / "data").is_dir():
        pytest.skip(f"real data not found at {SHARED}")
    return SHARED


@pytest.fixture
def euroc_copy(shared: Path, tmp_path: Path) -> Path:
    """A writable EuRoC root in tmp_path: V1_01_micro with images linked and text files copied."""
    import shutil

    src = shared / "data" / "euroc" / "V1_01_micro" / "mav0"
    dst = tmp_path / "euroc" / "V1_01_micro" / "mav0"
    dst.mkdir(parents=True)
    (dst / "state_groundtruth_estimate0").symlink_to(src / "state_groundtruth_estimate0")
    for cam in ("cam0", "cam1"):
        (dst / cam).mkdir()
        (dst / cam / "data").symlink_to(src / cam / "data")
        for name in ("data.csv", "sensor.yaml"):
            shutil.copy(src / cam / name, dst / cam)
    return tmp_path / "euroc"
