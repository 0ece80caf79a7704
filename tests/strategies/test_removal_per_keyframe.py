"""On a real (tiny) SLAM run: at every keyframe each strategy removes (1 - keep) of its candidates.

Global strategies remove exactly n_candidates - ceil(keep x n_candidates); pocket removes what its
tile budgets leave (sum_k min(B_k, n_k) kept); mask hides that many and deletes them once they
have stayed hidden for its delay. The counts come from the core (FrameResult), the expectation
from the context the strategy saw.
"""

from __future__ import annotations

import math

import pytest
import torch

from bench.datasets.synthetic import open_sequence
from bench.slam.config import SlamConfig
from bench.slam.strategy import PruneConfig, PruneContext, Strategy, load_strategy
from bench.slam.system import FrameResult, System
from strategies.mask import STATE_MASKED_RUN

KEEP = 0.4


@pytest.fixture(scope="module")
def seq():
    return open_sequence({"width": 48, "height": 32, "n_frames": 4, "supersample": 1})


def _run(seq, strategy: Strategy, prune: PruneConfig | float = KEEP, **slam) -> tuple[list[FrameResult], list[dict]]:
    """Process the sequence, recording what the strategy saw and was expected to keep at each prune."""
    seen: list[dict] = []
    decide = strategy.after_mapping

    def recorded(ctx: PruneContext):
        n_cand = int(ctx.candidates.sum())
        rec = {"kf": ctx.keyframe_index, "n_candidates": n_cand, "n_target": ctx.n_target}
        if hasattr(strategy, "budgets"):
            budget, n_k = strategy.budgets(ctx)
            rec["pocket_kept"] = int(torch.minimum(budget, n_k).sum())
        keep = decide(ctx)
        if STATE_MASKED_RUN in ctx.state:
            rec["masked_candidates"] = int((ctx.candidates & (ctx.state[STATE_MASKED_RUN] > 0)).sum())
        seen.append(rec)
        return keep

    strategy.after_mapping = recorded
    cfg = SlamConfig(
        **{
            "tracking_iters": 3,
            "tracking_iters_first": 5,
            "mapping_iters": 3,
            "kf_every": 1,
            "lost_min_silhouette_frac": 0.0,
            **slam,
        }
    )  # heavy pruning of a tiny map
    system = System(cfg, seq.K, seq.height, seq.width, strategy, prune, torch.device("cpu"))
    results = [system.step(seq[i]) for i in range(len(seq))]
    return results, seen


@pytest.mark.parametrize("name", ["area", "opacity", "gradient", "pocket"])
def test_each_keyframe_removes_the_shared_fraction_of_its_candidates(seq, name):
    results, seen = _run(seq, load_strategy(name))
    assert len(seen) == len(results) == 4 and all(r.is_keyframe for r in results)
    assert sum(s["n_candidates"] for s in seen) > 0
    for res, rec in zip(results, seen, strict=True):
        assert res.n_candidates == rec["n_candidates"]
        n = rec["n_candidates"]
        if name == "pocket":  # budgets round up and have a floor: at most the N_tar shares are kept
            want = n - rec["pocket_kept"]
        else:
            assert rec["n_target"] == math.ceil(KEEP * n)
            want = n - min(rec["n_target"], n)
        assert res.n_pruned == want, (name, rec, res.n_pruned)


def test_mask_at_delay_one_removes_the_shared_fraction(seq):
    results, seen = _run(seq, load_strategy("mask", {"masked_keyframes": 1}))
    assert sum(s["n_candidates"] for s in seen) > 0
    for res, rec in zip(results, seen, strict=True):
        assert res.n_pruned == rec["n_candidates"] - min(math.ceil(KEEP * rec["n_candidates"]), rec["n_candidates"])


def test_mask_hides_the_shared_fraction_and_deletes_within_its_delay(seq):
    results, seen = _run(seq, load_strategy("mask", {"masked_keyframes": 2}))
    masked_before = 0
    for res, rec in zip(results, seen, strict=True):
        n = rec["n_candidates"]
        assert rec["masked_candidates"] == n - min(math.ceil(KEEP * n), n)  # hidden at once
        assert res.n_pruned <= masked_before  # deleted only after a keyframe spent hidden
        masked_before = rec["masked_candidates"]
    assert results[0].n_pruned == 0


def test_pruning_every_frame_prunes_between_keyframes(seq):
    results, seen = _run(seq, load_strategy("area"), PruneConfig(keep_ratio=KEEP, every="frame"), kf_every=3)
    between = [r for r in results[1:] if not r.is_keyframe]
    assert between and all(r.n_candidates > 0 for r in between)
    assert len(seen) == len(results)  # one prune per frame once the map exists


def test_absolute_target_keeps_a_count(seq):
    results, seen = _run(seq, load_strategy("area"), PruneConfig(target="absolute", n_target=50))
    for res, rec in zip(results, seen, strict=True):
        assert rec["n_target"] == 50
        assert res.n_pruned == max(rec["n_candidates"] - 50, 0)


def test_screen_space_gradient_source_feeds_the_tile_budgets(seq):
    grads: list[torch.Tensor] = []
    strategy = load_strategy("pocket")
    budgets = strategy.budgets
    strategy.budgets = lambda ctx: grads.append(ctx.track_grad_mean.clone()) or budgets(ctx)
    _run(seq, strategy, PruneConfig(keep_ratio=KEEP, grad_source="means2d_all"))
    assert grads and all(bool(torch.isfinite(g).all()) for g in grads)
    assert float(grads[0].abs().max()) == 0.0  # the first keyframe: nothing tracked yet
    assert max(float(g.max()) for g in grads) > 0  # tracked frames pulled on the projected means
