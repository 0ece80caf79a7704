"""What a strategy returns is checked where the core receives it, and a bad output names the strategy."""

from __future__ import annotations

from dataclasses import dataclass

import pytest
import torch

from bench.errors import StrategyError
from bench.slam.gaussians import GaussianMap
from bench.slam.strategy import CheckedStrategy, MappingContext, PruneContext, Strategy


def _map(n: int) -> GaussianMap:
    g = GaussianMap(torch.device("cpu"))
    g.add({"means": torch.zeros(n, 3), "log_scales": torch.zeros(n, 3),
           "quats": torch.tensor([1.0, 0, 0, 0]).repeat(n, 1), "opacity_logits": torch.zeros(n),
           "colors": torch.zeros(n, 3)}, keyframe=0)  # fmt: skip
    return g


def _prune_ctx(g: GaussianMap) -> PruneContext:
    n = len(g)
    no = torch.zeros(n, dtype=torch.bool)
    return PruneContext(1, g, g.state, None, torch.zeros(n), no, ~no, 0.4, (32, 32))  # type: ignore[arg-type]


@dataclass
class Returns(Strategy):
    """A strategy whose hooks return whatever the test puts in ``out``."""

    out: object = None

    def after_mapping(self, ctx):
        return self.out

    def render_mask(self, ctx):
        return self.out

    def mapping_loss(self, ctx):
        return self.out

    def cap_score(self, ctx):
        return self.out


@pytest.mark.parametrize(
    ("out", "found"),
    [
        (torch.ones(5, dtype=torch.float32), "torch.float32 [5]"),  # a score, not a mask
        (torch.ones(4, dtype=torch.bool), "torch.bool [4]"),  # one Gaussian short
        ([True] * 5, "list"),
    ],
)
def test_a_malformed_keep_mask_is_a_strategy_error_naming_the_strategy(out, found):
    g = _map(5)
    with pytest.raises(StrategyError) as err:
        CheckedStrategy(Returns(out), "mine").after_mapping(_prune_ctx(g))
    assert str(err.value).startswith("strategy 'mine' after_mapping: expected a bool tensor [5]")
    assert found in str(err.value)


def test_a_well_formed_output_passes_unchanged():
    g = _map(5)
    keep = torch.tensor([True, False, True, True, False])
    assert CheckedStrategy(Returns(keep), "mine").after_mapping(_prune_ctx(g)) is keep
    assert CheckedStrategy(Returns(None), "mine").after_mapping(_prune_ctx(g)) is None


def test_a_cap_score_must_be_floating_per_gaussian():
    g = _map(3)
    with pytest.raises(StrategyError, match=r"strategy 'mine' cap_score: expected a floating tensor \[3\]"):
        CheckedStrategy(Returns(torch.ones(3, dtype=torch.bool)), "mine").cap_score(_prune_ctx(g))
    assert CheckedStrategy(Returns(None), "mine").cap_score(_prune_ctx(g)) is None


def test_render_mask_and_loss_shapes_are_checked():
    g = _map(3)
    ctx = MappingContext(0, 0, g, g.state, True)
    with pytest.raises(StrategyError, match=r"strategy 'mine' render_mask: expected a floating tensor \[3\]"):
        CheckedStrategy(Returns(torch.ones(3, dtype=torch.bool)), "mine").render_mask(ctx)
    with pytest.raises(StrategyError, match="strategy 'mine' mapping_loss: expected a scalar tensor or None"):
        CheckedStrategy(Returns(torch.ones(3)), "mine").mapping_loss(ctx)


@pytest.mark.parametrize("hook", ["cap_score", "render_mask", "mapping_loss"])
def test_a_score_mask_or_loss_that_is_not_finite_is_a_strategy_error(hook: str) -> None:
    g = _map(3)
    ctx = _prune_ctx(g) if hook == "cap_score" else MappingContext(0, 0, g, g.state, True)
    out = torch.tensor(float("nan")) if hook == "mapping_loss" else torch.tensor([0.5, float("nan"), float("inf")])
    with pytest.raises(StrategyError) as err:
        getattr(CheckedStrategy(Returns(out), "mine"), hook)(ctx)
    found = "1 NaN and 0 infinite of 1" if hook == "mapping_loss" else "1 NaN and 1 infinite of 3"
    assert str(err.value) == f"strategy 'mine' {hook}: expected finite values, found {found}"
    finite = torch.tensor(0.5) if hook == "mapping_loss" else torch.tensor([0.5, 0.0, 1.0])
    assert getattr(CheckedStrategy(Returns(finite), "mine"), hook)(ctx) is finite


def test_nan_scores_ranked_by_top_k_keep_are_a_strategy_error_naming_the_strategy() -> None:
    from bench.slam.strategy import top_k_keep

    class NanScores(Strategy):
        def after_mapping(self, ctx):
            score = torch.tensor([0.3, float("nan"), 0.1, 0.2, float("nan")])  # [N]
            return top_k_keep(score, ctx.candidates, 2)

    with pytest.raises(StrategyError) as err:
        CheckedStrategy(NanScores(), "nans").after_mapping(_prune_ctx(_map(5)))
    assert (
        str(err.value)
        == "strategy 'nans' after_mapping: top_k_keep: expected scores to rank, found 2 NaN of 5 candidates"
    )


def test_a_strategy_error_raised_inside_a_hook_gets_the_name():
    class Broken(Strategy):
        def after_mapping(self, ctx):
            raise StrategyError("expected rasterize(..., stats=True) outputs, found hit_count None")

    with pytest.raises(StrategyError, match="^strategy 'broken' after_mapping: expected rasterize"):
        CheckedStrategy(Broken(), "broken").after_mapping(_prune_ctx(_map(2)))


def test_every_hook_of_the_contract_is_forwarded_and_checked():
    """Each hook of ``Strategy`` is a method of the wrapper of its own (not the base's no-op), and reaches the
    strategy through it."""
    import bench.slam.strategy as contract

    public = {n for n, v in vars(Strategy).items() if callable(v) and not n.startswith("_")}
    assert set(contract.HOOKS) == public
    assert public <= set(vars(CheckedStrategy)), f"not forwarded: {sorted(public - set(vars(CheckedStrategy)))}"
    called = []

    class Spy(Strategy):
        pass

    for hook in public:  # each hook records its call and answers as the base class does

        def spy(self, *args, _hook=hook):
            called.append(_hook)
            return getattr(Strategy, _hook)(self, *args)

        setattr(Spy, hook, spy)
    g = _map(3)
    wrapped = CheckedStrategy(Spy(), "spy")
    mctx = MappingContext(1, 0, g, g.state, True)
    wrapped.state_spec()
    wrapped.extra_params()
    wrapped.on_tracking_step(None)  # type: ignore[arg-type]
    wrapped.render_mask(mctx)
    wrapped.masked_count(g, g.state)
    wrapped.mapping_loss(mctx)
    wrapped.after_mapping(_prune_ctx(g))
    wrapped.cap_score(_prune_ctx(g))
    assert sorted(called) == sorted(public)
