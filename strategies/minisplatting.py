"""Mini-Splatting's simplification: blending-weight importance, zeroed where never a pixel's top contributor.

Read: fatPeter/mini-splatting @ c0d55811930dec3bfd3d61cad927093d166aaf82 (``ms/train.py`` steps 1 and 2
at ``simp_iteration1``/``simp_iteration2``; ``gaussian_renderer/__init__.py`` ``render_imp``; the vendored
rasterizer's per-pair ``accum_weights += alpha*T`` and per-pixel argmax count, front-most on ties).

Per view: accum_weights (sum alpha*T), area_proj (contributing pixels), area_max (pixels where the
Gaussian has the largest alpha*T). ``ms_imp_metric=indoor`` (default; SLAM benchmarks are indoor):
I = sum_v accum_weights; ``outdoor``: I = sum_v [area_max_v > 0] accum_weights_v / area_proj_v. Then
I = 0 wherever sum_v area_max_v = 0.

Keep rules: equal_removal with ``ms_mode=topk`` (default): the top N_tar by I, then by the raw sum of
alpha*T (the many I = 0 ties), then by index. ``ms_mode=sample``: step 1 with N_tar draws, weighted by I
without replacement (``torch.multinomial``, seeded ``slam.seed + keyframe index``; the authors use the
global numpy RNG seeded 0), topped up by the secondary key if fewer Gaussians have I > 0; the authors'
``reinitial_pts`` afterwards is not copied. ``rule=authors``: step 2, the CDF rule at ``ms_cdf_thres`` (0.99).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import torch

from bench.api import PruneContext, setting
from strategies._criteria import RenderCriterion, rank_keep


@dataclass
class MiniSplattingPruning(RenderCriterion):
    """Keep the Gaussians of largest accumulated blending weight among those that top some pixel."""

    description: ClassVar[str] = "Mini-Splatting (c0d55811): sum alpha*T, 0 if never a pixel's max-weight Gaussian"
    reads: ClassVar[frozenset[str]] = frozenset({"weight_sum", "top1"})

    ms_mode: str = setting("topk", "str", choices=("topk", "sample"))  # equal_removal: top N_tar | N_tar sampled
    ms_imp_metric: str = setting("indoor", "str", choices=("indoor", "outdoor"))
    ms_cdf_thres: float = setting(0.99, "float", lo=0.0, hi=1.0)  # rule=authors (step 2)

    def importance(self, ctx: PruneContext) -> tuple[torch.Tensor, torch.Tensor]:
        """(I, raw sum of alpha*T) [N] over the scoring views."""
        n = len(ctx.gaussians)
        imp = torch.zeros(n, device=ctx.candidates.device)
        raw = torch.zeros_like(imp)
        area_max = torch.zeros_like(imp)
        for out in self.views(ctx, ("weight_sum", "top1")):
            # a stats=True render with the extra statistics asked for fills these
            assert out.weight_sum is not None and out.top1_count is not None and out.hit_count is not None
            w = out.weight_sum.float()
            top = out.top1_count.float()
            raw += w
            area_max += top
            if self.ms_imp_metric == "indoor":
                imp += w
            else:
                imp += torch.where(top > 0, w / out.hit_count.float().clamp_min(1), 0.0)
        return torch.where(area_max > 0, imp, 0.0), raw

    def after_mapping(self, ctx: PruneContext) -> torch.Tensor:
        imp, raw = self.importance(ctx)
        if self.rule == "authors":
            return self.keep_authors(ctx, cdf_keep(imp, ctx.candidates, self.ms_cdf_thres))
        if self.ms_mode == "topk":
            return self.keep_top(ctx, imp, raw)
        gen = torch.Generator(device=imp.device).manual_seed(ctx.seed + ctx.keyframe_index)
        return sample_keep(imp, raw, ctx.candidates, ctx.n_target, gen, self.protected(ctx))


def cdf_keep(imp: torch.Tensor, candidates: torch.Tensor, thres: float) -> torch.Tensor:
    """Step 2 over the candidates: keep I > vals[s], vals = sort(I + 1e-6), s the first index whose
    normalised cumulative sum exceeds 1 - thres."""
    keep = torch.ones_like(candidates)
    idx = candidates.nonzero().flatten()
    if idx.numel():
        i = imp[idx]
        vals = torch.sort(i + 1e-6).values
        cum = torch.cumsum(vals, 0) / vals.sum()
        s = int(torch.nonzero(cum > 1 - thres).flatten()[0]) if bool((cum > 1 - thres).any()) else vals.numel() - 1
        keep[idx] = i > vals[s]
    return keep


def sample_keep(imp, raw, candidates, k, gen, protected=None) -> torch.Tensor:
    """Step 1 at a controlled count: ``k`` kept in all (protected ones first), drawn among the candidates
    with probability I / sum I without replacement; if fewer have I > 0, all of those and the rest by ``raw``."""
    protected = torch.zeros_like(candidates) if protected is None else protected & candidates
    keep = ~candidates | protected
    idx = (candidates & ~protected).nonzero().flatten()
    budget = min(max(k - int(protected.sum()), 0), idx.numel())
    if budget == 0:
        return keep
    p = imp[idx].double()
    nnz = int((p > 0).sum())
    if budget <= nnz:
        drawn = idx[torch.multinomial(p / p.sum(), budget, replacement=False, generator=gen)]
        keep[drawn] = True
        return keep
    keep[idx[p > 0]] = True
    return rank_keep([raw], candidates, k, keep & candidates)
