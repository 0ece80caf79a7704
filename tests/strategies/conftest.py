"""Hand-built scenes for strategy tests: Gaussians placed at chosen pixels, rendered by the real rasterizer.

The camera is the identity with a 64x48 px image (a 4x3 grid of 16 px tiles), so a Gaussian put
at pixel (u, v) lands in tile (v // 16) * 4 + u // 16 through the real projection.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import pytest
import torch

from bench.slam.gaussians import GaussianMap
from bench.slam.raster import rasterize
from bench.slam.strategy import PruneContext, Strategy, TrackingContext


@dataclass
class Scene:
    W: int = 64
    H: int = 48
    FX: float = 40.0
    CX: float = 32.0
    CY: float = 24.0
    TILES_X: int = 4
    rows: list[dict] = field(default_factory=list)

    @property
    def K(self) -> torch.Tensor:
        return torch.tensor([[self.FX, 0.0, self.CX], [0.0, self.FX, self.CY], [0.0, 0.0, 1.0]])

    def tile_of(self, u: float, v: float) -> int:
        """The tile a pixel belongs to, by hand."""
        return int(v // 16) * self.TILES_X + int(u // 16)

    def add(
        self,
        u: float,
        v: float,
        *,
        z: float = 2.0,
        sigma_px: float = 0.6,
        opacity: float = 0.9,
        grad: float = 1.0,
        new: bool = False,
    ) -> int:
        """A Gaussian whose centre projects to pixel (u, v), isotropic with ``sigma_px`` at the image centre."""
        self.rows.append(dict(u=u, v=v, z=z, sigma_px=sigma_px, opacity=opacity, grad=grad, new=new))
        return len(self.rows) - 1

    def add_grid(self, tile_x: int, tile_y: int, n: int, **kw) -> list[int]:
        """``n`` Gaussians spread over one tile (at most 36), with slightly decreasing opacity."""
        out = []
        for i in range(n):
            u = tile_x * 16 + 1.5 + (i % 6) * 2.5
            v = tile_y * 16 + 1.5 + (i // 6) * 2.5
            kw_i = dict(kw)
            kw_i.setdefault("opacity", 0.95 - 0.015 * i)
            out.append(self.add(u, v, **kw_i))
        return out

    def gaussian_map(self, strategy: Strategy | None = None) -> GaussianMap:
        strategy = strategy or Strategy()
        g = GaussianMap(torch.device("cpu"), extra=strategy.extra_params(), state_dtypes=strategy.state_spec())
        r = self.rows
        z = torch.tensor([x["z"] for x in r])
        u = torch.tensor([x["u"] for x in r], dtype=torch.float32)
        v = torch.tensor([x["v"] for x in r], dtype=torch.float32)
        means = torch.stack([(u - self.CX) * z / self.FX, (v - self.CY) * z / self.FX, z], -1)  # [N, 3]
        scale = torch.tensor([x["sigma_px"] for x in r]) * z / self.FX  # [N] m
        o = torch.tensor([x["opacity"] for x in r])
        g.add(
            {
                "means": means,
                "log_scales": torch.log(scale)[:, None].repeat(1, 3),
                "quats": torch.tensor([1.0, 0.0, 0.0, 0.0]).repeat(len(r), 1),
                "opacity_logits": torch.logit(o),
                "colors": torch.full((len(r), 3), 0.5),
            },
            keyframe=0,
        )
        g.birth_kf[torch.tensor([x["new"] for x in r])] = 1  # born in the keyframe being pruned
        return g

    def context(self, g: GaussianMap, keep_ratio: float = 0.4, keyframe_index: int = 1) -> PruneContext:
        """The PruneContext the core would build after mapping keyframe ``keyframe_index`` (identity pose)."""
        with torch.no_grad():
            out = rasterize(
                g.means, g.log_scales, g.quats, g.opacities, g.colors, torch.eye(4), self.K, self.W, self.H, stats=True
            )
        is_new = g.birth_kf == keyframe_index
        grads = torch.tensor([x["grad"] for x in self.rows])
        return PruneContext(
            keyframe_index, g, g.state, out, grads, is_new, (out.tile_id >= 0) & ~is_new, keep_ratio, (self.H, self.W)
        )

    def build(self, strategy: Strategy | None = None, keep_ratio: float = 0.4) -> PruneContext:
        return self.context(self.gaussian_map(strategy), keep_ratio)

    def tracking_context(self, ctx: PruneContext, grad_norm: torch.Tensor, frame_index: int = 0) -> TrackingContext:
        return TrackingContext(frame_index, ctx.keyframe_index, ctx.gaussians, ctx.state, ctx.raster, grad_norm)


def hand_budgets(
    n_target: int, grads: dict[int, list[float]], b_min: int = 5, b_max: int = 200, rounding=math.ceil
) -> dict[int, int]:
    """B_k = clip(round(N_tar G_k / sum G), B_min, B_max), written out the slow way."""
    g_mean = {k: sum(v) / len(v) for k, v in grads.items()}
    total = sum(g_mean.values())
    return {k: min(max(rounding(n_target * g / total), b_min), b_max) for k, g in g_mean.items()}


@pytest.fixture
def scene() -> Scene:
    return Scene()


@pytest.fixture
def budgets():
    return hand_budgets
