"""What the six literature criteria share (issue 42; the conventions and known answers: docs/criteria.md).

Each criterion scores every Gaussian, then keeps by one of two rules:
- ``equal_removal`` (the benchmark's default): the top ``ctx.n_target`` candidates by score, ties
  broken by the criterion's secondary keys and then by the lower index (older Gaussians first), as a
  stable descending sort does;
- ``authors``: the authors' own keep rule, which does not control the removal ratio.

The SLAM options every render-based criterion takes: ``score_views`` (which views the "all training
views" of the authors' code becomes: the keyframes still held by default) and ``protect_new_kf``
(exempt the Gaussians added within the last k keyframes; 0, the default, is the authors' behaviour).
The authors recompute their statistics from scratch at each prune; so does every criterion here
(statistics accumulated as each keyframe is mapped would be cheaper but stale, so they are not offered).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import torch

from bench.api import SCORE_VIEWS, PruneContext, RasterOutput, Strategy, setting

KEEP_RULES: tuple[str, ...] = ("equal_removal", "authors")


def rank_keep(
    keys: list[torch.Tensor], candidates: torch.Tensor, k: int, protected: torch.Tensor | None = None
) -> torch.Tensor:
    """[N] bool: every non-candidate, every ``protected`` candidate, and the best remaining candidates up to
    ``k`` kept in all, ranked by ``keys`` (primary first, each descending), then by the lower index."""
    protected = torch.zeros_like(candidates) if protected is None else protected & candidates
    keep = ~candidates | protected
    idx = (candidates & ~protected).nonzero().flatten()  # ascending index: the last tie-break
    budget = max(k - int(protected.sum()), 0)
    if idx.numel() and budget > 0:
        for key in reversed(keys):  # stable sorts, least significant key first
            idx = idx[torch.sort(key[idx], descending=True, stable=True).indices]
        keep = keep.clone()
        keep[idx[:budget]] = True
    return keep


def sort_index_prune(score: torch.Tensor, candidates: torch.Tensor, percent: float) -> torch.Tensor:
    """[N] bool keep mask of the authors' ``prune_gaussians`` (LightGaussian, Speedy-Splat, LP-3DGS) over the
    candidates: v = sort(score)[int(percent (n - 1))], prune score <= v (ties with v included)."""
    keep = torch.ones_like(candidates)
    idx = candidates.nonzero().flatten()
    if idx.numel() and percent > 0:
        s = score[idx]
        v = torch.sort(s).values[int(percent * (idx.numel() - 1))]
        keep[idx[s <= v]] = False
    return keep


@dataclass
class Criterion(Strategy):
    """The fields and helpers every criterion shares (not a strategy itself: no entry point)."""

    rule: str = setting("equal_removal", "str", choices=KEEP_RULES)  # equal_removal | authors
    protect_new_kf: int = setting(0, "int", lo=0)  # exempt Gaussians added in the last k keyframes (0: none)

    def protected(self, ctx: PruneContext) -> torch.Tensor | None:
        """[N] bool: the Gaussians ``protect_new_kf`` exempts, or None."""
        if self.protect_new_kf <= 0:
            return None
        return ctx.gaussians.birth_kf > ctx.keyframe_index - self.protect_new_kf

    def keep_top(self, ctx: PruneContext, *keys: torch.Tensor) -> torch.Tensor:
        """The equal-removal keep mask by ``keys`` (primary first)."""
        return rank_keep(list(keys), ctx.candidates, ctx.n_target, self.protected(ctx))

    def keep_authors(self, ctx: PruneContext, keep: torch.Tensor) -> torch.Tensor:
        """An authors' keep mask, with ``protect_new_kf`` applied and non-candidates kept."""
        prot = self.protected(ctx)
        keep = keep | ~ctx.candidates
        return keep if prot is None else keep | prot


@dataclass
class RenderCriterion(Criterion):
    """A criterion scored from renders of the scoring views (``score_views``)."""

    # views scored: held_keyframes (every keyframe held, the new one included: the authors' training
    # cameras) | window (the mapping window) | current (the new keyframe only)
    score_views: str = setting("held_keyframes", "str", choices=SCORE_VIEWS)

    def views(self, ctx: PruneContext, extra: tuple[str, ...]) -> Iterator[RasterOutput]:
        """The render of each scoring view, with the ``extra`` statistics."""
        for _, out in ctx.render_views(self.score_views, extra):
            yield out
