"""Pocket-SLAM: keep the Gaussians that paint the most of the image, with a budget per 16x16 tile.

After a keyframe's mapping, each candidate Gaussian gets the rendering-area score S_i (Eqs. 5-6,
see ``strategies._area``) and belongs to the tile holding its projected centre. A tile's budget
follows how hard tracking pulled on its Gaussians (Eqs. 7-8): tiles whose Gaussians carry large
tracking gradients hold geometry that tracking relies on, so they keep more; every occupied tile
keeps at least ``budget_min`` so no region of the view is emptied.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import torch

from bench.api import TILE_PX, PruneContext, Strategy, StrategyError, check, setting
from strategies._area import AREA_MODES, area_score
from strategies.random import chance_score

BUDGET_ROUNDINGS: tuple[str, ...] = ("ceil", "floor")
RANKS: tuple[str, ...] = ("area", "random")
TILE_SOURCES: tuple[str, ...] = ("center", "zero")


def tile_budgets(
    tile: torch.Tensor,
    grad: torch.Tensor,
    candidates: torch.Tensor,
    n_tiles: int,
    n_target: int,
    budget_min: int,
    budget_max: int,
    rounding: str = "ceil",
) -> tuple[torch.Tensor, torch.Tensor]:
    """Per-tile budgets B_k [T] and candidate counts n_k [T] (Eqs. 7-8).

    G_k is the mean tracking-gradient norm of tile k's candidates, and
    B_k = clip(round(N_tar G_k / sum_j G_j), B_min, B_max) over the occupied tiles. When no
    occupied tile has any gradient (nothing was tracked yet) the target is split evenly, the
    limit of equal G_k. Unoccupied tiles get budget 0.
    """
    idx = candidates.nonzero().flatten()  # [M]
    t = tile[idx]  # [M]
    n_k = torch.bincount(t, minlength=n_tiles)  # [T]
    g_sum = torch.zeros(n_tiles, dtype=torch.float64, device=tile.device)
    g_sum.index_add_(0, t, grad[idx].detach().to(torch.float64))
    occupied = n_k > 0  # [T]
    g_k = torch.where(occupied, g_sum / n_k.clamp_min(1), torch.zeros_like(g_sum))  # [T]
    total = g_k.sum()
    if float(total) > 0:
        raw = n_target * g_k / total  # [T] N_tar * G_k / sum_j G_j, float64 so exact shares stay exact
    else:
        raw = n_target * occupied.to(torch.float64) / occupied.sum().clamp_min(1)
    raw = torch.ceil(raw) if rounding == "ceil" else torch.floor(raw)
    budget = raw.clamp(budget_min, budget_max).to(torch.long)
    return torch.where(occupied, budget, torch.zeros_like(budget)), n_k


def keep_top_per_tile(
    score: torch.Tensor, tile: torch.Tensor, candidates: torch.Tensor, budget: torch.Tensor
) -> torch.Tensor:
    """[N] bool: every non-candidate, plus the ``budget[k]`` best-scoring candidates of each tile k.

    Vectorised as one segmented top-k: sort candidates by score (descending), then stably by
    tile, so each tile's candidates form a contiguous run in score order; a candidate's rank in
    its tile is its position minus the run's start, and it survives if rank < B_k. Ties keep
    the lower index (both sorts are stable).
    """
    keep = ~candidates
    idx = candidates.nonzero().flatten()  # [M]
    if idx.numel() == 0:
        return keep
    t = tile[idx]  # [M]
    order = torch.sort(score[idx], descending=True, stable=True).indices  # [M]
    order = order[torch.sort(t[order], stable=True).indices]  # [M] grouped by tile, score-descending within
    t_sorted = t[order]
    n_k = torch.bincount(t_sorted, minlength=budget.numel())  # [T]
    start = torch.cumsum(n_k, 0) - n_k  # [T] first position of each tile's run
    rank = torch.arange(idx.numel(), device=idx.device) - start[t_sorted]  # [M]
    keep = keep.clone()
    keep[idx[order[rank < budget[t_sorted]]]] = True
    return keep


@dataclass
class PocketPruning(Strategy):
    """The paper's method: per-tile top-B_k by rendering-area score; new Gaussians are exempt.

    Pruning ratio: the budgets are shares of the shared target N_tar = ctx.n_target, so the
    number kept is sum_k min(B_k, n_k); rounding up and the B_min floor can make it exceed N_tar.
    """

    description: ClassVar[str] = "Pocket-SLAM: rendering-area score, per-tile budgets from tracking gradients"

    # tile side in pixels; must equal the rasterizer's tile
    tile_px: int = setting(TILE_PX, "int", lo=TILE_PX, hi=TILE_PX, hint=f"the rasterizer's tile size {TILE_PX}")
    budget_min: int = setting(5, "int", lo=0)  # B_min: every occupied tile keeps at least this many
    budget_max: int = setting(200, "int", lo=1)  # B_max: no tile keeps more than this many
    area: str = setting("exact", "str", choices=AREA_MODES)  # C_i: exact | analytic | radius
    budget_round: str = setting("ceil", "str", choices=BUDGET_ROUNDINGS)  # B_k rounding: ceil | floor
    # which tile a Gaussian belongs to: "center" = the tile of its projected centre (the paper);
    # "zero" = tile (0, 0) for every rendered Gaussian, as in the released code, whose tile lookup
    # reads a zero-filled means2D placeholder. There the one occupied tile gets min(N_tar, B_max), so
    # each prune keeps the B_max rendered older Gaussians of largest area. Only for +experiment=released.
    tile_source: str = setting("center", "str", choices=TILE_SOURCES)
    # what ranks the candidates within a tile: "area" = S_i (the paper); "random" = a uniform draw from the run's
    # seed and the keyframe index (strategies/random.py), so each tile keeps the same count B_k as with S_i: the
    # chance baseline for the criterion alone, with the tile budgets held
    rank: str = setting("area", "str", choices=RANKS)

    def __post_init__(self) -> None:
        super().__post_init__()  # each field's own rule
        # the one rule between two fields
        check(
            "pocket",
            self.budget_max >= self.budget_min,
            f"budget_max: expected an integer >= budget_min ({self.budget_min}) and >= 1, found {self.budget_max!r}",
        )

    def budgets(self, ctx: PruneContext) -> tuple[torch.Tensor, torch.Tensor]:
        """(B_k [T], n_k [T]) for this keyframe's tile grid."""
        tiles_x, tiles_y = ctx.raster.tiles_xy
        h, w = ctx.image_hw
        if (tiles_x, tiles_y) != (math.ceil(w / self.tile_px), math.ceil(h / self.tile_px)):
            raise StrategyError(
                f"raster tile grid {tiles_x}x{tiles_y} does not match a {w}x{h} px image in {self.tile_px} px tiles"
            )
        return tile_budgets(
            self._tiles(ctx),
            ctx.track_grad_mean,
            self._candidates(ctx),
            tiles_x * tiles_y,
            ctx.n_target,
            self.budget_min,
            self.budget_max,
            self.budget_round,
        )

    def after_mapping(self, ctx: PruneContext) -> torch.Tensor:
        if self.rank == "random":
            score = chance_score(ctx)  # [N] iid uniform
        else:
            score = area_score(ctx.raster, ctx.gaussians.opacities, self.area)  # [N] S_i
        budget, _ = self.budgets(ctx)
        return keep_top_per_tile(score, self._tiles(ctx), self._candidates(ctx), budget)

    def cap_score(self, ctx: PruneContext) -> torch.Tensor:
        """S_i at the context's view: at the cap (slam.densify.cap) the Gaussians that paint the least of the
        new keyframe's image make room, those out of its view (S_i = 0) first; the tile budgets play no part."""
        return area_score(ctx.raster, ctx.gaussians.opacities, self.area)

    def _tiles(self, ctx: PruneContext) -> torch.Tensor:
        """[N] tile index per Gaussian (see ``tile_source``)."""
        if self.tile_source == "zero":
            return torch.zeros_like(ctx.raster.tile_id)
        return ctx.raster.tile_id

    def _candidates(self, ctx: PruneContext) -> torch.Tensor:
        """[N] bool: the core's candidates, and only those with a tile (tile_id -1 is never pruned).

        With ``tile_source=zero``: every rendered (radius > 0) Gaussian that is not new, as the
        released code tests its zero placeholder, always inside the image, and the radius.
        """
        if self.tile_source == "zero":
            return ~ctx.is_new & (ctx.raster.radius_px > 0)
        return ctx.candidates & (ctx.raster.tile_id >= 0)
