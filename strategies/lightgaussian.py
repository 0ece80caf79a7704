"""LightGaussian's global significance as its code computes it.

Read: VITA-Group/LightGaussian @ 6676b983e77baadd909effc56a6aaadafa964dcc (``prune.py``
``calculate_v_imp_score`` and ``prune_list``; ``scene/gaussian_model.py`` ``prune_gaussians``), with the
count kernel of its rasterizer Kevin-2017/compress-diff-gaussian-rasterization: the pinned submodule
240618bbc5fb21c270a0c5babb292615011a2f15 adds o_j per contributing pixel, the newest commit
9893d8c607684bc1a432e179cc97035d72d84520 adds o_j * T_ij (T before j).

imp_j = sum over the scoring views and pixels of the weight ``lg_weight``: ``opacity_T`` (o*T, the
newest rasterizer; default), ``opacity`` (o per hit, the pinned rasterizer and the paper), ``alpha_T``
(the blending weight, which no commit computes). Score v_j = (V_j / kth)^v_pow * imp_j, V_j the product
of the activated scales, kth = sort(V, descending)[int(0.9 N)] over the whole map; no clipping
(``lg_volume_clip=True``: the paper's clip of V / kth to [0, 1]). The code's non-atomic sums lose
updates; this computes the exact sums.

This is not ``opacity`` (the Pocket-SLAM paper's reading of LightGaussian, a mean per observing view
with a clipped volume): this module follows the authors' code.
Keep rules: equal_removal (top N_tar by v) or ``rule=authors``, the sort-index rule at ``lg_prune_percent``
(0.66, ``run_prune_finetune.sh``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import torch

from bench.api import PruneContext, setting
from strategies._criteria import RenderCriterion, sort_index_prune

LG_WEIGHTS: tuple[str, ...] = ("opacity_T", "opacity", "alpha_T")


def volume_factor(log_scales: torch.Tensor, power: float, clip: bool) -> torch.Tensor:
    """(V / kth)^power [N], V = prod(exp(log_scales)), kth = sort(V, descending)[int(0.9 N)] (in log space)."""
    log_v = log_scales.detach().sum(-1)  # [N]
    if not log_v.numel():
        return log_v
    kth = torch.sort(log_v, descending=True).values[min(int(log_v.numel() * 0.9), log_v.numel() - 1)]
    r = log_v - kth
    return torch.exp(power * (r.clamp(max=0.0) if clip else r))


@dataclass
class LightGaussianPruning(RenderCriterion):
    """Keep the Gaussians of largest volume-weighted summed opacity (x transmittance) over the scoring views."""

    description: ClassVar[str] = "LightGaussian (6676b983, raster 9893d8c6): sum_views sum_px o*T x (V/V_90)^0.1"
    reads: ClassVar[frozenset[str]] = frozenset({"weight_sum"})

    lg_weight: str = setting("opacity_T", "str", choices=LG_WEIGHTS)  # what each contributing pixel adds
    lg_v_pow: float = setting(0.1, "float", lo=0.0)  # v_pow
    lg_volume_clip: bool = setting(False, "bool")  # the paper's clip of V / kth to [0, 1] (the code has none)
    lg_prune_percent: float = setting(0.66, "float", lo=0.0, hi=1.0)  # rule=authors: sort-index percent

    def importance(self, ctx: PruneContext) -> torch.Tensor:
        """imp [N]: the summed weight over the scoring views."""
        imp = torch.zeros(len(ctx.gaussians), device=ctx.candidates.device)
        o = ctx.gaussians.opacities.detach().float()
        for out in self.views(ctx, ("weight_sum",)):
            # a stats=True render with the extra statistics asked for fills these
            assert out.opacity_t_sum is not None and out.weight_sum is not None and out.hit_count is not None
            if self.lg_weight == "opacity_T":
                imp += out.opacity_t_sum.float()
            elif self.lg_weight == "alpha_T":
                imp += out.weight_sum.float()
            else:
                imp += o * out.hit_count.float()
        return imp

    def score(self, ctx: PruneContext) -> torch.Tensor:
        return self.importance(ctx) * volume_factor(ctx.gaussians.log_scales, self.lg_v_pow, self.lg_volume_clip)

    def cap_score(self, ctx: PruneContext) -> torch.Tensor:
        """The criterion's score over its scoring views ranks the map at slam.densify.cap."""
        return self.score(ctx)

    def after_mapping(self, ctx: PruneContext) -> torch.Tensor:
        v = self.score(ctx)
        if self.rule == "equal_removal":
            return self.keep_top(ctx, v)
        return self.keep_authors(ctx, sort_index_prune(v, ctx.candidates, self.lg_prune_percent))
