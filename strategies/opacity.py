"""LightGaussian's global significance: how often and how opaquely a Gaussian is hit, times its volume.

LightGaussian scores GS_j = sum over training views and pixels of 1(G_j hits pixel) * o_j * gamma(V_j)
with gamma(V) = min(V / V_90, 1)^beta, beta = 0.1, V_90 the 90th-percentile volume. In SLAM the
training views arrive one keyframe at a time and Gaussians are born all along the drive. A sum since
birth ranks a Gaussian born one keyframe ago lowest merely for its age: it is pruned, and its hole
is re-seeded. So the score is per observation: the mean of o_j * hits_j over the prune calls whose
view the Gaussian was hit in, times the volume factor at scoring.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import torch

from bench.api import PruneContext, Strategy, StrategyError, setting, top_k_keep

STATE_SIGNIFICANCE = "opacity_significance"  # [N] sum over observing views of o_i * hit_count_i
STATE_VIEWS = "opacity_views"  # [N] views (prune calls) in which the Gaussian hit at least one pixel


def volume_factor(log_scales: torch.Tensor, quantile: float, power: float) -> torch.Tensor:
    """gamma(V) [N] = min(V / V_q, 1)^power, V = prod(exp(log_scales)), V_q the ``quantile`` volume.

    The published LightGaussian code divides by the value 90% of the way down the descending
    sort and does not clip; we follow the paper's formula (90th percentile, clipped to 1).
    """
    log_v = log_scales.detach().sum(-1)  # [N] log volume (the 4/3 pi constant cancels)
    k = min(max(int(math.ceil(quantile * log_v.numel())), 1), log_v.numel())
    log_vq = torch.kthvalue(log_v, k).values
    return torch.exp(power * (log_v - log_vq).clamp(max=0.0))  # in log space: no under/overflow for tiny scales


@dataclass
class OpacityPruning(Strategy):
    """Prune the candidates of lowest accumulated significance down to N_tar (ctx.n_target)."""

    description: ClassVar[str] = "LightGaussian: opacity x hit count per observing view x volume^0.1"

    use_volume: bool = setting(True, "bool")  # multiply by the normalised volume factor gamma(V)
    volume_power: float = setting(0.1, "float", lo=0.0)  # beta in gamma(V) = min(V / V_90, 1)^beta
    # V_90: volumes are normalised by this quantile of the map's volumes
    volume_quantile: float = setting(0.9, "float", lo=0.0, hi=1.0, lo_open=True)

    def state_spec(self) -> dict[str, torch.dtype]:
        return {STATE_SIGNIFICANCE: torch.float32, STATE_VIEWS: torch.float32}

    def significance(self, ctx: PruneContext) -> torch.Tensor:
        """[N] score after this view's hits have been accumulated: the mean over observing views."""
        score = ctx.state[STATE_SIGNIFICANCE] / ctx.state[STATE_VIEWS].clamp_min(1)
        if self.use_volume and score.numel():
            score = score * volume_factor(ctx.gaussians.log_scales, self.volume_quantile, self.volume_power)
        return score

    def after_mapping(self, ctx: PruneContext) -> torch.Tensor:
        if ctx.raster.hit_count is None:
            raise StrategyError("expected rasterize(..., stats=True) outputs, found hit_count None")
        hits = ctx.raster.hit_count.to(torch.float32)  # [N] pixels hit in this keyframe
        ctx.state[STATE_SIGNIFICANCE] += ctx.gaussians.opacities.detach() * hits
        ctx.state[STATE_VIEWS] += (hits > 0).to(torch.float32)
        return top_k_keep(self.significance(ctx), ctx.candidates, ctx.n_target)

    def cap_score(self, ctx: PruneContext) -> torch.Tensor:
        """The significance accumulated over the prunes so far, this view's hits not added (slam.densify.cap)."""
        return self.significance(ctx)
