"""A pruning strategy in its own package: keep the Gaussians the tracker leans on, nearest first."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import torch

from bench.api import PruneContext, Strategy, TrackingContext, top_k_keep


@dataclass
class NearestPruning(Strategy):
    """Score = tracking gradient accumulated since birth / depth; the best N_tar candidates stay."""

    description: ClassVar[str] = "example plugin: tracking gradient over depth"
    depth_power: float = 1.0  # 0 ignores depth; larger values favour near Gaussians more

    def state_spec(self) -> dict[str, torch.dtype]:
        return {"nearest_grad": torch.float32}  # [N], zero for new Gaussians, sliced by the core

    def on_tracking_step(self, ctx: TrackingContext) -> None:
        ctx.state["nearest_grad"] += ctx.grad_norm  # [N] g_i of this frame's last tracking step

    def after_mapping(self, ctx: PruneContext) -> torch.Tensor:
        depth = ctx.raster.depths.clamp_min(1e-3)  # [N] camera-space depth at the keyframe pose
        score = ctx.state["nearest_grad"] / depth**self.depth_power
        return top_k_keep(score, ctx.candidates, ctx.n_target)  # [N] bool keep mask
