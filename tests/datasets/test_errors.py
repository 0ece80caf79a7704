"""Bad input: every known problem is a single-line DatasetError naming what was expected and found.

Each test builds a copy of the real data in tmp_path (images symlinked, text files copied) and
breaks one thing.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from bench.datasets import euroc, kitti, tum
from bench.errors import DatasetError


def _one_line(exc: pytest.ExceptionInfo[DatasetError], *parts: str) -> str:
    msg = str(exc.value)
    assert "\n" not in msg and msg[:1].islower(), msg
    assert "expected" in msg, msg
    for part in parts:
        assert part in msg, msg
    return msg


@pytest.fixture
def kitti_copy(shared: Path, tmp_path: Path) -> Path:
    src = shared / "data" / "kitti"
    seq = tmp_path / "kitti" / "sequences" / "06"
    seq.mkdir(parents=True)
    (seq / "image_1").symlink_to(src / "sequences" / "06" / "image_1")
    (seq / "image_0").mkdir()
    for png in sorted((src / "sequences" / "06" / "image_0").glob("*.png")):
        (seq / "image_0" / png.name).symlink_to(png)
    for name in ("calib.txt", "times.txt"):
        shutil.copy(src / "sequences" / "06" / name, seq)
    (tmp_path / "kitti" / "poses").mkdir()
    shutil.copy(src / "poses" / "06.txt", tmp_path / "kitti" / "poses")
    return tmp_path / "kitti"


@pytest.fixture
def kcfg(kitti_cfg: dict, kitti_copy: Path) -> dict:
    return {**kitti_cfg, "root": str(kitti_copy), "cache_dir": None}


def test_copy_is_valid(kcfg):
    assert len(kitti.open_sequence(kcfg)) == 51


def test_missing_root(kcfg, tmp_path):
    with pytest.raises(DatasetError) as exc:
        kitti.open_sequence({**kcfg, "root": str(tmp_path / "nowhere")})
    _one_line(exc, "kitti root not found", str(tmp_path / "nowhere"), "see datasets/kitti/README.md")


def test_missing_sequence(kcfg, kitti_copy):
    with pytest.raises(DatasetError) as exc:
        kitti.open_sequence({**kcfg, "seq": "10"})
    sequences = kitti_copy / "sequences"
    assert str(exc.value) == (
        f"kitti sequence '10' not found: expected {sequences}/10/image_2 or image_0; "
        f"{sequences} has: 06; see datasets/kitti/README.md"
    )
    _one_line(exc)


def test_truncated_poses(kcfg, kitti_copy):
    poses = kitti_copy / "poses" / "06.txt"
    poses.write_text("".join(poses.read_text().splitlines(keepends=True)[:50]))
    with pytest.raises(DatasetError) as exc:
        kitti.open_sequence(kcfg)
    _one_line(exc, str(poses), "expected 51 poses", "found 50")


def test_pose_line_with_missing_number(kcfg, kitti_copy):
    poses = kitti_copy / "poses" / "06.txt"
    lines = poses.read_text().splitlines()
    lines[2] = " ".join(lines[2].split()[:11])
    poses.write_text("\n".join(lines) + "\n")
    with pytest.raises(DatasetError) as exc:
        kitti.open_sequence(kcfg)
    _one_line(exc, "line 3", "expected 12 numbers, found 11")


def test_non_finite_pose(kcfg, kitti_copy):
    poses = kitti_copy / "poses" / "06.txt"
    lines = poses.read_text().splitlines()
    lines[7] = " ".join(["nan", *lines[7].split()[1:]])
    poses.write_text("\n".join(lines) + "\n")
    with pytest.raises(DatasetError) as exc:
        kitti.open_sequence(kcfg)
    _one_line(exc, str(poses), "line 8", "expected finite numbers, found nan")


def test_times_count_mismatch(kcfg, kitti_copy):
    times = kitti_copy / "sequences" / "06" / "times.txt"
    times.write_text("".join(times.read_text().splitlines(keepends=True)[:40]))
    with pytest.raises(DatasetError) as exc:
        kitti.open_sequence(kcfg)
    _one_line(exc, str(times), "expected 51 lines", "found 40")


def test_image_count_mismatch(kcfg, kitti_copy):
    (kitti_copy / "sequences" / "06" / "image_0" / "000050.png").unlink()
    with pytest.raises(DatasetError) as exc:
        kitti.open_sequence(kcfg)
    _one_line(exc, "image_0 and image_1", "found 50 and 51")


def test_missing_calib(kcfg, kitti_copy):
    calib = kitti_copy / "sequences" / "06" / "calib.txt"
    calib.unlink()
    with pytest.raises(DatasetError) as exc:
        kitti.open_sequence(kcfg)
    _one_line(exc, f"expected {calib}", "image_0, image_1, times.txt", "see datasets/kitti/README.md")


def test_malformed_calib(kcfg, kitti_copy):
    calib = kitti_copy / "sequences" / "06" / "calib.txt"
    lines = calib.read_text().splitlines()
    calib.write_text(lines[0] + "\n" + " ".join(lines[1].split()[:-1]) + "\n")
    with pytest.raises(DatasetError) as exc:
        kitti.open_sequence(kcfg)
    _one_line(exc, str(calib), "line 2", "12 finite numbers after 'P1:'", "found 11 values")
    calib.write_text(lines[0] + "\n")
    with pytest.raises(DatasetError) as exc:
        kitti.open_sequence(kcfg)
    _one_line(exc, "expected P1", "found keys P0")


def test_corrupt_png(kcfg, kitti_copy):
    bad = kitti_copy / "sequences" / "06" / "image_0" / "000003.png"
    bad.unlink()
    bad.write_bytes(b"\x89PNG\r\n\x1a\n" + b"\x00" * 40)  # a PNG signature and nothing usable
    seq = kitti.open_sequence(kcfg)  # lazy: only frame 0 is read at open
    with pytest.raises(DatasetError) as exc:
        seq[3]
    _one_line(exc, "image unreadable", str(bad), "found 48 bytes")


def test_euroc_missing_sequence(euroc_cfg, shared):
    with pytest.raises(DatasetError) as exc:
        euroc.open_sequence({**euroc_cfg, "seq": "MH01"})
    root = (shared / "data" / "euroc").resolve()  # the message names the resolved root (shared may be a link)
    _one_line(exc, "euroc sequence 'MH01' (alias of MH_01_easy) not found", str(root / "MH_01_easy" / "mav0"))
    assert "has: V1_01_micro" in str(exc.value)


@pytest.mark.parametrize(
    ("old", "new", "parts"),
    [
        (
            "intrinsics: [458.654, 457.296, 367.215, 248.375]",
            "intrinsics: [458.654, 457.296, 367.215]",
            ["key 'intrinsics'", "expected 4 finite numbers, found 3"],
        ),
        ("intrinsics:", "intrinsic:", ["expected key 'intrinsics'", "found keys"]),
        ("distortion_model: radial-tangential", "distortion_model: equidistant", ["found 'equidistant'"]),
        ("rows: 4", "rows: [4", ["expected valid yaml"]),
    ],
)
def test_bad_sensor_yaml(euroc_cfg, euroc_copy, old, new, parts):
    root = euroc_copy
    sensor = root / "V1_01_micro" / "mav0" / "cam0" / "sensor.yaml"
    text = sensor.read_text()
    assert old in text
    sensor.write_text(text.replace(old, new))
    with pytest.raises(DatasetError) as exc:
        euroc.open_sequence({**euroc_cfg, "root": str(root), "cache_dir": None})
    _one_line(exc, f"euroc sensor.yaml {sensor}", *parts)


def test_euroc_csv_and_images_disagree(euroc_cfg, euroc_copy):
    root = euroc_copy
    csv = root / "V1_01_micro" / "mav0" / "cam1" / "data.csv"
    csv.write_text("".join(csv.read_text().splitlines(keepends=True)[:-3]))
    with pytest.raises(DatasetError) as exc:
        euroc.open_sequence({**euroc_cfg, "root": str(root), "cache_dir": None})
    _one_line(exc, str(csv), "(37)", "found 40")


def test_tum_missing_sequence_and_bad_depth(cfg_of, tmp_path):
    import cv2
    import numpy as np

    with pytest.raises(DatasetError) as exc:
        tum.open_sequence(cfg_of("tum", root=str(tmp_path), seq="fr1_desk"))
    _one_line(exc, "tum sequence 'fr1_desk' not found", "rgbd_dataset_freiburg1_desk/rgb.txt", "has: (empty)")

    seq = tmp_path / "rgbd_dataset_freiburg1_desk"
    seq.mkdir()
    cv2.imwrite(str(seq / "c.png"), np.zeros((8, 8, 3), np.uint8))
    cv2.imwrite(str(seq / "d.png"), np.zeros((8, 8), np.uint8))  # 8-bit, not 16-bit
    (seq / "rgb.txt").write_text("1.0 c.png\n")
    with pytest.raises(DatasetError) as exc:
        tum.open_sequence(cfg_of("tum", root=str(tmp_path), seq="fr1_desk"))
    _one_line(exc, "tum depth list missing", "found c.png, d.png, rgb.txt")
    (seq / "depth.txt").write_text("1.001 d.png\n")
    opened = tum.open_sequence(cfg_of("tum", root=str(tmp_path), seq="fr1_desk", downscale=1))
    assert not opened.has_gt
    with pytest.raises(DatasetError) as exc:
        opened[0]
    _one_line(exc, "expected a 16-bit single-channel png, found uint8")
