"""Pocket-SLAM without the tile budget (the paper's ablation): one global top-N_tar by area score."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import torch

from bench.api import PruneContext, Strategy, setting, top_k_keep
from strategies._area import AREA_MODES, area_score


@dataclass
class AreaPruning(Strategy):
    """Keep the N_tar candidates with the largest rendering-area share S_i (Eqs. 5-6), wherever they are.

    Without per-tile budgets, a few large Gaussians (sky, walls) can take the whole budget and
    empty textured regions; that is what the ablation measures.
    """

    description: ClassVar[str] = "rendering-area score, one global budget (pocket without tile budget)"

    area: str = setting("exact", "str", choices=AREA_MODES)  # C_i: exact | analytic | radius (as in pocket)

    def after_mapping(self, ctx: PruneContext) -> torch.Tensor:
        score = area_score(ctx.raster, ctx.gaussians.opacities, self.area)  # [N]
        return top_k_keep(score, ctx.candidates, ctx.n_target)

    def cap_score(self, ctx: PruneContext) -> torch.Tensor:
        """S_i at the context's view, as pocket's (slam.densify.cap)."""
        return area_score(ctx.raster, ctx.gaussians.opacities, self.area)
