"""Pocket pruning on hand-built scenes whose right answer is known (paper Eqs. 5-8)."""

from __future__ import annotations

import math

import pytest
import torch

from bench.errors import ConfigError
from bench.slam.strategy import load_strategy
from strategies._area import coverage
from strategies.area import AreaPruning
from strategies.pocket import PocketPruning, keep_top_per_tile, tile_budgets


def kept_in(keep: torch.Tensor, idx: list[int]) -> int:
    return int(keep[idx].sum())


def test_sky_gaussian_survives_while_crowded_tile_is_cut_to_its_budget(scene):
    sky = scene.add(8, 8, z=30.0, sigma_px=10.0, opacity=0.9, grad=1.0)  # huge, far, centre in tile 0
    small = scene.add_grid(0, 0, 30, grad=1.0)  # tile 0: crowded with tiny splats
    other = scene.add_grid(2, 1, 10, grad=3.0)  # tile 6: tracking pulls harder here
    ctx = scene.build()
    assert ctx.raster.tile_id[sky] == 0 and (ctx.raster.tile_id[small] == 0).all()
    assert (ctx.raster.tile_id[other] == 6).all()
    assert ctx.n_target == math.ceil(0.4 * 41) == 17
    # G_0 = 1, G_6 = 3: B_0 = ceil(17 / 4) = 5, B_6 = ceil(51 / 4) = 13 >= its 10 candidates
    keep = PocketPruning().after_mapping(ctx)
    assert keep[sky]
    assert kept_in(keep, [sky, *small]) == 5
    c = ctx.raster.coverage
    best_small = sorted(small, key=lambda i: -float(c[i]))[:4]
    assert keep[best_small].all()
    assert keep[other].all()
    assert c[sky] > 10 * c[small].max()  # it survives because it paints the most, not by chance

    keep_area = AreaPruning().after_mapping(ctx)  # the global rule keeps the sky Gaussian too
    assert keep_area[sky] and int((keep_area & ctx.candidates).sum()) == 17
    assert kept_in(keep_area, small) > 4  # ... but it does not protect the textured tile's share


def test_every_occupied_tile_keeps_at_least_budget_min(scene, budgets):
    quiet = scene.add_grid(0, 0, 12, grad=0.01)
    busy = scene.add_grid(1, 1, 12, grad=10.0)
    sparse = scene.add_grid(2, 2, 3, grad=0.01)  # fewer candidates than B_min: all kept
    ctx = scene.build()
    expected = budgets(ctx.n_target, {0: [0.01] * 12, 5: [10.0] * 12, 10: [0.01] * 3})
    assert expected == {0: 5, 5: 11, 10: 5}
    keep = PocketPruning().after_mapping(ctx)
    assert kept_in(keep, quiet) == 5
    assert kept_in(keep, busy) == 11
    assert kept_in(keep, sparse) == 3


@pytest.mark.parametrize(
    ("grads", "ceil_b", "floor_b"),
    [
        ((1.0, 2.0, 4.0), (6, 11, 21), (5, 10, 20)),  # 36 * G_k / 7 is fractional: rounding matters
        ((1.0, 1.0, 1.0), (12, 12, 12), (12, 12, 12)),  # 36 / 3 is whole: both agree
    ],
)
def test_ceil_and_floor_differ_only_for_fractional_shares(scene, budgets, grads, ceil_b, floor_b):
    tiles = [(3, 0), (1, 2), (2, 1)]  # ids 3, 9, 6: a swapped x/y or a collapsed tile id moves the budgets
    groups = [scene.add_grid(tx, ty, 30, grad=g) for (tx, ty), g in zip(tiles, grads, strict=True)]
    ctx = scene.build()
    assert ctx.n_target == 36
    hand = {ty * 4 + tx: [g] * 30 for (tx, ty), g in zip(tiles, grads, strict=True)}
    assert tuple(budgets(36, hand).values()) == ceil_b
    assert tuple(budgets(36, hand, rounding=math.floor).values()) == floor_b
    for rounding, expected in (("ceil", ceil_b), ("floor", floor_b)):
        keep = PocketPruning(budget_round=rounding).after_mapping(ctx)
        assert [kept_in(keep, grp) for grp in groups] == list(expected), rounding


def test_tile_membership_comes_from_the_real_projection(scene):
    placed = {(3, 0): 2.0, (0, 2): 1.0, (2, 1): 5.0}  # tile -> gradient
    groups = {t: scene.add_grid(*t, 20, grad=g) for t, g in placed.items()}
    ctx = scene.build()
    for (tx, ty), idx in groups.items():
        for i in idx:
            row = scene.rows[i]
            assert ctx.raster.tile_id[i] == scene.tile_of(row["u"], row["v"]) == ty * 4 + tx
    # N_tar = 24, G = (2, 1, 5) / 8: B = ceil(6), ceil(3) -> 5, ceil(15); all in one tile would keep 24
    budget, n_k = PocketPruning().budgets(ctx)
    assert budget[3] == 6 and budget[8] == 5 and budget[6] == 15
    assert int(budget.sum()) == 26 and (budget[[0, 1, 2, 4, 5, 7, 9, 10, 11]] == 0).all()
    assert n_k[3] == n_k[8] == n_k[6] == 20
    keep = PocketPruning().after_mapping(ctx)
    assert [kept_in(keep, groups[t]) for t in placed] == [6, 5, 15]


def test_rank_random_keeps_the_tile_budgets_with_a_seeded_draw(scene):
    """strategy.params.rank=random: the same count per tile as the area rank, a different and seeded choice."""
    import dataclasses

    placed = {(3, 0): 2.0, (0, 2): 1.0, (2, 1): 5.0}
    groups = {t: scene.add_grid(*t, 20, grad=g) for t, g in placed.items()}
    ctx = scene.build()
    by_area = PocketPruning().after_mapping(ctx)
    chance = PocketPruning(rank="random")
    keep = chance.after_mapping(ctx)
    assert [kept_in(keep, groups[t]) for t in placed] == [kept_in(by_area, groups[t]) for t in placed] == [6, 5, 15]
    assert not torch.equal(keep, by_area)
    assert torch.equal(keep, chance.after_mapping(ctx))  # same seed and keyframe: the same subset
    assert not torch.equal(keep, chance.after_mapping(dataclasses.replace(ctx, seed=ctx.seed + 1)))
    with pytest.raises(ConfigError, match="rank: expected one of area, random, found 'opacity'"):
        load_strategy("pocket", {"rank": "opacity"})


def test_new_gaussians_are_exempt_and_do_not_shape_budgets(scene):
    old0 = scene.add_grid(0, 0, 10, grad=1.0)
    new0 = [scene.add(3 + i, 13, grad=100.0, opacity=0.99, sigma_px=2.0, new=True) for i in range(8)]
    old5 = scene.add_grid(1, 1, 10, grad=1.0)
    ctx = scene.build()
    assert not ctx.candidates[new0].any() and ctx.candidates[old0 + old5].all()
    assert ctx.n_target == 8  # counted over the 20 old Gaussians only
    keep = PocketPruning().after_mapping(ctx)
    assert keep[new0].all()
    # with the new ones ignored both tiles have G = 1: B = max(ceil(8 / 2), 5) = 5 each
    assert kept_in(keep, old0) == 5 and kept_in(keep, old5) == 5


def test_gaussians_off_image_are_kept(scene):
    inside = scene.add_grid(0, 0, 20)
    outside = [scene.add(-5.0, 10.0), scene.add(70.0, 10.0), scene.add(10.0, 50.0)]
    ctx = scene.build()
    assert (ctx.raster.tile_id[outside] == -1).all() and not ctx.candidates[outside].any()
    keep = PocketPruning().after_mapping(ctx)
    assert keep[outside].all() and kept_in(keep, inside) == 8


def brute_coverage(scene, i: int) -> tuple[float, torch.Tensor]:
    """sum_p o exp(-d^T Lambda^-1 d / 2) over every image pixel, Lambda from the EWA Jacobian by hand."""
    r = scene.rows[i]
    z, s = r["z"], r["sigma_px"] * r["z"] / scene.FX
    x, y = (r["u"] - scene.CX) * z / scene.FX, (r["v"] - scene.CY) * z / scene.FX
    f = scene.FX
    J = torch.tensor([[f / z, 0.0, -f * x / z**2], [0.0, f / z, -f * y / z**2]], dtype=torch.float64)
    lam = s * s * J @ J.T + 0.3 * torch.eye(2, dtype=torch.float64)  # [2, 2] px^2, with the 0.3 px^2 low-pass
    ys, xs = torch.meshgrid(torch.arange(scene.H), torch.arange(scene.W), indexing="ij")
    d = torch.stack([xs - r["u"], ys - r["v"]], -1).reshape(-1, 2).to(torch.float64)  # [P, 2]
    power = -0.5 * torch.einsum("pi,ij,pj->p", d, torch.linalg.inv(lam), d)
    return float(r["opacity"] * torch.exp(power).sum()), lam


def test_exact_coverage_matches_brute_force_and_analytic_matches_exact_inside(scene):
    centre = scene.add(32, 24, sigma_px=3.0, opacity=0.8)
    border = scene.add(61, 4, sigma_px=4.0, opacity=0.6)  # mostly outside the image
    corner = scene.add(10, 40, sigma_px=1.5, opacity=0.9)
    ctx = scene.build()
    exact = coverage(ctx.raster, ctx.gaussians.opacities, "exact")
    for i in (centre, border, corner):
        brute, _ = brute_coverage(scene, i)
        assert float(exact[i]) == pytest.approx(brute, rel=5e-3), i
    analytic = coverage(ctx.raster, ctx.gaussians.opacities, "analytic")
    _, lam = brute_coverage(scene, centre)
    assert float(analytic[centre]) == pytest.approx(0.8 * 2 * math.pi * math.sqrt(float(torch.det(lam))), rel=1e-4)
    assert float(analytic[centre]) == pytest.approx(float(exact[centre]), rel=0.02)
    assert float(analytic[border]) > 1.5 * float(exact[border])  # the closed form ignores the image border
    radius = coverage(ctx.raster, ctx.gaussians.opacities, "radius")
    r = math.ceil(3 * math.sqrt(9.0 + 0.3))  # 3 sigma of the larger eigenvalue, 10 px
    assert float(radius[centre]) == pytest.approx(0.8 * math.pi * r * r, rel=1e-5)


@pytest.mark.parametrize("area", ["exact", "analytic", "radius"])
def test_area_variants_rank_a_bigger_splat_higher(scene, area):
    small = scene.add(24, 24, sigma_px=1.0)
    big = scene.add(40, 24, sigma_px=3.0)
    ctx = scene.build()
    s = coverage(ctx.raster, ctx.gaussians.opacities, area)
    assert s[big] > s[small] > 0


@pytest.mark.parametrize(
    ("params", "needle"),
    [
        ({"area": "pixels"}, "area: expected one of exact, analytic, radius, found 'pixels'"),
        ({"budget_round": "round"}, "budget_round: expected one of ceil, floor, found 'round'"),
        ({"tile_px": 8}, "tile_px: expected the rasterizer's tile size 16, found 8"),
        ({"budget_min": 10, "budget_max": 5}, "budget_max: expected an integer >= budget_min (10)"),
        ({"budget_min": -1}, "budget_min: expected an integer >= 0"),
    ],
)
def test_bad_parameters_raise_one_line_config_errors(params, needle):
    with pytest.raises(ConfigError) as err:
        load_strategy("pocket", params)
    msg = str(err.value)
    assert needle in msg and "\n" not in msg and msg == msg.lower()
    with pytest.raises(ConfigError):
        PocketPruning(**params)


def test_segmented_top_k_matches_a_per_tile_loop():
    g = torch.Generator().manual_seed(3)
    n, n_tiles = 2000, 12
    tile = torch.randint(-1, n_tiles, (n,), generator=g)
    cand = (tile >= 0) & (torch.rand(n, generator=g) > 0.2)
    score = torch.rand(n, generator=g)
    budget = torch.randint(0, 60, (n_tiles,), generator=g)
    keep = keep_top_per_tile(score, tile, cand, budget)
    assert keep[~cand].all()
    for k in range(n_tiles):
        idx = ((tile == k) & cand).nonzero().flatten()
        best = idx[torch.topk(score[idx], min(int(budget[k]), idx.numel())).indices]
        assert set(idx[keep[idx]].tolist()) == set(best.tolist()), k


def test_budgets_split_evenly_when_no_tile_has_gradient():
    tile = torch.tensor([0, 0, 0, 2, 2, 5])
    cand = torch.ones(6, dtype=torch.bool)
    budget, n_k = tile_budgets(tile, torch.zeros(6), cand, 6, 30, 1, 200)
    assert budget.tolist() == [10, 0, 10, 0, 0, 10] and n_k.tolist() == [3, 0, 2, 0, 0, 1]


def test_zero_tile_source_keeps_the_budget_max_largest_rendered_gaussians(scene):
    """The released code's effect: every Gaussian in tile (0,0), so one budget min(N_tar, B_max) for the view."""
    small = scene.add_grid(0, 0, 10, sigma_px=0.5)
    large = scene.add_grid(3, 2, 4, sigma_px=2.0)
    edge = scene.add(-1.0, 20.0, sigma_px=2.0)  # centre off-image, but it renders: a candidate there
    s = PocketPruning(tile_source="zero", budget_min=1, budget_max=5, area="radius", budget_round="floor")
    ctx = scene.build(s, keep_ratio=1.0)
    assert int(ctx.raster.radius_px[edge]) > 0 and not bool(ctx.candidates[edge])
    keep = s.after_mapping(ctx)
    assert int(keep.sum()) == 5  # min(N_tar = 14, B_max = 5), the off-image one ranked with the rest
    assert keep[large].all() and not keep[small].any()
