"""Speedy-Splat's score: the squared opacity-scaled gradient of the image sum, per Gaussian.

Read: j-alex-hanson/speedy-splat @ 6b523aa3ba4d1085317e9aa7700d7d980fd1996d (``train.py`` ``score_func``
and ``prune``; ``prune_gaussians``), rasterizer j-alex-hanson/speedy-splat-rasterizer @
0a4245f7f73e29085cc35348f7558f6b087d828f (``backward.cu``: ``dL_dG = con_o.w * dL_dalpha``,
``atomicAdd(dL_dG2[j], dL_dG * dL_dG)``, with L = image.sum()).

S_j = sum over the scoring views and pixels of (o_j dI/dalpha_ij)^2, I the image summed over its
channels (channels summed before squaring), the background included. The authors get it from one
backward pass per view; here the rasterizer evaluates the same closed form in its forward pass
(``alpha_grad_sq``; no parameter gradient is touched). The colour is the map's RGB as rendered (the
authors' is the SH colour clamped at 0; the maps here store RGB).
Keep rules: equal_removal (top N_tar by S) or ``rule=authors``: the sort-index rule at
``ss_prune_ratio`` (0.8, the authors' ``densify_prune_ratio``; 0.3 after densification).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import torch

from bench.api import PruneContext, setting
from strategies._criteria import RenderCriterion, sort_index_prune


@dataclass
class SpeedySplatPruning(RenderCriterion):
    """Keep the Gaussians whose opacity most moves the rendered image over the scoring views."""

    description: ClassVar[str] = "Speedy-Splat (6b523aa3): sum_views sum_px (o dI/dalpha)^2"
    reads: ClassVar[frozenset[str]] = frozenset({"alpha_grad_sq"})

    ss_prune_ratio: float = setting(0.8, "float", lo=0.0, hi=1.0)  # rule=authors: sort-index percent

    def score(self, ctx: PruneContext) -> torch.Tensor:
        s = torch.zeros(len(ctx.gaussians), device=ctx.candidates.device)
        for out in self.views(ctx, ("alpha_grad_sq",)):
            assert out.alpha_grad_sq is not None  # asked for in extra
            s += out.alpha_grad_sq.float()
        return s

    def cap_score(self, ctx: PruneContext) -> torch.Tensor:
        """The criterion's score over its scoring views ranks the map at slam.densify.cap."""
        return self.score(ctx)

    def after_mapping(self, ctx: PruneContext) -> torch.Tensor:
        s = self.score(ctx)
        if self.rule == "equal_removal":
            return self.keep_top(ctx, s)
        return self.keep_authors(ctx, sort_index_prune(s, ctx.candidates, self.ss_prune_ratio))
