"""EuRoC MAV loader on the real V1_01_easy excerpt (40 raw, distorted stereo frames)."""

from __future__ import annotations

import logging
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch
import yaml

from bench.datasets import euroc
from bench.errors import DatasetError


def _sensor(path: Path) -> dict:
    return yaml.safe_load("\n".join(path.read_text().splitlines()[1:]))  # drop %YAML:1.0


def _quat_wxyz_to_rot(w, x, y, z) -> np.ndarray:
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


@pytest.fixture(scope="module")
def mav(shared: Path) -> Path:
    return shared / "data" / "euroc" / "V1_01_micro" / "mav0"


@pytest.fixture(scope="module")
def reference(mav: Path) -> dict:
    """stereoRectify recomputed here from the raw sensor.yaml files, independently of the loader."""
    s0, s1 = _sensor(mav / "cam0" / "sensor.yaml"), _sensor(mav / "cam1" / "sensor.yaml")
    K = [np.array([[f[0], 0, f[2]], [0, f[1], f[3]], [0, 0, 1]]) for f in (s0["intrinsics"], s1["intrinsics"])]
    D = [np.array(s["distortion_coefficients"]) for s in (s0, s1)]
    T_BS0 = np.array(s0["T_BS"]["data"]).reshape(4, 4)
    T_BS1 = np.array(s1["T_BS"]["data"]).reshape(4, 4)
    T = np.linalg.inv(T_BS1) @ T_BS0
    R1, _, P1, P2, *_ = cv2.stereoRectify(
        K[0], D[0], K[1], D[1], (752, 480), T[:3, :3], T[:3, 3:], flags=cv2.CALIB_ZERO_DISPARITY, alpha=0
    )
    return {"R1": R1, "P1": P1, "P2": P2, "T_BS0": T_BS0, "baseline_m": float(np.linalg.norm(T[:3, 3]))}


def test_frames_are_rectified(euroc_cfg, reference):
    seq = euroc.open_sequence({**euroc_cfg, "downscale": 1})
    assert seq.name == "euroc/V1_01_micro" and len(seq) == 40
    assert (seq.width, seq.height) == (752, 480)
    np.testing.assert_allclose(seq.K.numpy(), reference["P1"][:3, :3], rtol=1e-5)
    assert seq.baseline_m == pytest.approx(reference["baseline_m"], rel=1e-3)  # ~0.110 m
    frame = seq[0]
    assert frame.rgb.shape == (480, 752, 3) and torch.equal(frame.rgb[..., 0], frame.rgb[..., 2])
    # Measured: valid fraction 0.80, median depth 2.20 m (the drone sits ~2 m from the padded walls).
    valid = frame.depth_m > 0
    assert 0.6 < valid.float().mean() < 0.95
    assert 1.5 < frame.depth_m[valid].median() < 3.5


def test_downscaled_intrinsics(euroc_cfg, reference):
    seq = euroc.open_sequence(euroc_cfg)  # yaml default downscale 2
    assert (seq.width, seq.height) == (376, 240)
    K = reference["P1"][:3, :3]
    assert seq.K[0, 0].item() == pytest.approx(K[0, 0] / 2, rel=1e-5)
    assert seq.K[1, 2].item() == pytest.approx((K[1, 2] + 0.5) / 2 - 0.5, rel=1e-5)
    assert seq[39].depth_m.shape == (240, 376)


def test_gt_is_rectified_cam0_pose(euroc_cfg, mav, reference):
    seq = euroc.open_sequence(euroc_cfg)
    assert seq.has_gt
    gt = seq.gt_poses.numpy()  # [40, 4, 4]
    rows = np.loadtxt(mav / "state_groundtruth_estimate0" / "data.csv", delimiter=",", comments="#")
    row = rows[0]  # same timestamp as the first image
    R_WB = _quat_wxyz_to_rot(*row[4:8])
    R_BS, t_BS = reference["T_BS0"][:3, :3], reference["T_BS0"][:3, 3]
    # camera orientation = body orientation * T_BS rotation * rectification rotation^T
    np.testing.assert_allclose(R_WB.T @ gt[0, :3, :3] @ reference["R1"], R_BS, atol=1e-5)
    np.testing.assert_allclose(gt[0, :3, 3], row[1:4] + R_WB @ t_BS, atol=1e-6)
    angle = np.degrees(np.arccos((np.trace(R_WB.T @ gt[0, :3, :3]) - 1) / 2))
    assert angle > 80  # the camera looks along body x, a ~90 degree turn from the IMU axes
    assert np.isfinite(gt).all()


def test_timestamps_associate(euroc_cfg, mav):
    seq = euroc.open_sequence(euroc_cfg)
    stamps_ns = np.loadtxt(mav / "cam0" / "data.csv", delimiter=",", comments="#", usecols=0, dtype=np.int64)
    assert len(stamps_ns) == 40 and len(seq) == 40  # 40 image / pose pairs
    np.testing.assert_allclose(seq.timestamps_s, stamps_ns * 1e-9, rtol=0, atol=1e-6)
    assert seq[5].timestamp_s == pytest.approx(stamps_ns[5] * 1e-9, abs=1e-6)
    gt_ns = np.loadtxt(
        mav / "state_groundtruth_estimate0" / "data.csv", delimiter=",", comments="#", usecols=0, dtype=np.int64
    )
    nearest = np.abs(gt_ns[None, :] - stamps_ns[:, None]).min(axis=1)
    assert nearest.max() <= 0.02e9


def test_alias_resolves(euroc_cfg, mav, tmp_path):
    assert euroc.resolve_seq("MH01") == "MH_01_easy" and euroc.resolve_seq("mh_05") == "MH_05_difficult"
    assert euroc.resolve_seq("V101") == "V1_01_easy" and euroc.resolve_seq("V2_03") == "V2_03_difficult"
    (tmp_path / "V1_01_easy").mkdir()
    (tmp_path / "V1_01_easy" / "mav0").symlink_to(mav)
    seq = euroc.open_sequence({**euroc_cfg, "root": str(tmp_path), "seq": "V101", "last": 4})
    assert seq.name == "euroc/V1_01_easy" and len(seq) == 5


def _copy_with_gt_rows(mav: Path, tmp_path: Path, keep_rows: slice) -> Path:
    dst = tmp_path / "V1_01_micro" / "mav0"
    (dst / "state_groundtruth_estimate0").mkdir(parents=True)
    for cam in ("cam0", "cam1"):
        (dst / cam).symlink_to(mav / cam)
    lines = (mav / "state_groundtruth_estimate0" / "data.csv").read_text().splitlines()
    body = lines[1:][keep_rows]
    (dst / "state_groundtruth_estimate0" / "data.csv").write_text("\n".join([lines[0], *body]) + "\n")
    return tmp_path


def test_frames_without_gt_are_dropped_or_raise(euroc_cfg, mav, tmp_path, caplog):
    root = _copy_with_gt_rows(mav, tmp_path, slice(10, None))  # gt starts after the cameras
    with caplog.at_level(logging.WARNING, logger="bench.datasets.euroc"):
        seq = euroc.open_sequence({**euroc_cfg, "root": str(root), "cache_dir": None})
    assert len(seq) == 30 and seq.has_gt
    assert any("dropping 10 of 40 frames" in r.message for r in caplog.records)
    with pytest.raises(DatasetError, match="expected a pose within 0.02 s of every frame"):
        euroc.open_sequence({**euroc_cfg, "root": str(root), "cache_dir": None, "gt_missing": "error"})


def test_no_groundtruth_file(euroc_cfg, mav, tmp_path):
    root = _copy_with_gt_rows(mav, tmp_path, slice(0, 0))
    shutil.rmtree(root / "V1_01_micro" / "mav0" / "state_groundtruth_estimate0")
    seq = euroc.open_sequence({**euroc_cfg, "root": str(root), "cache_dir": None})
    assert len(seq) == 40 and not seq.has_gt and seq.gt_poses is None
