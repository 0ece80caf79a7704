"""RadSplat's maximum ray contribution: h_j = max over views and pixels of the blending weight alpha*T.

There is no official code; the reimplementation read is ASU-ESIC-FAN-Lab/LP-3DGS @
0e97321f774b9fed391839426cc9bd555b30319d (``renderCUDA_mw_score``: ``atomicMax(max_weight_score[j],
alpha*T)``; ``scene/gaussian_model_rad_splat.py`` ``prune_list``: the max over the training cameras).
The per-view maximum is the rasterizer's ``max_weight`` statistic; unseen Gaussians score 0.

Keep rules: ``equal_removal`` keeps the top N_tar by h (ties by index). ``rule=authors`` with
``rs_authors=threshold`` keeps h >= ``rs_threshold`` (the paper, 0.01; 0.25 for "RadSplat Light"); with
``rs_authors=percent`` it is LP-3DGS's sort-index rule at ``rs_prune_percent`` (0.6).
SLAM: the "training cameras" are ``score_views`` (default: the keyframes held), re-rendered at each prune.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import torch

from bench.api import PruneContext, StrategyError, setting
from strategies._criteria import RenderCriterion, sort_index_prune


@dataclass
class RadSplatPruning(RenderCriterion):
    """Keep the Gaussians of largest maximum blending weight over the scoring views."""

    description: ClassVar[str] = "RadSplat (LP-3DGS reimpl. 0e97321f): max over views and pixels of alpha*T"

    rs_authors: str = setting("threshold", "str", choices=("threshold", "percent"))  # rule=authors: which one
    rs_threshold: float = setting(0.01, "float", lo=0.0)  # paper: prune h < 0.01
    rs_prune_percent: float = setting(0.6, "float", lo=0.0, hi=1.0)  # LP-3DGS: sort-index rule at 0.6

    def score(self, ctx: PruneContext) -> torch.Tensor:
        """h [N]: max over the scoring views of the per-view max alpha*T (0 where never blended)."""
        h = torch.zeros(len(ctx.gaussians), device=ctx.candidates.device)
        for out in self.views(ctx, ()):
            if out.max_weight is None:
                raise StrategyError("radsplat: expected rasterize(..., stats=True) outputs, found max_weight None")
            h = torch.maximum(h, out.max_weight.detach().float())
        return h

    def cap_score(self, ctx: PruneContext) -> torch.Tensor:
        """The criterion's score over its scoring views ranks the map at slam.densify.cap."""
        return self.score(ctx)

    def after_mapping(self, ctx: PruneContext) -> torch.Tensor:
        h = self.score(ctx)
        if self.rule == "equal_removal":
            return self.keep_top(ctx, h)
        if self.rs_authors == "threshold":
            return self.keep_authors(ctx, h >= self.rs_threshold)
        return self.keep_authors(ctx, sort_index_prune(h, ctx.candidates, self.rs_prune_percent))
