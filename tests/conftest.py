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


def make_venv(path: Path) -> Path:
    """A new venv at ``path`` that sees this test run's installed packages, returning its interpreter.

    ``venv --system-site-packages`` would expose the *base* interpreter's site, which is not where the
    dependencies live when the tests themselves run in a venv (the README's set-up) or a conda env. A ``.pth``
    file listing the running interpreter's site directories works for all three. Its lines only extend
    ``sys.path``: ``.pth`` files inside those directories (an editable install of this checkout among them) are
    not processed, so the package under test is whatever the new venv installs itself.
    """
    import site
    import subprocess
    import sys

    subprocess.run([sys.executable, "-m", "venv", str(path)], check=True, timeout=300)
    python = path / "bin" / "python"
    target = subprocess.run(
        [str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
        check=True,
        capture_output=True,
        text=True,
        timeout=60,
    ).stdout.strip()
    dirs = [*site.getsitepackages(), site.getusersitepackages()]
    (Path(target) / "_outer_site.pth").write_text("".join(f"{d}\n" for d in dirs if Path(d).is_dir()))
    return python
