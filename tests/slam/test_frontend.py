"""The sparse flow + PnP motion guess against ground-truth relative motion."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from bench.datasets import open_sequence
from bench.datasets.synthetic import open_sequence as open_synthetic
from bench.errors import ConfigError
from bench.slam.config import SlamConfig
from bench.slam.frontend import FlowPnpConfig, relative_motion, to_gray_u8
from bench.slam.strategy import Strategy
from bench.slam.system import System

REPO = Path(__file__).resolve().parents[2]


def _gt_rel(f0, f1) -> np.ndarray:
    """Previous camera -> current camera, [4, 4]."""
    return np.linalg.inv(f1.gt_c2w.numpy()) @ f0.gt_c2w.numpy()


def _guess(f0, f1, K, prior: np.ndarray | None = None) -> tuple[np.ndarray | None, int]:
    return relative_motion(
        to_gray_u8(f0.rgb), to_gray_u8(f1.rgb), f0.depth_m.numpy(), K.double().numpy(), FlowPnpConfig(), prior
    )


def test_recovers_synthetic_motion():
    seq = open_synthetic({"width": 160, "height": 96, "n_frames": 3})
    T, n = _guess(seq[1], seq[2], seq.K)
    gt = _gt_rel(seq[1], seq[2])
    assert T is not None and n >= 30
    moved = np.linalg.norm(gt[:3, 3])
    assert moved > 0.3  # the check means something only if the camera moved
    assert np.linalg.norm(T[:3, 3] - gt[:3, 3]) < 0.1 * moved


@pytest.mark.parametrize("prior_off_m", [0.0, 0.3])
def test_a_velocity_prior_seeds_but_does_not_decide(prior_off_m: float):
    """The constant-velocity prediction starts PnP; a prior 0.3 m off is still corrected by the corners."""
    seq = open_synthetic({"width": 160, "height": 96, "n_frames": 3})
    gt = _gt_rel(seq[1], seq[2])
    prior = gt.copy()
    prior[2, 3] += prior_off_m
    T, _ = _guess(seq[1], seq[2], seq.K, prior)
    assert T is not None
    assert np.linalg.norm(T[:3, 3] - gt[:3, 3]) < 0.05 * np.linalg.norm(gt[:3, 3])


def test_recovers_kitti_motion(shared: Path, tmp_path: Path):
    cfg = {"root": str(shared / "data" / "kitti"), "seq": "06", "last": 1, "cache_dir": str(tmp_path)}
    seq = open_sequence("kitti", cfg)
    T, n = _guess(seq[0], seq[1], seq.K)
    gt = _gt_rel(seq[0], seq[1])
    assert T is not None and n >= 30
    assert np.linalg.norm(gt[:3, 3]) > 1.0  # KITTI 06 drives ~1.2 m per frame
    assert np.linalg.norm(T[:3, 3] - gt[:3, 3]) < 0.1  # measured 0.034 m


def test_textureless_pair_gives_no_guess():
    flat = np.full((32, 48), 128, np.uint8)
    T, n = relative_motion(flat, flat, np.full((32, 48), 5.0), np.eye(3) * 40 + np.diag([0, 0, -39.0]), FlowPnpConfig())
    assert T is None and n == 0


def test_flow_pnp_is_the_default_and_used_on_textured_frames():
    seq = open_synthetic({"width": 96, "height": 64, "n_frames": 3})
    cfg = SlamConfig(tracking_iters=2, tracking_iters_first=2, mapping_iters=1)
    assert cfg.tracking_init == "flow_pnp"
    s = System(cfg, seq.K, seq.height, seq.width, Strategy(), 0.4, torch.device("cpu"))
    for f in seq:
        s.step(f)
    assert s.tracking.init_source == ["flow_pnp", "flow_pnp"]


def test_system_falls_back_to_velocity_without_corners():
    seq = open_synthetic({"width": 48, "height": 32, "n_frames": 3, "supersample": 1})
    cfg = SlamConfig(
        tracking_iters=2,
        tracking_iters_first=2,
        mapping_iters=1,
        tracking_init="flow_pnp",
        flow_pnp={"min_inliers": 10_000},
    )
    s = System(cfg, seq.K, seq.height, seq.width, Strategy(), 0.4, torch.device("cpu"))
    for f in seq:
        s.step(f)
    assert s.tracking.init_source == ["velocity", "velocity"]


@pytest.mark.parametrize(
    ("kw", "msg"),
    [
        ({"tracking_init": "orb"}, "slam.tracking_init: expected one of velocity, flow_pnp, found 'orb'"),
        ({"flow_pnp": {"corners": 5}}, "slam.flow_pnp: expected a setting among .*, found corners"),
        ({"flow_pnp": {"min_inliers": "many"}}, "slam.flow_pnp.min_inliers: expected integer, found 'many'"),
        ({"lrs": {"colour": 0.01}}, "slam.lrs: expected a setting among means.*, found colour"),
    ],
)
def test_bad_settings_are_named(kw, msg):
    with pytest.raises(ConfigError, match=msg):
        SlamConfig(**kw)


def test_partial_learning_rates_keep_the_other_defaults():
    from dataclasses import asdict

    from bench.slam.gaussians import DEFAULT_LRS

    cfg = SlamConfig(lrs={"colors": 0.5})
    assert asdict(cfg.lrs) == {**DEFAULT_LRS, "colors": 0.5}
    assert SlamConfig(flow_pnp={"min_inliers": 7}).flow_pnp.min_inliers == 7  # typed, the other defaults kept
