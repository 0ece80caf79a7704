"""LP-3DGS as the Pocket-SLAM paper describes it: importance is tracking-gradient magnitude.

Gaussians that tracking never pulls on contribute nothing to pose estimation; the ones with the
smallest ||dL/dG_i|| are pruned first. The score is the mean over the tracked frames that rendered
the Gaussian, not a sum since birth: a sum ranks the newest Gaussians lowest merely for their age,
so they would be pruned and re-seeded at once.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import torch

from bench.api import PruneContext, Strategy, TrackingContext, top_k_keep

STATE_GRAD_SUM = "gradient_importance"  # [N] sum of g_i over the tracked frames that rendered the Gaussian
STATE_FRAMES = "gradient_frames"  # [N] tracked frames that rendered the Gaussian


@dataclass
class GradientPruning(Strategy):
    """Prune the candidates of lowest mean gradient norm per observing frame down to N_tar (ctx.n_target)."""

    description: ClassVar[str] = "LP-3DGS: tracking-gradient magnitude per observing frame"

    def state_spec(self) -> dict[str, torch.dtype]:
        return {STATE_GRAD_SUM: torch.float32, STATE_FRAMES: torch.float32}

    def on_tracking_step(self, ctx: TrackingContext) -> None:
        seen = ctx.raster.radius_px > 0  # [N] rendered at the tracked pose
        ctx.state[STATE_GRAD_SUM] += torch.where(seen, ctx.grad_norm.detach().to(torch.float32), 0.0)
        ctx.state[STATE_FRAMES] += seen.to(torch.float32)

    def score(self, state: dict[str, torch.Tensor]) -> torch.Tensor:
        """[N] mean g_i over the frames that rendered the Gaussian (0 if none did)."""
        return state[STATE_GRAD_SUM] / state[STATE_FRAMES].clamp_min(1)

    def cap_score(self, ctx: PruneContext) -> torch.Tensor:
        """The same mean g_i ranks the map at slam.densify.cap."""
        return self.score(ctx.state)

    def after_mapping(self, ctx: PruneContext) -> torch.Tensor:
        return top_k_keep(self.score(ctx.state), ctx.candidates, ctx.n_target)
