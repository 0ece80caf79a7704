"""Trimming the Fat: prune Gaussians whose view-space gradient and opacity are both low.

Read: salmanali96/Trimming-the-Fat @ 00cadf006d2f7ea0a38900db6045d013e2c68698 (``scene/gaussian_model.py``
``gradient_aware_prune`` and ``add_densification_stats``; ``train_prune.py`` schedule and arguments).

g_j = xyz_gradient_accum_j / denom_j (0 where denom = 0): the mean norm of dLoss/d(means2D) over the
mapping iterations that rendered j (the core keeps these sums for a strategy that reads
``mapping_grad2d``; nothing is rendered at prune time). Differences SLAM forces: the gradient is in
pixels, not the rasterizer's NDC-scaled units (a per-axis constant; the order changes only for
anisotropic images), and the accumulation window is ``tf_grad_window``: ``since_reset`` (default;
since this strategy's previous prune, the analogue of the authors' densification reset) or
``since_creation``.

Keep rules: ``rule=authors``: prune g < quantile(g, q) and o < quantile(o, q) over the candidates,
q = ``tf_pruning_level`` (0.025). equal_removal: s_j = max(R_g(j), R_o(j)), R the max-rank
(#{k: x_k <= x_j} - 1), the authors' rule at level q being s < q (n - 1); the top N_tar by s, then by
min(R_g, R_o), then by index.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import torch

from bench.api import READS_MAPPING_GRAD2D, PruneContext, StrategyError, setting
from strategies._criteria import Criterion

STATE_SUM0 = "trimfat_grad_sum0"  # [N] the core's gradient sum at this strategy's previous prune
STATE_N0 = "trimfat_grad_n0"  # [N] ... and its iteration count


def max_rank(x: torch.Tensor) -> torch.Tensor:
    """#{k: x_k <= x_j} - 1 per j."""
    return torch.searchsorted(torch.sort(x).values, x, right=True) - 1


@dataclass
class TrimFatPruning(Criterion):
    """Keep the Gaussians whose lower rank of (mapping gradient, opacity) is highest."""

    description: ClassVar[str] = "Trimming the Fat (00cadf00): low view-space gradient AND low opacity"
    reads: ClassVar[frozenset[str]] = frozenset({READS_MAPPING_GRAD2D})

    tf_pruning_level: float = setting(0.025, "float", lo=0.0, hi=1.0)  # q (rule=authors)
    tf_grad_window: str = setting("since_reset", "str", choices=("since_reset", "since_creation"))

    def state_spec(self) -> dict[str, torch.dtype]:
        return {STATE_SUM0: torch.float32, STATE_N0: torch.float32}

    def grad(self, ctx: PruneContext) -> torch.Tensor:
        """g [N]: mean ||dL/d means2d|| over the window's mapping iterations that rendered the Gaussian."""
        if ctx.mapping_grad2d is None:
            raise StrategyError("trimfat: expected PruneContext.mapping_grad2d, found None")
        total, n = ctx.mapping_grad2d
        if self.tf_grad_window == "since_reset":
            total, n = total - ctx.state[STATE_SUM0], n - ctx.state[STATE_N0]
        return torch.where(n > 0, total / n.clamp_min(1), 0.0)

    def after_mapping(self, ctx: PruneContext) -> torch.Tensor:
        g = self.grad(ctx)
        assert ctx.mapping_grad2d is not None  # grad() raised otherwise
        ctx.state[STATE_SUM0].copy_(ctx.mapping_grad2d[0])
        ctx.state[STATE_N0].copy_(ctx.mapping_grad2d[1])
        o = ctx.gaussians.opacities.detach().float()
        idx = ctx.candidates.nonzero().flatten()
        if self.rule == "authors":
            keep = torch.ones_like(ctx.candidates)
            if idx.numel():
                gc, oc = g[idx], o[idx]
                q = self.tf_pruning_level
                keep[idx] = ~((gc < torch.quantile(gc, q)) & (oc < torch.quantile(oc, q)))
            return self.keep_authors(ctx, keep)
        s = torch.zeros_like(g)
        s2 = torch.zeros_like(g)
        if idx.numel():
            rg, ro = max_rank(g[idx]).float(), max_rank(o[idx]).float()
            s[idx], s2[idx] = torch.maximum(rg, ro), torch.minimum(rg, ro)
        return self.keep_top(ctx, s, s2)
