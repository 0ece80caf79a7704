"""Every kernel called once ahead of a run, so that numba compiles and caches it (``compile_kernels``)."""

from __future__ import annotations

import torch

from bench.slam.conic import conic
from bench.slam.raster_fused.autograd import composite, project
from bench.slam.raster_fused.binning import bin_pairs, in_view
from bench.slam.raster_fused.criteria_stats import extra_stats
from bench.slam.raster_fused.ssim import SSIM_WINDOW_PX, ssim_map_fused


def compile_kernels() -> None:
    """Call every kernel once on a small view (forward with and without statistics, the criteria's
    statistics; backward to the Gaussians and to the pose), with the argument types of a real run, so
    that numba compiles and caches each of them. The same calls as ``raster._render_fused`` makes,
    without importing it."""
    n, size, tiles = 64, 64, 4
    g = torch.Generator().manual_seed(0)
    means = torch.cat([torch.rand(n, 2, generator=g) - 0.5, torch.full((n, 1), 3.0)], 1)
    params = [
        means,
        torch.full((n, 3), -3.0),
        torch.tensor([1.0, 0, 0, 0]).repeat(n, 1),
        torch.full((n,), 0.8),
        torch.rand(n, 3, generator=g),
    ]
    K = torch.tensor([[40.0, 0, 32], [0, 40.0, 32], [0, 0, 1]])
    for stats, gaussians in ((False, True), (True, False)):
        m, ls, q, op, col = (p.clone().requires_grad_(gaussians) for p in params)
        w2c = torch.eye(4, requires_grad=True)
        m2, cov, z, rect, _, _ = project(m, ls, q, w2c, K, size, size, 0.2, tiles, tiles)
        vis = in_view(rect)
        tile_start, gid = bin_pairs(rect.index_select(0, vis), z.index_select(0, vis), tiles * tiles, tiles)
        acc, t_final, *_ = composite(m2, cov, op, col, z, vis, gid, tile_start, size, size, tiles, stats, stats, 50.0)
        (acc.sum() + t_final.sum()).backward()
        if stats:  # the pruning criteria's statistics (rasterize(extra=...))
            inv = conic(*cov.index_select(0, vis).unbind(-1))  # [V, 3]
            extra_stats(
                m2.index_select(0, vis),
                inv,
                op.index_select(0, vis),
                col.index_select(0, vis),
                gid,
                tile_start,
                size,
                size,
                tiles,
                0.0,
                True,
            )
    # mapping's D-SSIM term (bench.slam.losses.dssim with fused=True)
    img = torch.rand(3, size, size, generator=g, requires_grad=True)
    ssim_map_fused(
        img, torch.rand(3, size, size, generator=g), torch.full((SSIM_WINDOW_PX,), 1.0 / SSIM_WINDOW_PX), 1e-4, 9e-4
    ).sum().backward()
