"""The fidelity and scale options of the backend: each term does what its docstring says, and only when on."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from torchmetrics.functional.image import structural_similarity_index_measure

from bench.datasets.synthetic import open_sequence
from bench.errors import ConfigError
from bench.slam.config import SlamConfig
from bench.slam.frontend import FlowPnpConfig, relative_motion, to_gray_u8
from bench.slam.losses import dssim, ssim_map
from bench.slam.strategy import Strategy
from bench.slam.system import System


@pytest.fixture(scope="module")
def seq():
    return open_sequence({"width": 160, "height": 96, "n_frames": 3})


def _system(seq, **kw) -> System:
    cfg = SlamConfig(**{"tracking_iters": 3, "tracking_iters_first": 3, "mapping_iters": 2, **kw})
    return System(cfg, seq.K, seq.height, seq.width, Strategy(), 0.4, torch.device("cpu"))


def test_ssim_loss_matches_torchmetrics_away_from_the_border():
    """Same window and constants as the evaluation metric; only the padding differs (zero here, reflect there)."""
    g = torch.Generator().manual_seed(0)
    a = torch.rand(40, 56, 3, generator=g)
    b = (a + 0.1 * torch.randn(40, 56, 3, generator=g)).clamp(0, 1)
    ours = ssim_map(a, b)[5:-5, 5:-5]  # [H-10, W-10]
    _, full = structural_similarity_index_measure(
        b.permute(2, 0, 1)[None].double(), a.permute(2, 0, 1)[None].double(), data_range=1.0, return_full_image=True
    )
    ref = full[0].mean(0)[5:-5, 5:-5]
    assert torch.allclose(ours.double(), ref, atol=1e-4), float((ours.double() - ref).abs().max())
    assert float(dssim(a, a)) == pytest.approx(0.0, abs=1e-6)
    assert float(dssim(a, b)) > 0.05


def test_ssim_loss_is_differentiable():
    a = torch.rand(24, 24, 3, requires_grad=True)
    dssim(a, torch.rand(24, 24, 3)).backward()
    assert a.grad is not None and a.grad.abs().sum() > 0


def test_frontend_hands_over_its_inliers(seq):
    f0, f1 = seq[1], seq[2]
    out: list = []
    T, n = relative_motion(
        to_gray_u8(f0.rgb),
        to_gray_u8(f1.rgb),
        f0.depth_m.numpy(),
        seq.K.double().numpy(),
        FlowPnpConfig(),
        inliers_out=out,
    )
    assert T is not None and len(out) == 2
    pts, uv = out
    assert pts.shape == (n, 3) and uv.shape == (n, 2)
    proj = (pts @ T[:3, :3].T + T[:3, 3]) @ seq.K.double().numpy().T
    assert np.abs(proj[:, :2] / proj[:, 2:] - uv).max() < 1.5  # inliers of a 1 px RANSAC threshold


def test_reprojection_term_is_zero_at_the_pose_that_made_it_and_grows_off_it(seq):
    s = _system(seq)
    w2c = torch.eye(4)
    pts = torch.tensor([[0.5, -0.2, 6.0], [-1.0, 0.3, 9.0], [2.0, 0.5, 12.0]])
    cam = pts @ seq.K.T
    uv = cam[:, :2] / cam[:, 2:]
    assert float(s.tracking._reprojection_px((pts, uv), w2c)) == pytest.approx(0.0, abs=1e-4)
    back = torch.eye(4)
    back[2, 3] = 0.5  # the camera half a metre behind
    assert float(s.tracking._reprojection_px((pts, uv), back)) > 0.5  # px, at 160x96


def test_feature_term_changes_tracking_only_when_on(seq):
    poses = []
    for weight in (0.0, 0.0, 1.0):
        s = _system(seq, feature_weight=weight)
        for i in range(3):
            s.step(seq[i])
        poses.append(s.poses[-1])
    assert torch.equal(poses[0], poses[1])
    assert not torch.equal(poses[0], poses[2])


def test_depth_outlier_mask_drops_a_planted_outlier_and_keeps_pixels_without_depth(seq):
    s = _system(seq, tracking_depth_outlier=10.0)
    s.step(seq[0])
    rgb, depth = s.observe(seq[0])
    depth = depth.clone()
    depth[10, 10] = depth[10, 10] + 50.0  # a car that moved on
    depth[20, 20] = 0.0
    with torch.no_grad():
        out = s.render(torch.eye(4))
    mask = out.alpha > s.cfg.silhouette_min
    keep = s.tracking._depth_inliers(out, depth, mask)
    assert not keep[10, 10] and keep[20, 20]
    assert keep[mask & (depth > 0)].float().mean() > 0.5


def test_isotropic_map_keeps_one_scale_per_gaussian_and_anisotropic_does_not(seq):
    spread = {}
    for iso in (True, False):
        s = _system(seq, mapping_iters=10, isotropic=iso)
        for i in range(2):
            s.step(seq[i])
        ls = s.map.log_scales.detach()  # [N, 3]
        spread[iso] = float((ls.max(-1).values - ls.min(-1).values).max())
    assert spread[True] < 1e-5 < 1e-2 < spread[False]


def test_antialiased_render_dims_what_the_plain_one_paints(seq):
    s = _system(seq, mapping_iters=3)
    s.step(seq[0])
    with torch.no_grad():
        plain = s.render(torch.eye(4)).alpha
        s.cfg.raster_antialias = True
        dimmed = s.render(torch.eye(4)).alpha
    assert (dimmed <= plain + 1e-6).all() and dimmed.sum() < plain.sum()


@pytest.mark.parametrize("bad", [{"tracking_depth_outlier": 0.5}, {"feature_weight": -1.0}, {"lambda_ssim_map": 1.5}])
def test_bad_values_are_one_line_errors(bad):
    with pytest.raises(ConfigError, match=f"slam.{next(iter(bad))}: expected"):
        SlamConfig(**bad)


def test_keyframe_rows_carry_the_fit_of_their_own_render(seq):
    s = _system(seq, mapping_iters=5)
    res = s.step(seq[0])
    d = res.diag
    assert 0.0 < d["kf_depth_frac"] <= 1.0
    assert d["kf_psnr_db"] > 5 and d["kf_psnr_depth_db"] > 5
    with torch.no_grad():
        pred = s.render(torch.eye(4)).color.clamp(0, 1)
    mse = float((pred - seq[0].rgb).pow(2).mean().double())
    assert d["kf_psnr_db"] == pytest.approx(-10 * np.log10(mse), abs=1e-3)


def test_faithful_preset_changes_only_what_it_names():
    from bench.cli.entry import compose
    from bench.run.validate import validate

    default = validate(compose([])).config.slam
    faithful = validate(compose(["slam=faithful"])).config.slam
    changed = {k for k in vars(default) if getattr(default, k) != getattr(faithful, k)}
    assert changed == {"name", "densify_stride", "lambda_ssim_map"}  # the corners' term is KITTI's (slam_dataset)
    assert (faithful.densify_stride, faithful.lambda_ssim_map) == (1, 0.2)


def test_faithful_fit_preset_is_the_faithful_one_plus_what_it_names():
    from bench.cli.entry import compose
    from bench.run.validate import validate

    kitti = ["dataset=kitti", "dataset.root=/nowhere"]  # not the synthetic default, whose refine_iters is its own
    faithful = validate(compose(["slam=faithful", *kitti])).config.slam
    fit = validate(compose(["slam=faithful_fit", *kitti])).config.slam
    changed = {k for k in vars(faithful) if getattr(faithful, k) != getattr(fit, k)}
    assert changed == {
        "name", "kf_every", "mapping_fit_psnr_db", "raster_antialias", "refine_iters", "refine_lr_final",
    }  # fmt: skip
    assert (fit.name, fit.kf_every, fit.mapping_iters, fit.raster_antialias, fit.refine_iters, fit.refine_lr_final) == (
        "faithful_fit",
        1,
        100,
        True,
        1000,
        0.01,
    )
    assert (fit.mapping_fit_psnr_db, fit.mapping_fit_max_iters) == (30.0, 300)


def test_a_keyframe_below_the_fit_target_gets_more_iterations_up_to_the_cap(seq):
    """An unreachable target runs to the cap in whole steps; the row records the iterations run."""
    s = _system(seq, mapping_iters=2, mapping_fit_psnr_db=99.0, mapping_fit_step=3, mapping_fit_max_iters=7)
    d = s.step(seq[0]).diag
    assert d["kf_map_iters"] == 7  # 2, then 3, then the 2 left to the cap
    assert d["kf_psnr_depth_db"] < 99.0


def test_a_reached_fit_target_stops_where_it_is_reached(seq):
    """A target below what the first iterations reach adds none: the run is the fixed-count run, bit for bit."""
    fixed = _system(seq, mapping_iters=4)
    target = _system(seq, mapping_iters=4, mapping_fit_psnr_db=1.0, mapping_fit_max_iters=50)
    d_fixed, d_target = fixed.step(seq[0]).diag, target.step(seq[0]).diag
    assert d_fixed["kf_map_iters"] == d_target["kf_map_iters"] == 4
    for k, p in fixed.map.params.items():
        assert torch.equal(p, target.map.params[k])
    for k in ("kf_psnr_db", "kf_psnr_depth_db", "kf_psnr_nodepth_db", "kf_depth_frac"):
        assert d_target[k] == d_fixed[k], k  # the top-up's own score, reused, is the row's own render's


def test_extra_fit_steps_continue_the_run_not_restart_it(seq):
    """4 + 3 + 3 iterations under a target never reached leave the map exactly as 10 iterations in one run:
    Adam's moments are kept and the iterations numbered on (a restart would reset the moments)."""
    one = _system(seq, mapping_iters=10)
    steps = _system(seq, mapping_iters=4, mapping_fit_psnr_db=99.0, mapping_fit_step=3, mapping_fit_max_iters=10)
    one.step(seq[0])
    assert steps.step(seq[0]).diag["kf_map_iters"] == 10
    for k, p in one.map.params.items():
        assert torch.equal(p, steps.map.params[k]), k


def test_a_fit_cap_below_the_fixed_count_is_a_one_line_error():
    with pytest.raises(ConfigError, match=r"slam.mapping_fit_max_iters: expected at least slam.mapping_iters \(150\)"):
        SlamConfig(mapping_iters=150, mapping_fit_psnr_db=30.0, mapping_fit_max_iters=100)
