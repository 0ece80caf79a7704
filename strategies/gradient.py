"""LP-3DGS as the Pocket-SLAM paper describes it: importance is accumulated tracking-gradient magnitude.

Gaussians that tracking never pulls on contribute nothing to pose estimation; the ones with the
smallest accumulated ||dL/dG_i|| are pruned first.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import torch

from bench.strategy import PruneContext, Strategy, TrackingContext, top_k_keep

STATE_GRAD_SUM = "gradient_importance"  # [N] sum of g_i over every tracked frame since the Gaussian's birth


@dataclass
class GradientPruning(Strategy):
    """Prune the candidates of lowest accumulated gradient norm down to N_tar (ctx.n_target)."""

    description: ClassVar[str] = "LP-3DGS: accumulated tracking-gradient magnitude"

    def state_spec(self) -> dict[str, torch.dtype]:
        return {STATE_GRAD_SUM: torch.float32}

    def on_tracking_step(self, ctx: TrackingContext) -> None:
        ctx.state[STATE_GRAD_SUM] += ctx.grad_norm.detach().to(torch.float32)

    def after_mapping(self, ctx: PruneContext) -> torch.Tensor:
        return top_k_keep(ctx.state[STATE_GRAD_SUM], ctx.candidates, ctx.n_target) | ctx.is_new
