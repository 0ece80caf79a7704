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


@pytest.fixture
def make_kitti_copy(shared: Path, tmp_path: Path):
    """``make(n_frames=None) -> root``: a writable KITTI 06 in tmp_path (images linked, text files cut to n)."""

    def make(n_frames: int | None = None) -> Path:
        src = shared / "data" / "kitti"
        seq = tmp_path / "kitti" / "sequences" / "06"
        seq.mkdir(parents=True)
        for cam in ("image_0", "image_1"):
            (seq / cam).mkdir()
            for png in sorted((src / "sequences" / "06" / cam).glob("*.png"))[:n_frames]:
                (seq / cam / png.name).symlink_to(png)
        (seq / "calib.txt").write_text((src / "sequences" / "06" / "calib.txt").read_text())
        for name, path in (("times.txt", seq / "times.txt"), ("06.txt", tmp_path / "kitti" / "poses" / "06.txt")):
            lines = (src / ("sequences/06" if name == "times.txt" else "poses") / name).read_text().splitlines(True)
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text("".join(lines[:n_frames]))
        return tmp_path / "kitti"

    return make
