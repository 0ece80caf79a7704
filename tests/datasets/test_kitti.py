"""KITTI odometry loader on the real sequence 06 excerpt (51 grayscale stereo frames)."""

from __future__ import annotations

import logging
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from bench.datasets import FrameSequence, kitti, stereo

FX, CX, CY = 707.0912, 601.8873, 183.1104
# Real calibration of sequences 04-12 for the colour cameras (KITTI data_odometry_calib).
P2 = "7.070912e+02 0 6.018873e+02 4.688783e+01 0 7.070912e+02 1.831104e+02 1.178601e-01 0 0 1 6.203223e-03"
P3 = "7.070912e+02 0 6.018873e+02 -3.334597e+02 0 7.070912e+02 1.831104e+02 1.930130e+00 0 0 1 3.318498e-03"


def test_intrinsics_baseline_and_padding(kitti_cfg):
    seq = kitti.open_sequence({**kitti_cfg, "seq": "6", "downscale": 1})
    assert isinstance(seq, FrameSequence)
    assert seq.name == "kitti/06" and len(seq) == 51
    assert (seq.width, seq.height) == (1226, 370)
    expected = torch.tensor([[FX, 0, CX], [0, FX, CY], [0, 0, 1]], dtype=torch.float32)
    assert seq.K.dtype == torch.float32 and torch.allclose(seq.K, expected)
    assert seq.baseline_m == pytest.approx(379.8145 / 707.0912, abs=1e-6)  # 0.5372 m
    assert kitti.normalize_seq(6) == "06" and kitti.normalize_seq("06") == "06"


def test_default_seq_used_when_seq_is_none(kitti_cfg):
    seq = kitti.open_sequence({**kitti_cfg, "seq": None})
    assert seq.name == "kitti/06"  # the yaml's default_seq


def test_ground_truth(kitti_cfg, shared):
    seq = kitti.open_sequence(kitti_cfg)
    assert seq.has_gt
    gt = seq.gt_poses
    assert gt.shape == (51, 4, 4) and gt.dtype == torch.float64
    assert torch.isfinite(gt).all()
    assert torch.allclose(gt[0], torch.eye(4, dtype=torch.float64), atol=1e-6)
    raw = np.loadtxt(shared / "data" / "kitti" / "poses" / "06.txt").reshape(-1, 3, 4)
    np.testing.assert_allclose(gt[:, :3, :].numpy(), raw)  # gray cam0: KITTI poses as they are
    rot = gt[:, :3, :3]
    assert torch.allclose(rot @ rot.transpose(1, 2), torch.eye(3, dtype=torch.float64).expand(51, 3, 3), atol=1e-5)


def test_stereo_depth_plausible(kitti_cfg):
    """Measured at downscale 4 (306x92): valid 0.674 / 0.694 / 0.674 and median depth
    12.66 / 12.82 / 10.48 m for frames 0 / 25 / 50 (5th-95th percentile ~6-38 m); at full resolution
    valid 0.66-0.68, median 10.4-12.7 m: a suburban street with houses and parked cars."""
    seq = kitti.open_sequence({**kitti_cfg, "downscale": 4})
    assert (seq.width, seq.height) == (306, 92)
    near_m = FX * seq.baseline_m / seq.params.num_disparities  # ~2.97 m
    for i in (0, 25, 50):
        frame = seq[i]
        depth = frame.depth_m
        assert depth.shape == (92, 306) and depth.dtype == torch.float32
        assert frame.rgb.shape == (92, 306, 3) and frame.rgb.dtype == torch.float32
        assert 0.0 <= frame.rgb.min() and frame.rgb.max() <= 1.0
        valid = depth > 0
        assert 0.55 < valid.float().mean() < 0.85
        assert 8.0 < depth[valid].median() < 18.0
        assert depth[valid].min() >= near_m - 1e-3 and depth.max() <= seq.max_depth_m
        assert valid[:, :20].float().mean() < 0.05  # left border: no match within num_disparities
        assert frame.timestamp_s == pytest.approx(0.1039 * i, abs=0.02)  # ~10 Hz


def test_colour_request_falls_back_to_gray(kitti_cfg, caplog):
    with caplog.at_level(logging.INFO, logger="bench.datasets.kitti"):
        seq = kitti.open_sequence({**kitti_cfg, "color": "color"})
    fallback = [r for r in caplog.records if r.name == "bench.datasets.kitti" and "falling back" in r.message]
    assert len(fallback) == 1 and "gray images image_0/image_1" in fallback[0].message
    rgb = seq[0].rgb
    assert torch.equal(rgb[..., 0], rgb[..., 1]) and torch.equal(rgb[..., 1], rgb[..., 2])


def test_downscale_stride_and_range(kitti_cfg, shared):
    seq = kitti.open_sequence({**kitti_cfg, "downscale": 2, "first": 10, "last": 20, "stride": 5})
    assert len(seq) == 3 and (seq.width, seq.height) == (613, 185)
    K = seq.K.double()
    assert K[0, 0].item() == pytest.approx(FX / 2, rel=1e-6)
    assert K[0, 2].item() == pytest.approx((CX + 0.5) / 2 - 0.5, rel=1e-6)
    assert K[1, 2].item() == pytest.approx((CY + 0.5) / 2 - 0.5, rel=1e-6)
    times = np.loadtxt(shared / "data" / "kitti" / "sequences" / "06" / "times.txt")
    raw = np.loadtxt(shared / "data" / "kitti" / "poses" / "06.txt").reshape(-1, 3, 4)
    frame = seq[1]
    assert frame.index == 1 and frame.timestamp_s == pytest.approx(times[15])
    np.testing.assert_allclose(frame.gt_c2w[:3].numpy(), raw[15])
    assert frame.rgb.shape == (185, 613, 3) and frame.depth_m.shape == (185, 613)
    with pytest.raises(IndexError):
        seq[3]


def test_cache_hit_returns_identical_depth(kitti_cfg, tmp_path, monkeypatch):
    cfg = {**kitti_cfg, "cache_dir": str(tmp_path / "cache"), "last": 0}
    seq = kitti.open_sequence(cfg)
    first = seq[0].depth_m
    files = list((tmp_path / "cache").rglob("*.npy"))
    assert len(files) == 1

    def boom(*args, **kwargs):
        raise AssertionError("stereo matching ran despite a cache hit")

    monkeypatch.setattr(stereo, "compute_disparity", boom)
    again = kitti.open_sequence(cfg)[0].depth_m  # a fresh sequence object finds the same key
    assert torch.equal(first, again)
    other = kitti.open_sequence({**cfg, "max_depth_m": 30.0})  # another parameter, another key
    assert other.depth_key(0) != seq.depth_key(0)
    with pytest.raises(AssertionError, match="cache hit"):
        other[0]


def test_cache_keys_images_by_content_not_path_or_mtime(kitti_cfg, tmp_path):
    """A copy of the frames elsewhere, with new mtimes, is the same depth; an image rewritten in place is not."""
    root = Path(kitti_cfg["root"])
    copy = tmp_path / "copy"
    shutil.copytree(root, copy, copy_function=shutil.copy)  # new mtimes
    cfg = {**kitti_cfg, "cache_dir": str(tmp_path / "cache"), "last": 0}
    seq = kitti.open_sequence(cfg)
    moved = kitti.open_sequence({**cfg, "root": str(copy)})
    assert moved.left_paths[0] != seq.left_paths[0]
    assert moved.depth_key(0) == seq.depth_key(0)
    left = moved.left_paths[0]
    st = left.stat()
    os.utime(left, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))  # touched: the same bytes
    assert moved.depth_key(0) == seq.depth_key(0)
    data = bytearray(left.read_bytes())
    data[-1] ^= 0xFF  # the same size, other bytes
    left.write_bytes(bytes(data))
    assert moved.depth_key(0) != seq.depth_key(0)


def test_cache_disabled_writes_nothing(kitti_cfg, tmp_path, monkeypatch):
    monkeypatch.setenv("HOME", str(tmp_path))
    seq = kitti.open_sequence({**kitti_cfg, "cache_dir": None, "last": 0})
    assert seq.cache.root is None and seq.cache.path("ab" * 32) is None
    seq.cache.save("ab" * 32, np.zeros((2, 2), np.float32))  # no-op
    assert not any(tmp_path.rglob("*.npy"))


def _colour_copy(shared: Path, tmp_path: Path) -> Path:
    """A KITTI root whose sequence 06 has only image_2/image_3 (the gray frames) + P2/P3."""
    src = shared / "data" / "kitti"
    seq = tmp_path / "kitti" / "sequences" / "06"
    seq.mkdir(parents=True)
    (seq / "image_2").symlink_to(src / "sequences" / "06" / "image_0")
    (seq / "image_3").symlink_to(src / "sequences" / "06" / "image_1")
    shutil.copy(src / "sequences" / "06" / "times.txt", seq)
    (seq / "calib.txt").write_text(f"P2: {P2}\nP3: {P3}\n")
    (tmp_path / "kitti" / "poses").mkdir()
    shutil.copy(src / "poses" / "06.txt", tmp_path / "kitti" / "poses")
    return tmp_path / "kitti"


def test_colour_camera_gt_and_baseline(kitti_cfg, shared, tmp_path, caplog):
    root = _colour_copy(shared, tmp_path)
    with caplog.at_level(logging.INFO, logger="bench.datasets.kitti"):
        seq = kitti.open_sequence({**kitti_cfg, "root": str(root), "cache_dir": None})
    assert any("using color images image_2/image_3" in r.message for r in caplog.records)
    P2m = np.array(P2.split(), float).reshape(3, 4)
    P3m = np.array(P3.split(), float).reshape(3, 4)
    t2 = np.linalg.solve(P2m[:, :3], P2m[:, 3])  # cam2 = cam0 shifted by -t2 (~6 cm left)
    t3 = np.linalg.solve(P3m[:, :3], P3m[:, 3])
    assert seq.baseline_m == pytest.approx(t2[0] - t3[0]) and 0.53 < seq.baseline_m < 0.54
    assert -P2m[0, 3] / P2m[0, 0] == pytest.approx(-t2[0], abs=0.01)  # the usual approximation
    gt = seq.gt_poses.numpy()
    raw = np.loadtxt(root / "poses" / "06.txt").reshape(-1, 3, 4)
    np.testing.assert_allclose(gt[:, :3, :3], raw[:, :, :3])  # rectified cameras share orientation
    np.testing.assert_allclose(gt[:, :3, 3], raw[:, :, 3] - np.einsum("nij,j->ni", raw[:, :, :3], t2))
    assert gt[0, 0, 3] == pytest.approx(-0.061, abs=0.002)


def test_sequence_without_poses_has_no_gt(kitti_cfg, shared, tmp_path):
    root = _colour_copy(shared, tmp_path)
    (root / "poses" / "06.txt").unlink()
    seq = kitti.open_sequence({**kitti_cfg, "root": str(root), "cache_dir": None, "last": 0})
    assert not seq.has_gt and seq.gt_poses is None
    assert seq[0].gt_c2w is None


def test_plugin_lookup_with_omegaconf(kitti_cfg):
    from omegaconf import OmegaConf

    from bench.datasets import open_sequence

    cfg = OmegaConf.create({**kitti_cfg, "seq": 6, "last": 2})  # Hydra turns dataset.seq=06 into 6
    seq = open_sequence("kitti", cfg)
    assert seq.name == "kitti/06" and len(seq) == 3
    assert cfg.seq == 6  # the caller's config is not modified
