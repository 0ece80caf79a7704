"""TUM RGB-D loader on a tiny synthetic folder written here (same file formats as the real data)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from bench.datasets import tum
from bench.errors import DatasetError

W, H = 64, 48
RGB_T = [10.000, 10.033, 10.066, 10.100, 10.200]  # the last has no depth within 0.02 s
DEPTH_T = [9.995, 10.040, 10.070, 10.104, 10.150]  # 10.150 has no rgb partner
RAW_DEPTH = [5000, 10000, 2500, 7500]  # -> 1.0, 2.0, 0.5, 1.5 m at depth_scale 5000


def _write_sequence(root: Path, name: str = "rgbd_dataset_freiburg1_test", gt_from_s: float = 9.9) -> Path:
    seq = root / name
    (seq / "rgb").mkdir(parents=True)
    (seq / "depth").mkdir()
    rgb_lines, depth_lines = ["# color images", "# timestamp filename"], ["# depth maps"]
    for k, t in enumerate(RGB_T):
        img = np.zeros((H, W, 3), np.uint8)
        img[..., 2] = 200  # red in BGR order
        img[..., 1] = 10 * k
        cv2.imwrite(str(seq / "rgb" / f"{t:.6f}.png"), img)
        rgb_lines.append(f"{t:.6f} rgb/{t:.6f}.png")
    for k, t in enumerate(DEPTH_T):
        d = np.full((H, W), RAW_DEPTH[k % 4], np.uint16)
        d[:4] = 0  # no reading
        d[4:8] = 60000  # 12 m, beyond max_depth_m
        cv2.imwrite(str(seq / "depth" / f"{t:.6f}.png"), d)
        depth_lines.append(f"{t:.6f} depth/{t:.6f}.png")
    (seq / "rgb.txt").write_text("\n".join(rgb_lines) + "\n")
    (seq / "depth.txt").write_text("\n".join(depth_lines) + "\n")
    gt = ["# ground truth trajectory", "# timestamp tx ty tz qx qy qz qw"]
    half = np.sqrt(0.5)
    for t in np.arange(gt_from_s, 10.3, 0.01):  # 100 Hz, rotated 90 deg about z
        gt.append(f"{t:.4f} {t - 10:.4f} 2.0 -1.0 0 0 {half:.9f} {half:.9f}")
    (seq / "groundtruth.txt").write_text("\n".join(gt) + "\n")
    return seq


@pytest.fixture
def cfg(cfg_of, tmp_path):
    _write_sequence(tmp_path)
    return cfg_of("tum", root=str(tmp_path), seq="rgbd_dataset_freiburg1_test", downscale=1)


def test_association_and_depth_scale(cfg, tmp_path):
    seq = tum.open_sequence(cfg)
    assert len(seq) == 4 and seq.has_gt  # rgb 10.200 has no depth partner
    np.testing.assert_allclose(seq.timestamps_s, RGB_T[:4])
    assert [p.name for p in seq.depth_paths] == [f"{t:.6f}.png" for t in DEPTH_T[:4]]
    for i, metres in enumerate([1.0, 2.0, 0.5, 1.5]):
        frame = seq[i]
        assert frame.depth_m.dtype == torch.float32 and frame.depth_m.shape == (H, W)
        assert frame.depth_m[10, 10].item() == pytest.approx(metres)
        assert (frame.depth_m[:8] == 0).all()  # 0 stays invalid; 12 m > max_depth_m -> 0
        assert frame.rgb.shape == (H, W, 3)
        assert frame.rgb[0, 0, 0].item() == pytest.approx(200 / 255)  # BGR file -> RGB tensor
        assert frame.rgb[0, 0, 1].item() == pytest.approx(10 * i / 255)
    half = tum.open_sequence({**cfg, "depth_scale": 10000.0})
    assert half[0].depth_m[10, 10].item() == pytest.approx(0.5)


def test_intrinsics_gt_and_downscale(cfg):
    seq = tum.open_sequence({**cfg, "seq": "fr1_test", "downscale": 2})  # short alias
    assert seq.name == "tum/rgbd_dataset_freiburg1_test"
    assert (seq.width, seq.height) == (32, 24)
    fx, fy, cx, cy = tum.DEFAULT_INTRINSICS["fr1"]
    expected = [[fx / 2, 0, (cx + 0.5) / 2 - 0.5], [0, fy / 2, (cy + 0.5) / 2 - 0.5], [0, 0, 1]]
    np.testing.assert_allclose(seq.K.numpy(), expected, rtol=1e-6)
    gt = seq[1].gt_c2w
    assert gt.dtype == torch.float64
    np.testing.assert_allclose(gt[:3, 3].numpy(), [0.03, 2.0, -1.0], atol=1e-9)  # nearest pose at 10.03
    np.testing.assert_allclose(gt[:3, :3].numpy(), [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-9)
    assert tum.camera_key("rgbd_dataset_freiburg3_long_office_household") == "fr3"


def test_missing_gt_at_start_drops(cfg_of, tmp_path):
    _write_sequence(tmp_path, gt_from_s=10.06)
    cfg = cfg_of("tum", root=str(tmp_path), seq="rgbd_dataset_freiburg1_test")
    assert len(tum.open_sequence(cfg)) == 2  # rgb 10.000 and 10.033 have no pose within 0.02 s
    with pytest.raises(DatasetError, match="found none for 2 of 4 frames"):
        tum.open_sequence({**cfg, "gt_missing": "error"})
