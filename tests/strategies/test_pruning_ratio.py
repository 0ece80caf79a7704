"""Every strategy against the shared pruning ratio on one hand-built scene, and new-Gaussian exemption."""

from __future__ import annotations

import dataclasses
import math

import pytest
import torch

from bench.slam.strategy import PruneContext, Strategy, load_strategy

BUILT_INS = ["none", "pocket", "area", "opacity", "gradient", "mask"]


def mixed_scene(scene) -> dict[str, list[int]]:
    """Candidates in four tiles with varied sizes and gradients, Gaussians off-image, and new ones."""
    g = torch.Generator().manual_seed(0)
    groups: dict[str, list[int]] = {}
    for name, (tx, ty, n, grad) in {
        "t0": (0, 0, 14, 0.5),
        "t6": (2, 1, 9, 2.0),
        "t11": (3, 2, 20, 1.0),
        "t4": (0, 1, 3, 0.1),
    }.items():
        groups[name] = scene.add_grid(tx, ty, n, grad=grad, sigma_px=float(torch.rand((), generator=g)) * 2 + 0.5)
    groups["off"] = [scene.add(-4.0, 20.0), scene.add(20.0, 60.0)]
    groups["new"] = [scene.add(20.0 + i, 20.0, new=True, grad=50.0) for i in range(4)]
    return groups


def prepared(scene, name: str, keep_ratio: float = 0.4) -> tuple[Strategy, PruneContext]:
    strategy = load_strategy(name)
    ctx = scene.context(scene.gaussian_map(strategy), keep_ratio)
    for f in range(3):  # what tracking would have accumulated
        grad = torch.linspace(0.1, 2.0, len(ctx.gaussians)).roll(7 * f)
        strategy.on_tracking_step(scene.tracking_context(ctx, grad, f))
    return strategy, ctx


@pytest.mark.parametrize("name", ["area", "opacity", "gradient"])
@pytest.mark.parametrize("keep_ratio", [0.4, 0.25, 1.0])
def test_global_strategies_keep_exactly_n_target_candidates(scene, name, keep_ratio):
    groups = mixed_scene(scene)
    strategy, ctx = prepared(scene, name, keep_ratio)
    assert int(ctx.candidates.sum()) == 46
    keep = strategy.after_mapping(ctx)
    assert keep.dtype == torch.bool and keep.shape == ctx.candidates.shape
    assert int((keep & ctx.candidates).sum()) == ctx.n_target == math.ceil(keep_ratio * 46)
    assert keep[~ctx.candidates].all()
    assert keep[groups["off"]].all() and keep[groups["new"]].all()


@pytest.mark.parametrize("keep_ratio", [0.4, 0.1])
def test_pocket_keeps_the_sum_of_capped_tile_budgets(scene, budgets, keep_ratio):
    groups = mixed_scene(scene)
    strategy, ctx = prepared(scene, "pocket", keep_ratio)
    grads = {0: [0.5] * 14, 6: [2.0] * 9, 11: [1.0] * 20, 4: [0.1] * 3}
    n_k = {k: len(v) for k, v in grads.items()}
    hand = budgets(ctx.n_target, grads)
    keep = strategy.after_mapping(ctx)
    assert int((keep & ctx.candidates).sum()) == sum(min(hand[k], n_k[k]) for k in hand)
    for name, k in (("t0", 0), ("t6", 6), ("t11", 11), ("t4", 4)):
        assert int(keep[groups[name]].sum()) == min(hand[k], n_k[k]), name
    assert keep[groups["off"]].all() and keep[groups["new"]].all()


def test_none_never_prunes(scene):
    mixed_scene(scene)
    strategy, ctx = prepared(scene, "none")
    assert strategy.after_mapping(ctx) is None


def test_learned_mask_ignores_the_keep_ratio(scene):
    mixed_scene(scene)
    _, ctx = prepared(scene, "mask", keep_ratio=0.1)
    strategy = load_strategy("mask", {"select": "learned"})
    assert strategy.after_mapping(ctx).all()  # nothing masked yet: nothing deleted, whatever N_tar says


@pytest.mark.parametrize("keep_ratio", [0.4, 0.1])
def test_mask_masks_all_but_n_target_candidates(scene, keep_ratio):
    groups = mixed_scene(scene)
    _, ctx = prepared(scene, "mask", keep_ratio)
    strategy = load_strategy("mask", {"masked_keyframes": 1})
    keep = strategy.after_mapping(ctx)
    assert int((keep & ctx.candidates).sum()) == ctx.n_target
    assert keep[groups["off"]].all() and keep[groups["new"]].all()


def test_a_budget_per_megapixel_scales_with_the_image():
    from bench.slam.strategy import PruneConfig

    per_mpx = PruneConfig(target="absolute", n_target_per_mpx=60_000 / (752 * 480 / 1e6))
    assert per_mpx.target_count((480, 752)) == 60_000  # the released EuRoC budget at its own resolution
    assert per_mpx.target_count((240, 376)) == 15_000  # a quarter of the pixels, a quarter of the Gaussians
    assert PruneConfig(target="absolute", n_target=80_000).target_count((96, 160)) == 80_000  # a count stays a count
    assert PruneConfig().target_count((480, 752)) is None  # the ratio target


def test_the_budget_floor_is_one_view_per_pixel_where_the_budget_is_lower():
    from bench.slam.strategy import PruneConfig

    floored = PruneConfig(target="absolute", n_target_per_mpx=166_223, n_target_floor_per_px=1.0)
    assert floored.target_count((120, 160)) == 160 * 120  # the budget (3,191) under one view's pixels
    assert floored.target_count((480, 752)) == 752 * 480  # and still at full size: 60,000 < 360,960
    assert PruneConfig(target="absolute", n_target=500_000, n_target_floor_per_px=1.0).target_count((480, 752)) == (
        500_000  # a budget above the floor is the budget
    )


def test_random_keeps_n_target_candidates_drawn_by_the_seed(scene):
    groups = mixed_scene(scene)
    strategy, ctx = prepared(scene, "random", 0.4)
    keep = strategy.after_mapping(ctx)
    assert int((keep & ctx.candidates).sum()) == ctx.n_target == math.ceil(0.4 * 46)
    assert keep[~ctx.candidates].all() and keep[groups["new"]].all()
    assert torch.equal(keep, strategy.after_mapping(ctx))  # same seed and keyframe: the same subset
    other_seed = strategy.after_mapping(dataclasses.replace(ctx, seed=ctx.seed + 1))
    other_kf = strategy.after_mapping(dataclasses.replace(ctx, keyframe_index=ctx.keyframe_index + 1))
    assert not torch.equal(keep, other_seed) and not torch.equal(keep, other_kf)


def test_random_draws_every_candidate_alike(scene):
    """Uniform: over many keyframes each candidate is kept about n_target / candidates of the time."""
    mixed_scene(scene)
    strategy, ctx = prepared(scene, "random", 0.4)
    kept = sum(strategy.after_mapping(dataclasses.replace(ctx, keyframe_index=k)).float() for k in range(2000))
    share = kept[ctx.candidates] / 2000  # [46]
    p = ctx.n_target / 46
    # binomial sd of a share over 2,000 draws is about 0.011: 5 sd either way
    assert float((share - p).abs().max()) < 0.06, share


def test_absolute_target_is_a_count_not_a_ratio(scene):
    mixed_scene(scene)
    _, ctx = prepared(scene, "area", 0.4)
    ctx = dataclasses.replace(ctx, target_count=7)
    assert ctx.n_target == 7
    keep = load_strategy("area").after_mapping(ctx)
    assert int((keep & ctx.candidates).sum()) == 7
