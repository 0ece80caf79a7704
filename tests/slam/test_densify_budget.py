"""The densification budget and cap (slam.densify.*): the cap holds, the strategy's lowest-scored make room,
the seeds are chosen deterministically, the budget curve bounds each keyframe, bad values are one line."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from bench.errors import ConfigError
from bench.slam.config import DensifyConfig, SlamConfig
from bench.slam.densify import cap_keep, map_cap, pick_seeds, seed_budget, taming_target
from bench.slam.gaussians import GaussianMap
from bench.slam.strategy import CheckedStrategy, PruneContext, Strategy, load_strategy
from bench.slam.system import System


@pytest.fixture(scope="module")
def seq():
    from bench.datasets.synthetic import open_sequence

    return open_sequence({"width": 48, "height": 32, "n_frames": 5, "supersample": 1})


def _system(seq, strategy: Strategy, **densify) -> System:
    cfg = SlamConfig(
        tracking_iters=3,
        tracking_iters_first=5,
        mapping_iters=3,
        kf_every=1,
        lost_min_silhouette_frac=0.0,
        densify=densify,
    )
    return System(cfg, seq.K, seq.height, seq.width, CheckedStrategy(strategy, "s"), 0.4, torch.device("cpu"))


def _drive(seq, strategy: Strategy, **densify):
    system = _system(seq, strategy, **densify)
    results = []
    for i in range(len(seq)):
        results.append(system.step(seq[i]))
        results[-1].diag["n_after"] = len(system.map)
    return system, results


class FakeScore(Strategy):
    """Scores by a fixed per-Gaussian number (the Gaussian's red channel) and keeps the last score it gave."""

    last: torch.Tensor | None = None

    def cap_score(self, ctx: PruneContext) -> torch.Tensor:
        self.last = ctx.gaussians.colors[:, 0].detach().clone()
        return self.last


@pytest.mark.parametrize("name", ["none", "pocket"])
def test_the_cap_is_never_exceeded_and_the_counts_add_up(seq, name):
    cap = 400
    system = _system(seq, load_strategy(name, {}), cap=cap)
    for i in range(len(seq)):
        before = len(system.map)
        res = system.step(seq[i])
        grown = before - res.diag["n_cap_removed"] + res.n_added  # the map after this keyframe's seeds
        assert grown <= cap and len(system.map) <= cap
        assert len(system.map) == grown - res.n_pruned
        if name == "none":
            assert res.diag["n_cap_removed"] == 0  # no score: nothing removed, seeds dropped
    assert len(system.map) == cap or name == "pocket"


def test_a_cap_by_rule_grows_with_the_keyframes_and_holds(seq):
    """slam.densify.cap_per_mpix_kf: after keyframe k the map holds at most rate x megapixels x (k + 1)."""
    rate = 1e5  # 48x32 px: 153 Gaussians more allowed per keyframe, fewer than a keyframe seeds unbounded
    system = _system(seq, load_strategy("none", {}), cap_per_mpix_kf=rate)
    caps = []
    for i in range(len(seq)):
        res = system.step(seq[i])
        caps.append(int(rate * seq.width * seq.height / 1e6 * (i + 1)))
        assert len(system.map) + res.n_pruned <= caps[-1]
    unbounded, _ = _drive(seq, load_strategy("none", {}))
    assert len(system.map) < len(unbounded.map)  # the rule binds


def test_the_rule_and_a_fixed_cap_take_the_lower():
    rule = DensifyConfig(cap_per_mpix_kf=2000.0)
    both = DensifyConfig(cap=5000, cap_per_mpix_kf=2000.0)
    assert map_cap(DensifyConfig(), 3, 10**6) is None
    assert map_cap(DensifyConfig(cap=5000), 3, 10**6) == 5000
    assert [map_cap(rule, k, 10**6) for k in (0, 1, 2)] == [2000, 4000, 6000]
    assert [map_cap(both, k, 10**6) for k in (0, 1, 2)] == [2000, 4000, 5000]
    assert map_cap(rule, 0, 100) == 1  # never a cap of 0


def test_the_rules_floor_holds_one_view_until_the_rule_passes_it():
    """slam.densify.cap_floor_per_px: the rule's cap is never below that many Gaussians per pixel of one image."""
    floored = DensifyConfig(cap_per_mpix_kf=2000.0, cap_floor_per_px=0.005)  # a floor of 5,000 at 1 MP
    assert [map_cap(floored, k, 10**6) for k in (0, 1, 2, 3)] == [5000, 5000, 6000, 8000]
    assert map_cap(DensifyConfig(cap=3000, cap_per_mpix_kf=2000.0, cap_floor_per_px=0.005), 0, 10**6) == 3000
    assert map_cap(DensifyConfig(cap_floor_per_px=1.0), 0, 10**6) is None  # a floor alone is no cap


def test_at_the_cap_the_lowest_scored_are_removed():
    g = GaussianMap(torch.device("cpu"))
    n = 6
    red = torch.tensor([0.5, 0.1, 0.9, 0.1, 0.7, 0.3])
    g.add(
        {
            "means": torch.zeros(n, 3),
            "log_scales": torch.zeros(n, 3),
            "quats": torch.tensor([1.0, 0, 0, 0]).repeat(n, 1),
            "opacity_logits": torch.zeros(n),
            "colors": torch.stack([red, red, red], -1),
        },
        keyframe=0,
    )
    keep = cap_keep(red, 3)
    assert keep.tolist() == [True, False, True, False, True, False]  # 0.5, 0.9, 0.7 stay
    assert cap_keep(red, 5).tolist() == [True, True, True, False, True, True]  # a tie keeps the lower index
    g.remove(keep)  # the core's one removal path
    assert sorted(g.colors[:, 0].tolist()) == pytest.approx([0.5, 0.7, 0.9])


def test_the_system_removes_by_the_strategys_score(seq):
    fake = FakeScore()
    system = _system(seq, fake, cap=300)
    masks: list[torch.Tensor] = []
    remove = system.map.remove

    def recorded(keep: torch.Tensor) -> int:  # the core's one removal path, watched
        masks.append(keep)
        return remove(keep)

    system.map.remove = recorded  # type: ignore[method-assign]
    for i in range(len(seq)):
        res = system.step(seq[i])
        if res.diag["n_cap_removed"]:
            assert fake.last is not None and masks  # the cap's removal is the first one of the keyframe
            keep = masks[0]
            assert int((~keep).sum()) == res.diag["n_cap_removed"]
            assert float(fake.last[~keep].max()) <= float(fake.last[keep].min())  # the lowest-scored went
            return
        masks.clear()
    pytest.fail("the cap never bound")


def test_same_seed_same_kept_set(seq):
    runs = [_drive(seq, load_strategy("pocket", {}), cap=300, budget="constant", per_keyframe=150)[0] for _ in (0, 1)]
    assert torch.equal(runs[0].map.means, runs[1].map.means)
    assert torch.equal(runs[0].map.birth_kf, runs[1].map.birth_kf)


def test_the_budget_bounds_each_keyframe(seq):
    _, results = _drive(seq, load_strategy("none", {}), budget="constant", per_keyframe=50)
    assert all(r.n_added <= 50 for r in results)
    assert any(r.diag["n_densify_dropped"] > 0 for r in results)
    cfg = DensifyConfig(budget="taming", final_count=1000, final_keyframe=4)
    assert seed_budget(cfg, 0, 0, None) is None  # keyframe 0 seeds as today: the curve's start
    assert [seed_budget(cfg, k, 500, 400) for k in (1, 2, 4, 9)] == [
        max(taming_target(k, 400, 1000, 4) - 500, 0) for k in (1, 2, 4, 9)
    ]
    assert [taming_target(k, 100, 1000, 10) for k in (0, 5, 10, 20)] == [100, 775, 1000, 1000]


def test_seed_orders_are_deterministic():
    sel = torch.zeros(4, 5, dtype=torch.bool)
    sel[1:, 1:] = True  # 12 candidates
    deficit = torch.zeros(4, 5)
    deficit[3, 4] = deficit[2, 2] = 1.0
    err = torch.zeros(4, 5)
    err[1, 1] = 2.0
    need = pick_seeds(sel, 3, "need", deficit, err, np.random.default_rng(0))
    assert need.nonzero().tolist() == [[1, 1], [2, 2], [3, 4]]  # deficit, then depth error
    a = pick_seeds(sel, 5, "random", deficit, err, np.random.default_rng([0, 1]))
    b = pick_seeds(sel, 5, "random", deficit, err, np.random.default_rng([0, 1]))
    assert torch.equal(a, b) and int(a.sum()) == 5 and not (a & ~sel).any()
    assert pick_seeds(sel, 20, "random", deficit, err, np.random.default_rng(0)) is sel  # all fit: as today


@pytest.mark.parametrize(
    ("densify", "message"),
    [
        ({"cap": 0}, "slam.densify.cap: expected an integer >= 1 or null, found 0"),
        ({"cap_per_mpix_kf": 0}, "slam.densify.cap_per_mpix_kf: expected a number > 0 or null, found 0"),
        ({"budget": "linear"}, "slam.densify.budget: expected one of constant, taming or null, found 'linear'"),
        ({"budget": "constant"}, "slam.densify.per_keyframe: expected an integer with slam.densify.budget=constant"),
        ({"per_keyframe": -1}, "slam.densify.per_keyframe: expected an integer >= 0 or null, found -1"),
        ({"unscored": "area"}, "slam.densify.unscored: expected one of drop, opacity, found 'area'"),
    ],
)
def test_bad_values_are_one_line(densify, message):
    with pytest.raises(ConfigError) as err:
        SlamConfig(densify=densify)
    assert str(err.value).startswith(message) and "\n" not in str(err.value)


def test_a_resumed_run_keeps_the_budget_curve(seq):
    """The taming curve's start (the map after keyframe 0) and the seed sample's generator are checkpointed."""
    import io

    densify = {"cap": 500, "budget": "taming", "final_count": 450, "final_keyframe": 3}
    straight, _ = _drive(seq, load_strategy("pocket", {}), **densify)
    first = _system(seq, load_strategy("pocket", {}), **densify)
    for i in range(2):
        first.step(seq[i])
    buf = io.BytesIO()
    torch.save(first.state_dict(), buf)
    buf.seek(0)
    resumed = _system(seq, load_strategy("pocket", {}), **densify)
    resumed.load_state_dict(torch.load(buf, weights_only=True), lambda i: seq[i])
    assert resumed.mapping.densify_start == first.mapping.densify_start is not None
    for i in range(2, len(seq)):
        resumed.step(seq[i])
    assert torch.equal(resumed.map.means, straight.map.means)
