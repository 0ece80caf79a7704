"""LightGaussian (opacity) and LP-3DGS (gradient) scores, accumulated in their own state entries."""

from __future__ import annotations

import pytest
import torch

from bench.errors import ConfigError
from bench.slam.strategy import load_strategy
from strategies.gradient import STATE_GRAD_SUM, GradientPruning
from strategies.opacity import STATE_SIGNIFICANCE, OpacityPruning, volume_factor


def test_volume_factor_is_normalised_by_the_90th_percentile_and_clipped():
    vol = torch.arange(1.0, 11.0)  # volumes 1..10: V_90 is the 9th smallest, 9
    log_scales = torch.log(vol)[:, None] * torch.tensor([1.0, 0.0, 0.0])  # prod(exp(log_scales)) = vol
    got = volume_factor(log_scales, 0.9, 0.1)
    want = torch.clamp(vol / 9.0, max=1.0) ** 0.1
    torch.testing.assert_close(got, want)
    assert got[-2:].eq(1.0).all()


def test_opacity_scores_the_mean_over_observing_views(scene):
    idx = scene.add_grid(0, 0, 10) + scene.add_grid(1, 1, 10, opacity=0.3)
    strategy = OpacityPruning(use_volume=False)
    assert STATE_SIGNIFICANCE in strategy.state_spec()
    ctx = scene.context(scene.gaussian_map(strategy))
    per_kf = ctx.gaussians.opacities.detach() * ctx.raster.hit_count.float()  # [N]
    assert (ctx.raster.hit_count[idx] > 0).all()
    strategy.after_mapping(ctx)
    keep = strategy.after_mapping(ctx)  # a second keyframe seeing the same view
    torch.testing.assert_close(ctx.state[STATE_SIGNIFICANCE], 2 * per_kf)
    torch.testing.assert_close(strategy.significance(ctx), per_kf)  # per view, not the sum
    best = torch.topk(per_kf, ctx.n_target).indices
    assert keep[best].all() and int(keep.sum()) == ctx.n_target


def test_opacity_does_not_rank_a_young_gaussian_low_for_its_age(scene):
    old = scene.add_grid(1, 1, 6)  # inside the image: every one hits as many pixels
    strategy = OpacityPruning(use_volume=False)
    g = scene.gaussian_map(strategy)
    for _ in range(3):  # three earlier views of the same Gaussians
        strategy.after_mapping(scene.context(g))
    with torch.no_grad():
        g.params["opacity_logits"][old[0]] = 4.0  # most opaque, but seen only from now on:
    g.state[STATE_SIGNIFICANCE][old[0]] = 0.0  # as if born just before this keyframe
    g.state["opacity_views"][old[0]] = 0.0
    keep = strategy.after_mapping(scene.context(g, keep_ratio=0.5))
    assert keep[old[0]]  # a sum since birth would rank it last


def test_opacity_volume_factor_protects_larger_splats(scene):
    same = dict(opacity=0.5)
    tiny = [scene.add(4.0 + 3 * i, 4.0, sigma_px=0.4, **same) for i in range(4)]
    large = [scene.add(40.0 + 6 * i, 30.0, sigma_px=2.5, **same) for i in range(4)]
    ctx = scene.build(OpacityPruning(), keep_ratio=0.5)
    keep = OpacityPruning().after_mapping(ctx)
    assert keep[large].all() and not keep[tiny].any()


def test_gradient_scores_the_mean_over_observing_frames_and_prunes_the_lowest(scene):
    idx = scene.add_grid(0, 0, 10)
    strategy = GradientPruning()
    ctx = scene.context(scene.gaussian_map(strategy), keep_ratio=0.3)
    g1 = torch.linspace(0.0, 1.0, 10)
    g2 = torch.linspace(1.0, 0.0, 10) * 0.5  # every frame counts, not the last step
    for f, g in enumerate((g1, g2)):
        strategy.on_tracking_step(scene.tracking_context(ctx, g, f))
    torch.testing.assert_close(ctx.state[STATE_GRAD_SUM], g1 + g2)
    torch.testing.assert_close(strategy.score(ctx.state), (g1 + g2) / 2)
    keep = strategy.after_mapping(ctx)
    assert ctx.n_target == 3
    assert keep[idx].tolist() == [False] * 7 + [True] * 3  # (g1 + g2) / 2 = 0.25 + 0.25 i / 9, rising


def test_gradient_ignores_frames_that_did_not_render_the_gaussian(scene):
    idx = scene.add_grid(0, 0, 4)
    off = scene.add(-40.0, 20.0)  # never rendered
    strategy = GradientPruning()
    ctx = scene.context(scene.gaussian_map(strategy))
    assert int(ctx.raster.radius_px[off]) == 0
    strategy.on_tracking_step(scene.tracking_context(ctx, torch.full((5,), 2.0), 0))
    assert strategy.score(ctx.state)[idx].eq(2.0).all() and float(strategy.score(ctx.state)[off]) == 0.0


@pytest.mark.parametrize("params", [{"volume_power": -1.0}, {"volume_quantile": 0.0}, {"use_volume": "yes"}])
def test_opacity_rejects_bad_parameters(params):
    with pytest.raises(ConfigError, match=r"strategy 'opacity'|strategy\.params\.use_volume: expected true or false"):
        load_strategy("opacity", params)
