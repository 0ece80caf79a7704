"""EfficientGS's max-weight-contributor pruning, with the weight its code compares.

Read: wenkaier/EfficientGS @ 1f70babee25b87e4c6379e1f26fe00add763356c (``train.py`` pruning with
``--prune_by_max_weight --prune_way p4``; the vendored rasterizer's ``forward.cu`` computes
``weight = alpha * T`` after ``T = test_T``, i.e. alpha times the transmittance *behind* the Gaussian,
and flags per view the Gaussians that are some pixel's top-1 by that weight, front-most on ties).

cnt_j = number of scoring views in which j is some pixel's top-1; pix_j = such (view, pixel) pairs.
``eg_weight=alpha_T_after`` (default, the code) | ``alpha_T`` (the true blending weight, the paper's intent).
Keep rules: equal_removal (top N_tar by cnt, then pix, then index) or ``rule=authors``: keep
cnt >= ``eg_view_num`` (1). Only top-1 is offered (the code's default ``top_k=1``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import torch

from bench.api import PruneContext, setting
from strategies._criteria import RenderCriterion


@dataclass
class EfficientGSPruning(RenderCriterion):
    """Keep the Gaussians that are the largest-weight contributor of some pixel in the most views."""

    description: ClassVar[str] = "EfficientGS (1f70babe): views where the Gaussian tops a pixel by alpha*T_after"
    reads: ClassVar[frozenset[str]] = frozenset({"top1"})

    eg_weight: str = setting("alpha_T_after", "str", choices=("alpha_T_after", "alpha_T"))
    eg_view_num: int = setting(1, "int", lo=1)  # rule=authors: keep cnt >= view_num

    def counts(self, ctx: PruneContext) -> tuple[torch.Tensor, torch.Tensor]:
        """(cnt, pix) [N] over the scoring views."""
        cnt = torch.zeros(len(ctx.gaussians), device=ctx.candidates.device)
        pix = torch.zeros_like(cnt)
        for out in self.views(ctx, ("top1",)):
            assert out.top1_after_count is not None and out.top1_count is not None  # asked for in extra
            top = (out.top1_after_count if self.eg_weight == "alpha_T_after" else out.top1_count).float()
            cnt += (top > 0).float()
            pix += top
        return cnt, pix

    def after_mapping(self, ctx: PruneContext) -> torch.Tensor:
        cnt, pix = self.counts(ctx)
        if self.rule == "equal_removal":
            return self.keep_top(ctx, cnt, pix)
        return self.keep_authors(ctx, cnt >= self.eg_view_num)
