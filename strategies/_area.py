"""The rendering-area score shared by ``pocket`` and ``area`` (paper Eqs. 5-6).

Kept in one place so that the tile-budget ablation (``area``) scores Gaussians exactly as the
full method (``pocket``) does; the two differ only in how the budget is spent.
"""

from __future__ import annotations

import math

import torch

from bench.api import RasterOutput, StrategyError

AREA_MODES: tuple[str, ...] = ("exact", "analytic", "radius")


def coverage(raster: RasterOutput, opacities: torch.Tensor, mode: str = "exact") -> torch.Tensor:
    """C_i [N]: how much of the image Gaussian i paints, summed alpha over pixels (Eq. 5).

    ``exact`` is the rasterizer's per-pixel sum sum_p o_i exp(-d^T Lambda_i^-1 d / 2) over the
    image; ``analytic`` is its closed form without image borders, o_i 2 pi sqrt(det Lambda_i);
    ``radius`` is the cruder o_i pi r_i^2 with r_i the 3-sigma screen radius. The last two are the
    variants in the authors' released code. Gaussians that are not rendered score 0.
    """
    if mode == "exact":
        if raster.coverage is None:
            raise StrategyError("area mode 'exact': expected rasterize(..., stats=True) outputs, found coverage None")
        return raster.coverage.detach()
    rendered = raster.radius_px > 0  # [N]
    o = opacities.detach()
    if mode == "analytic":
        cov = raster.cov2d.detach()  # [N, 2, 2] px^2, includes the 0.3 px^2 low-pass
        det = (cov[:, 0, 0] * cov[:, 1, 1] - cov[:, 0, 1] * cov[:, 1, 0]).clamp_min(0.0)  # [N]
        area = 2.0 * math.pi * torch.sqrt(det)
    elif mode == "radius":
        r = raster.radius_px.to(o.dtype)  # [N] px
        area = math.pi * r * r
    else:
        raise StrategyError(f"area mode: expected one of {', '.join(AREA_MODES)}, found {mode!r}")
    return torch.where(rendered, o * area, torch.zeros_like(area))


def area_score(raster: RasterOutput, opacities: torch.Tensor, mode: str = "exact") -> torch.Tensor:
    """S_i = C_i / sum_j C_j [N] (Eq. 6): a Gaussian's share of the rendered area in this view."""
    c = coverage(raster, opacities, mode)  # [N]
    total = c.sum()
    return c / total if float(total) > 0 else torch.zeros_like(c)
