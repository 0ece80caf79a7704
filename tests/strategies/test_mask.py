"""MaskGaussian: straight-through Gumbel masks, sparsity loss, and deletion deferred by M keyframes."""

from __future__ import annotations

import pytest
import torch

from bench.errors import ConfigError
from bench.slam.gaussians import ParamSpec
from bench.slam.strategy import MappingContext, load_strategy
from strategies.mask import PARAM_LOGITS, STATE_MASKED_RUN, MaskPruning


def mapping_ctx(g, training: bool, iteration: int = 0) -> MappingContext:
    return MappingContext(1, iteration, g, g.state, training)


def test_logits_are_an_extra_parameter_owned_by_the_core(scene):
    s = MaskPruning(init_keep_logit=3.0, mask_lr=0.02)
    assert s.extra_params() == {PARAM_LOGITS: ParamSpec(init=3.0, lr=0.02)}
    scene.add_grid(0, 0, 5)
    g = scene.gaussian_map(s)
    assert torch.equal(g.params[PARAM_LOGITS].detach(), torch.full((5,), 3.0))


def test_training_mask_is_binary_forward_with_soft_gradients_and_seeded(scene):
    scene.add_grid(0, 0, 30)
    s = MaskPruning(init_keep_logit=0.0)  # p_keep = 0.5: about half are sampled away
    g = scene.gaussian_map(s)
    m = s.render_mask(mapping_ctx(g, training=True))
    assert m.shape == (30,) and set(m.detach().unique().tolist()) == {0.0, 1.0}
    m.sum().backward()
    assert g.params[PARAM_LOGITS].grad is not None and (g.params[PARAM_LOGITS].grad > 0).all()
    again = MaskPruning(init_keep_logit=0.0).render_mask(mapping_ctx(g, training=True))
    assert torch.equal(m.detach(), again.detach())  # same seed, same noise
    other = MaskPruning(init_keep_logit=0.0, seed=1).render_mask(mapping_ctx(g, training=True))
    assert not torch.equal(m.detach(), other.detach())


def test_learned_eval_mask_is_the_hard_threshold(scene):
    scene.add_grid(0, 0, 4)
    s = MaskPruning(select="learned")
    g = scene.gaussian_map(s)
    with torch.no_grad():
        g.params[PARAM_LOGITS].copy_(torch.tensor([2.0, -0.1, 0.1, -3.0]))
    assert s.render_mask(mapping_ctx(g, training=False)).tolist() == [1.0, 0.0, 1.0, 0.0]
    assert s.masked_count(g, g.state) == 2


def test_sparsity_loss_is_weighted_mean_keep_probability(scene):
    scene.add_grid(0, 0, 3)
    s = MaskPruning(sparsity_weight=0.1)
    g = scene.gaussian_map(s)
    with torch.no_grad():
        g.params[PARAM_LOGITS].copy_(torch.tensor([0.0, 2.0, -1.0]))
    loss = s.mapping_loss(mapping_ctx(g, training=True))
    want = 0.1 * torch.sigmoid(torch.tensor([0.0, 2.0, -1.0])).mean()
    torch.testing.assert_close(loss, want)
    loss.backward()
    assert (g.params[PARAM_LOGITS].grad > 0).all()  # it pushes keep probabilities down


def test_learned_masks_are_deleted_at_the_mth_consecutive_masked_keyframe(scene):
    idx = scene.add_grid(0, 0, 6)
    s = MaskPruning(masked_keyframes=3, select="learned")
    g = scene.gaussian_map(s)

    def keyframe(values: list[float], kf: int) -> torch.Tensor:
        with torch.no_grad():  # what mapping would have learned; remove() replaces the Parameter
            g.params[PARAM_LOGITS].copy_(torch.tensor(values))
        return s.after_mapping(scene.context(g, keyframe_index=kf))

    # 0, 1 stay masked; 2 is masked twice then shown again; 3 is masked from the second keyframe on
    k1 = keyframe([-1.0, -1.0, -1.0, 1.0, 1.0, 1.0], 1)
    k2 = keyframe([-1.0, -1.0, -1.0, -1.0, 1.0, 1.0], 2)
    assert k1.all() and k2.all()  # hidden, not deleted
    assert s.masked_count(g, g.state) == 4 and len(g) == 6
    k3 = keyframe([-1.0, -1.0, 1.0, -1.0, 1.0, 1.0], 3)
    assert k3[idx].tolist() == [False, False, True, True, True, True]
    assert g.state[STATE_MASKED_RUN].tolist() == [3, 3, 0, 2, 0, 0]
    g.remove(k3)  # what the core does with the keep mask; the state is sliced with the map
    assert g.state[STATE_MASKED_RUN].tolist() == [0, 2, 0, 0]
    k4 = keyframe([1.0, -1.0, 1.0, 1.0], 4)
    assert k4.tolist() == [True, False, True, True]  # Gaussian 3 reaches its third masked keyframe


def test_ratio_masks_the_lowest_logits_of_the_candidates_and_hides_them(scene):
    idx = scene.add_grid(0, 0, 10)
    off = scene.add(-4.0, 20.0)  # outside the image: not a candidate
    s = MaskPruning(masked_keyframes=3)
    g = scene.gaussian_map(s)
    with torch.no_grad():
        g.params[PARAM_LOGITS].copy_(torch.tensor([float(i) for i in range(10)] + [-9.0]))
    ctx = scene.context(g, keep_ratio=0.4, keyframe_index=1)
    assert int(ctx.candidates.sum()) == 10 and ctx.n_target == 4
    keep = s.after_mapping(ctx)
    assert keep.all()  # masked, not yet deleted
    masked = g.state[STATE_MASKED_RUN] > 0
    assert masked[idx].tolist() == [True] * 6 + [False] * 4 and not masked[off]  # the off-image one is not ranked
    assert s.masked_count(g, g.state) == 6
    shown = s.render_mask(mapping_ctx(g, training=False))
    assert shown[idx].tolist() == [0.0] * 6 + [1.0] * 4
    trained = s.render_mask(mapping_ctx(g, training=True))
    assert trained[idx[:6]].eq(0).all()  # hidden in mapping too


def test_ratio_deletes_what_stays_masked_for_the_delay(scene):
    idx = scene.add_grid(0, 0, 5)
    s = MaskPruning(masked_keyframes=2)
    g = scene.gaussian_map(s)

    def keyframe(values: list[float], kf: int) -> torch.Tensor:
        with torch.no_grad():
            g.params[PARAM_LOGITS].copy_(torch.tensor(values))
        return s.after_mapping(scene.context(g, keep_ratio=0.4, keyframe_index=kf))  # keeps ceil(0.4 n)

    assert keyframe([0.0, 1.0, 2.0, 3.0, 4.0], 1).all()  # 0, 1, 2 masked
    k2 = keyframe([5.0, 1.0, 2.0, 3.0, 4.0], 2)  # 0 ranks high now: unmasked; 1, 2, 3 masked
    assert k2[idx].tolist() == [True, False, False, True, True]  # 1 and 2 reached the delay
    assert g.state[STATE_MASKED_RUN].tolist() == [0, 2, 2, 1, 0]


def test_ratio_with_delay_one_removes_like_the_other_strategies(scene):
    idx = scene.add_grid(0, 0, 10)
    s = MaskPruning(masked_keyframes=1)
    g = scene.gaussian_map(s)
    ctx = scene.context(g, keep_ratio=0.3)
    keep = s.after_mapping(ctx)
    assert int(keep[idx].sum()) == ctx.n_target == 3


@pytest.mark.parametrize(
    "params",
    [
        {"gumbel_tau": 0.0},
        {"masked_keyframes": 0},
        {"masked_keyframes": 1.5},
        {"sparsity_weight": -1.0},
        {"select": "top"},
    ],
)
def test_mask_rejects_bad_parameters(params):
    with pytest.raises(ConfigError, match=r"strategy 'mask'|strategy\.params\.masked_keyframes: expected an integer"):
        load_strategy("mask", params)
