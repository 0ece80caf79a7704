"""Depth helpers: disparity -> depth, valid-aware downscale, intrinsics scaling, cache files."""

from __future__ import annotations

import numpy as np
import pytest

from bench.config.settings import as_config
from bench.datasets import realio
from bench.datasets.stereo import DepthCache, StereoParams, disparity_to_depth
from bench.errors import ConfigError


def test_disparity_to_depth_masks_invalid_and_far():
    disp = np.array([[-1.0, 0.0, 10.0, 1.0]], np.float32)
    depth = disparity_to_depth(disp, fx_px=700.0, baseline_m=0.5, max_depth_m=100.0)
    np.testing.assert_allclose(depth, [[0, 0, 35.0, 0]])  # 350 m at 1 px is beyond 100 m


def test_downscale_depth_takes_a_measured_value_and_needs_half_valid():
    d = np.zeros((4, 6), np.float32)
    d[:2, :2] = [[1.0, 1.0], [9.0, 9.0]]  # an edge: lower median 1.0, never the 5.0 mean
    d[:2, 2:4] = [[3.0, 0.0], [0.0, 0.0]]  # 1 of 4 valid -> invalid
    d[2:, :2] = [[2.0, 4.0], [0.0, 8.0]]  # 3 of 4 valid -> median 4.0
    out = realio.downscale_depth(d, 2)
    assert out.shape == (2, 3)
    np.testing.assert_allclose(out, [[1.0, 0.0, 0.0], [4.0, 0.0, 0.0]])


def test_scale_k_keeps_pixel_centres():
    K = np.array([[100.0, 0, 49.5], [0, 100.0, 29.5], [0, 0, 1]])
    K2 = realio.scale_K(K, 2)  # the centre of a 100x60 image stays the centre of the 50x30 one
    np.testing.assert_allclose(K2, [[50.0, 0, 24.5], [0, 50.0, 14.5], [0, 0, 1]])


def test_cache_roundtrip_and_bad_entries(tmp_path):
    cache = DepthCache(tmp_path, "kitti")
    key = DepthCache.key({"left": "a.png", "n": 1})
    assert key != DepthCache.key({"left": "a.png", "n": 2})
    depth = np.arange(6, dtype=np.float32).reshape(2, 3)
    assert cache.load(key, (2, 3)) is None
    cache.save(key, depth)
    np.testing.assert_array_equal(cache.load(key, (2, 3)), depth)
    assert cache.load(key, (3, 2)) is None  # wrong shape: recompute
    cache.path(key).write_bytes(b"garbage")
    assert cache.load(key, (2, 3)) is None
    assert not list(tmp_path.rglob("*.tmp"))


def test_stereo_params_validation():
    assert as_config(StereoParams, {"num_disparities": 64}).num_disparities == 64
    with pytest.raises(ConfigError, match="multiple of 16"):
        as_config(StereoParams, {"num_disparities": 50})
    with pytest.raises(ConfigError, match="found blocksize"):
        as_config(StereoParams, {"blocksize": 5})
