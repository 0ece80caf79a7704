"""A differentiable 16x16-tile Gaussian rasterizer: one projection front, two compositing backends.

The front (EWA projection, culling, tile rectangles) is torch, so autograd carries gradients from
the screen-space quantities to every Gaussian parameter and the camera pose. Compositing is either
the ``torch`` reference below (CPU and CUDA) or the compiled ``fused`` CPU backend
(``bench/slam/raster_fused/``), whose memory scales with Gaussians, pairs and pixels.

Both follow the 3DGS CUDA conventions so that pruning statistics mean what they mean in
the paper's code: EWA projection with a 0.3 px low-pass, alpha = min(0.99, o exp(-d^T S'^-1 d / 2)),
contributions below 1/255 skipped, compositing front to back per tile and stopped once
transmittance would fall below 1e-4. In the torch reference, instead of a per-pixel loop, each tile's depth-sorted
Gaussian list is padded into a dense block [tiles, 256, K] and composited with a cumulative
sum of log-transmittance, so autograd provides gradients for every Gaussian and the pose.
Tiles are grouped by list length before padding to bound wasted work.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from bench.errors import ConfigError
from bench.slam.conic import conic
from bench.slam.se3 import quat_to_rotmat

TILE_PX = 16
ALPHA_MIN = 1.0 / 255.0
ALPHA_MAX = 0.99
T_MIN = 1e-4
LOG_T_MIN = math.log(T_MIN)
LOWPASS_PX2 = 0.3
CHUNK_ELEMS = 1 << 22  # pixel x Gaussian pairs per composited block


@dataclass
class RasterOutput:
    """What one render returns; per-Gaussian fields are [N] unless noted and cover every Gaussian."""

    color: torch.Tensor  # [H, W, 3]
    depth: torch.Tensor  # [H, W] expected z (not normalised by alpha)
    alpha: torch.Tensor  # [H, W] accumulated opacity (silhouette)
    means2d: torch.Tensor  # [N, 2] projected centre, px
    cov2d: torch.Tensor  # [N, 2, 2] screen covariance incl. low-pass, px^2; 0 where the centre is culled
    depths: torch.Tensor  # [N] camera z, m
    radius_px: torch.Tensor  # [N] int, ceil(3 sigma_max); 0 = not rendered
    tile_id: torch.Tensor  # [N] int, 16x16 tile holding the centre; -1 behind camera / outside image
    tiles_xy: tuple[int, int]  # tile grid (tiles_x, tiles_y)
    coverage: torch.Tensor | None  # [N] C_i = sum_p o_i exp(-d^T S'^-1 d / 2) over the image (stats=True)
    hit_count: torch.Tensor | None  # [N] pixels the Gaussian contributed to (stats=True)
    max_weight: torch.Tensor | None  # [N] max blending weight alpha*T over pixels (stats=True)
    # the pruning criteria's statistics, [N] each, computed only when ``rasterize(extra=...)`` names them
    # (EXTRA_STATS); T is the transmittance in front of the Gaussian, sums and counts run over the image
    weight_sum: torch.Tensor | None = None  # "weight_sum": sum alpha*T (Mini-Splatting)
    opacity_t_sum: torch.Tensor | None = None  # "weight_sum": sum o*T (LightGaussian's newest rasterizer)
    top1_count: torch.Tensor | None = None  # "top1": pixels whose largest alpha*T is this Gaussian's
    top1_after_count: torch.Tensor | None = None  # "top1": the same by alpha*T*(1 - alpha) (EfficientGS's code)
    alpha_grad_sq: torch.Tensor | None = None  # "alpha_grad_sq": sum (o dI/dalpha)^2, I the channel-summed image


# what ``rasterize(extra=...)`` may ask for, and the RasterOutput fields each one fills
EXTRA_STATS: dict[str, tuple[str, ...]] = {
    "weight_sum": ("weight_sum", "opacity_t_sum"),
    "top1": ("top1_count", "top1_after_count"),
    "alpha_grad_sq": ("alpha_grad_sq",),
}


def check_extra(extra) -> frozenset[str]:
    """``extra`` as a set, or a one-line ConfigError naming what is not a statistic."""
    extra = frozenset(extra or ())
    unknown = sorted(extra - set(EXTRA_STATS))
    if unknown:
        raise ConfigError(
            f"rasterize extra statistics: expected among {', '.join(EXTRA_STATS)}, found {', '.join(unknown)}"
        )
    return extra


def covariance3d(log_scales: torch.Tensor, quats: torch.Tensor) -> torch.Tensor:
    """R S S^T R^T from log-scales [N, 3] and quaternions [N, 4] -> [N, 3, 3]."""
    R = quat_to_rotmat(quats)
    M = R * torch.exp(log_scales)[:, None, :]
    return M @ M.transpose(1, 2)


def drawn_log_scales(log_scales: torch.Tensor, isotropic: bool) -> torch.Tensor:
    """The log-scales [N, 3] a map is drawn with: as stored, or under ``slam.isotropic`` their mean on every
    axis (the three columns then get equal gradients and stay equal; the map file keeps all three)."""
    return log_scales.mean(-1, keepdim=True).expand(-1, 3) if isotropic else log_scales


def antialias_compensation(cov: torch.Tensor) -> torch.Tensor:
    """Mip-Splatting's 2D filter (gsplat's ``rasterize_mode="antialiased"``): the opacity factor
    sqrt(det(S) / det(S + 0.3 I)) [N] for screen covariances ``cov`` [N, 3] (a, b, c) that already hold
    the 0.3 px low-pass.

    Why: the low-pass alone widens a sub-pixel Gaussian to 0.3 px at full opacity, so a Gaussian fitted
    up close (a later, nearer view on a forward drive) paints a thicker, brighter blob into every
    earlier, farther view. The factor keeps the blob's integral, not its peak (Yu et al., CVPR 2024,
    eq. 9; gsplat ``fully_fused_projection``'s ``compensations``)."""
    a, b, c = cov.unbind(-1)
    det = a * c - b * b
    det_raw = (a - LOWPASS_PX2) * (c - LOWPASS_PX2) - b * b
    # below the clamp the factor carries no gradient, where its square root's would be unbounded; a zero
    # covariance (culled by its centre) or a degenerate one draws nothing, and gets 0
    factor = (det_raw / det.clamp_min(1e-12)).clamp_min(1e-12).sqrt()
    return torch.where(det > 0, factor, torch.zeros_like(factor))


def project(
    means: torch.Tensor, cov3d: torch.Tensor, w2c: torch.Tensor, K: torch.Tensor, width: int, height: int
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """EWA splatting: world Gaussians -> (means2d [N, 2], cov2d [N, 2, 2], z [N])."""
    R, t = w2c[:3, :3], w2c[:3, 3]
    p = means @ R.T + t  # [N, 3]
    z = p[:, 2]
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    zs = torch.where(z.abs() < 1e-6, torch.full_like(z, 1e-6), z)
    # clamp the Jacobian's lever arm like 3DGS, so Gaussians far off-screen stay bounded
    lim_x = 1.3 * (0.5 * width / fx)
    lim_y = 1.3 * (0.5 * height / fy)
    tx = torch.clamp(p[:, 0] / zs, -lim_x, lim_x) * zs
    ty = torch.clamp(p[:, 1] / zs, -lim_y, lim_y) * zs
    zero = torch.zeros_like(z)
    J = torch.stack(
        [torch.stack([fx / zs, zero, -fx * tx / zs**2], -1), torch.stack([zero, fy / zs, -fy * ty / zs**2], -1)], -2
    )  # [N, 2, 3]
    T = J @ R  # [N, 2, 3]
    cov2d = T @ cov3d @ T.transpose(1, 2)
    cov2d = cov2d + LOWPASS_PX2 * torch.eye(2, device=means.device, dtype=means.dtype)
    means2d = torch.stack([fx * p[:, 0] / zs + cx, fy * p[:, 1] / zs + cy], -1)
    return means2d, cov2d, z


BACKENDS = ("auto", "fused", "torch", "gsplat")


def resolve_backend(backend: str, device: torch.device) -> str:
    """``auto`` is the compiled ``fused`` backend on CPU; on CUDA, ``gsplat`` where it can run, else
    the torch reference.

    ``gsplat`` (``bench/slam/raster_gsplat.py``) runs on CUDA tensors only; asking for it where it
    cannot run is a config error that says why.
    """
    if backend not in BACKENDS:
        raise ConfigError(f"raster backend must be one of {', '.join(BACKENDS)}; found '{backend}'")
    if backend == "auto":
        if device.type == "cpu":
            return "fused"
        from bench.slam.raster_gsplat import unavailable_reason

        return "gsplat" if unavailable_reason() is None else "torch"
    if backend == "fused" and device.type != "cpu":
        raise ConfigError(
            f"the fused rasterizer runs on cpu tensors; found device '{device}' "
            "(use slam.raster_backend=torch or auto there)"
        )
    if backend == "gsplat":
        if device.type != "cuda":
            raise ConfigError(
                f"slam.raster_backend=gsplat runs on cuda tensors; found device '{device}' "
                "(use slam.raster_backend=fused or auto there)"
            )
        from bench.slam.raster_gsplat import unavailable_reason

        reason = unavailable_reason()
        if reason is not None:
            raise ConfigError(f"slam.raster_backend=gsplat: {reason}")
    return backend


@dataclass
class _Front:
    """Projection and culling shared by both backends (all in torch, differentiable where it matters)."""

    means2d: torch.Tensor  # [N, 2]
    cov2d: torch.Tensor  # [N, 2, 2]
    z: torch.Tensor  # [N]
    conic: torch.Tensor  # [N, 3] (a, b, c) of the inverse covariance
    rect: torch.Tensor  # [N, 4] long tile rectangle (x0, x1, y0, y1); empty for culled Gaussians
    counts: torch.Tensor  # [N] tiles touched
    radius_px: torch.Tensor  # [N] long
    tile_id: torch.Tensor  # [N] long
    tiles_x: int
    tiles_y: int


def _front(means, log_scales, quats, w2c, K, width, height, near_m) -> _Front:
    tiles_x = (width + TILE_PX - 1) // TILE_PX
    tiles_y = (height + TILE_PX - 1) // TILE_PX
    cov3d = covariance3d(log_scales, quats)
    means2d, cov2d, z = project(means, cov3d, w2c, K, width, height)
    a, b, c = cov2d[:, 0, 0], cov2d[:, 0, 1], cov2d[:, 1, 1]
    det = a * c - b * b
    inv = conic(a, b, c)  # [N, 3] inverse covariance

    with torch.no_grad():
        mid = 0.5 * (a + c)
        lam = mid + torch.sqrt(torch.clamp(mid * mid - det, min=0.1))
        radius = torch.ceil(3.0 * torch.sqrt(lam))
        m2 = means2d.detach()
        # in front of the near plane and inside the frustum widened by 30% (3DGS's in_frustum and
        # Jacobian clamp): Gaussians beside or under a moving camera would otherwise smear huge,
        # mis-projected footprints over the image
        in_x = (m2[:, 0] - K[0, 2]).abs() < 1.3 * 0.5 * width
        in_y = (m2[:, 1] - K[1, 2]).abs() < 1.3 * 0.5 * height
        centre = (z > near_m) & in_x & in_y  # [N] culled by its centre where False
        front = centre & (det > 0)
        tmin_x = torch.clamp(torch.floor((m2[:, 0] - radius) / TILE_PX), 0, tiles_x)
        tmax_x = torch.clamp(torch.floor((m2[:, 0] + radius) / TILE_PX) + 1, 0, tiles_x)
        tmin_y = torch.clamp(torch.floor((m2[:, 1] - radius) / TILE_PX), 0, tiles_y)
        tmax_y = torch.clamp(torch.floor((m2[:, 1] + radius) / TILE_PX) + 1, 0, tiles_y)
        span_x = (tmax_x - tmin_x).long()
        span_y = (tmax_y - tmin_y).long()
        counts = torch.where(front, span_x * span_y, torch.zeros_like(span_x))
        rect = torch.stack([tmin_x, tmax_x, tmin_y, tmax_y], -1).long()
        rect[:, 1] = torch.where(counts > 0, rect[:, 1], rect[:, 0])  # culled: empty rectangle
        radius_px = torch.where(counts > 0, radius, torch.zeros_like(radius)).long()
        inside = front & (m2[:, 0] >= 0) & (m2[:, 0] < width) & (m2[:, 1] >= 0) & (m2[:, 1] < height)
        tile_id = torch.where(
            inside,
            (m2[:, 1].clamp(0, height - 1) // TILE_PX).long() * tiles_x
            + (m2[:, 0].clamp(0, width - 1) // TILE_PX).long(),
            torch.full_like(counts, -1),
        )
    cov2d = torch.where(centre[:, None, None], cov2d, torch.zeros_like(cov2d))  # as the fused backend returns it
    return _Front(means2d, cov2d, z, inv, rect, counts, radius_px, tile_id, tiles_x, tiles_y)


def _front_fused(means, log_scales, quats, w2c, K, width, height, near_m) -> _FusedFront:
    """The projection of every Gaussian by one compiled kernel (and its hand-written backward), and
    the index of those in view: the rest of the fused path runs on them alone."""
    from bench.slam import raster_fused

    tiles_x = (width + TILE_PX - 1) // TILE_PX
    tiles_y = (height + TILE_PX - 1) // TILE_PX
    means2d, cov, z, rect, radius_px, tile_id = raster_fused.project(
        means, log_scales, quats, w2c, K, width, height, near_m, tiles_x, tiles_y
    )
    cov2d = cov.index_select(1, _COV2D_ORDER).reshape(-1, 2, 2)  # [N, 2, 2]; a gather: advanced indexing costs more
    vis = raster_fused.in_view(rect)  # [V]
    return _FusedFront(means2d, cov2d, cov, z, rect, radius_px, tile_id, tiles_x, tiles_y, vis)


_COV2D_ORDER = torch.tensor([0, 1, 1, 2])  # (a, b, c) -> [[a, b], [b, c]]


@dataclass
class _FusedFront:
    """The fused path's projection: per-Gaussian fields over all N, and ``vis`` [V] (int64), the
    Gaussians with a tile, in index order.

    On a long drive most of the map is behind the camera; everything after the projection (conic,
    binning, compositing, the per-Gaussian reductions and their autograd) then costs per Gaussian in
    view, not per Gaussian of the map. The pair list keeps its order (depth, ties by index), so the
    results are those of the whole map, bit for bit: the others add no pair."""

    means2d: torch.Tensor  # [N, 2]
    cov2d: torch.Tensor  # [N, 2, 2]
    cov: torch.Tensor  # [N, 3] (a, b, c)
    z: torch.Tensor  # [N]
    rect: torch.Tensor  # [N, 4] int32
    radius_px: torch.Tensor  # [N] long
    tile_id: torch.Tensor  # [N] long
    tiles_x: int
    tiles_y: int
    vis: torch.Tensor  # [V] long


def rasterize(
    means: torch.Tensor,
    log_scales: torch.Tensor,
    quats: torch.Tensor,
    opacities: torch.Tensor,
    colors: torch.Tensor,
    w2c: torch.Tensor,
    K: torch.Tensor,
    width: int,
    height: int,
    background: torch.Tensor | None = None,
    near_m: float = 0.2,
    stats: bool = False,
    depth_far_m: float | None = None,
    backend: str = "auto",
    extra: frozenset[str] | tuple[str, ...] = (),
    antialiased: bool = False,
    gsplat_stats: str = "auto",
) -> RasterOutput:
    """Render Gaussians (world frame) through camera ``w2c`` [4, 4] with intrinsics ``K`` [3, 3].

    ``depth_far_m``: Gaussians farther than this still paint colour and silhouette but add nothing
    to the depth image. A near surface leaking 1% transmittance onto a sky Gaussian at 120 m
    would otherwise shift its rendered depth by 1.2 m and bias depth-supervised tracking.

    ``backend``: ``torch`` (the dense reference that autograd differentiates), ``fused`` (compiled
    CPU kernels, ``bench/slam/raster_fused/``), ``gsplat`` (CUDA, ``bench/slam/raster_gsplat.py``)
    or ``auto`` (see ``resolve_backend``). ``torch`` and ``fused`` return the same outputs and
    gradients up to float32 rounding; ``gsplat`` follows gsplat's footprint and clamp conventions
    (its module docstring lists them).

    ``extra``: the pruning criteria's statistics to compute besides (``EXTRA_STATS``; forward only,
    without gradient); none by default, so a run whose strategy reads none never pays for them.

    ``antialiased``: scale each opacity by ``antialias_compensation`` of its screen covariance, on
    every backend (``slam.raster_antialias``). The statistics then see the scaled opacities.

    ``gsplat_stats``: how the ``gsplat`` backend computes the statistics (``slam.gsplat_stats``: ``torch``,
    ``triton`` or ``auto``); the other backends ignore it.
    """
    extra = check_extra(extra)
    backend = resolve_backend(backend, means.device)
    bg = torch.zeros(3, device=means.device, dtype=means.dtype) if background is None else background
    if backend == "gsplat":
        from bench.slam.raster_gsplat import rasterize_gsplat

        if extra:
            raise ConfigError(
                f"slam.raster_backend=gsplat: statistics {', '.join(sorted(extra))} are not "
                "implemented there (use slam.raster_backend=torch)"
            )
        z = means @ w2c[2, :3] + w2c[2, 3]  # [N] camera z of every Gaussian
        return RasterOutput(
            **rasterize_gsplat(
                means,
                log_scales,
                quats,
                opacities,
                colors,
                z,
                _paint_depth(z, depth_far_m),
                w2c,
                K,
                width,
                height,
                bg,
                near_m,
                stats,
                antialiased,
                gsplat_stats,
            )
        )
    if backend == "fused":
        ff = _front_fused(means, log_scales, quats, w2c, K, width, height, near_m)
        return _render_fused(ff, opacities, colors, depth_far_m, bg, width, height, stats, extra, antialiased)
    fr = _front(means, log_scales, quats, w2c, K, width, height, near_m)
    if antialiased:
        cov = torch.stack([fr.cov2d[:, 0, 0], fr.cov2d[:, 0, 1], fr.cov2d[:, 1, 1]], -1)  # [N, 3]
        opacities = opacities * antialias_compensation(cov).to(opacities.dtype)
    z_paint = _paint_depth(fr.z, depth_far_m)
    return _render_torch(fr, opacities, colors, z_paint, bg, width, height, stats, extra)


def _paint_depth(z: torch.Tensor, depth_far_m: float | None) -> torch.Tensor:
    """The depth each Gaussian paints: z, or 0 beyond ``depth_far_m``."""
    return z if depth_far_m is None else torch.where(z < depth_far_m, z, torch.zeros_like(z))


def _render_fused(
    ff: _FusedFront, opacities, colors, depth_far_m, bg, width, height, stats, extra=frozenset(), antialiased=False
) -> RasterOutput:
    from bench.slam import raster_fused  # numba compiles on first use; the torch backend never needs it

    n_tiles = ff.tiles_x * ff.tiles_y
    n = colors.shape[0]
    vis = ff.vis
    z_v = ff.z.detach().index_select(0, vis)  # [V], for the depth order
    tile_start, gid = raster_fused.bin_pairs(ff.rect.index_select(0, vis), z_v, n_tiles, ff.tiles_x)
    if gid.numel():
        # the Gaussians in view gathered, their conic and antialiasing factor, and the gradients scattered back
        # to [N], in the compositing's own kernels; coverage, hit_count, max_weight [N] (empty without stats)
        acc, t_final, coverage, hit_count, max_weight = raster_fused.composite(
            ff.means2d, ff.cov, opacities, colors, ff.z, vis, gid, tile_start, width, height, ff.tiles_x, stats,
            antialiased, depth_far_m,
        )  # fmt: skip
    else:  # nothing in view: constant images that carry no gradient, as the torch backend returns
        acc, t_final = torch.zeros(width * height, 4), torch.ones(width * height)
        coverage, hit_count, max_weight = torch.zeros(n), torch.zeros(n, dtype=torch.int64), torch.zeros(n)
    dtype = colors.dtype
    ext = {}
    if extra:
        ex = torch.zeros(n, 5)  # [N, 5]: zero out of view
        if gid.numel():
            from bench.slam.raster_fused.criteria_stats import extra_stats

            with torch.no_grad():  # forward-only statistics of the Gaussians in view, as the compositing sees them
                cov_vis = ff.cov.index_select(0, vis)  # [V, 3]
                op_v = opacities.index_select(0, vis)  # [V]
                if antialiased:
                    op_v = op_v * antialias_compensation(cov_vis).to(op_v.dtype)
                ex[vis] = extra_stats(
                    ff.means2d.index_select(0, vis),
                    conic(*cov_vis.unbind(-1)),
                    op_v,
                    colors.index_select(0, vis),
                    gid,
                    tile_start,
                    width,
                    height,
                    ff.tiles_x,
                    float(bg.sum()),
                    "alpha_grad_sq" in extra,
                )
        cols = {
            "weight_sum": ex[:, 0],
            "opacity_t_sum": ex[:, 1],
            "top1_count": ex[:, 2].round().long(),
            "top1_after_count": ex[:, 3].round().long(),
            "alpha_grad_sq": ex[:, 4],
        }
        ext = {
            f: cols[f] if cols[f].dtype == torch.int64 else cols[f].to(dtype)
            for name in extra
            for f in EXTRA_STATS[name]
        }
    return RasterOutput(
        color=(acc[:, :3] + t_final[:, None] * bg).to(dtype).reshape(height, width, 3),
        depth=acc[:, 3].to(dtype).reshape(height, width),
        alpha=(1.0 - t_final).to(dtype).reshape(height, width),
        means2d=ff.means2d,
        cov2d=ff.cov2d,
        depths=ff.z,
        radius_px=ff.radius_px,
        tile_id=ff.tile_id,
        tiles_xy=(ff.tiles_x, ff.tiles_y),
        coverage=coverage.to(dtype) if stats else None,
        hit_count=hit_count if stats else None,
        max_weight=max_weight.to(dtype) if stats else None,
        **ext,
    )


def _render_torch(fr: _Front, opacities, colors, z_paint, bg, width, height, stats, extra=frozenset()) -> RasterOutput:
    means2d, conic, z, counts = fr.means2d, fr.conic, fr.z, fr.counts
    tiles_x, tiles_y = fr.tiles_x, fr.tiles_y
    n_tiles = tiles_x * tiles_y
    device, dtype = means2d.device, means2d.dtype
    N = means2d.shape[0]
    tmin_x, tmin_y = fr.rect[:, 0], fr.rect[:, 2]
    span_x = fr.rect[:, 1] - fr.rect[:, 0]
    with torch.no_grad():
        # (tile, gaussian) pairs, sorted by tile then depth
        gid = torch.repeat_interleave(torch.arange(N, device=device), counts)
        if gid.numel():
            first = torch.cumsum(counts, 0) - counts
            local = torch.arange(gid.numel(), device=device) - first[gid]
            sx = span_x[gid].clamp_min(1)
            tx = tmin_x[gid] + local % sx
            ty = tmin_y[gid] + local // sx
            tid = ty * tiles_x + tx
            depth_rank = torch.empty(N, dtype=torch.long, device=device)
            depth_rank[torch.argsort(z.detach())] = torch.arange(N, device=device)
            order = torch.argsort(tid * N + depth_rank[gid])
            gid, tid = gid[order], tid[order]
        else:
            tid = gid
        per_tile = torch.bincount(tid, minlength=n_tiles)
        tile_start = torch.cumsum(per_tile, 0) - per_tile
        # pixel coordinates of each tile: [n_tiles, 256]
        ly, lx = torch.meshgrid(
            torch.arange(TILE_PX, device=device), torch.arange(TILE_PX, device=device), indexing="ij"
        )
        tyy = torch.arange(n_tiles, device=device) // tiles_x
        txx = torch.arange(n_tiles, device=device) % tiles_x
        px = txx[:, None] * TILE_PX + lx.reshape(1, -1)  # [T, 256]
        py = tyy[:, None] * TILE_PX + ly.reshape(1, -1)
        pix_valid = (px < width) & (py < height)
        pix_lin = torch.where(pix_valid, py * width + px, torch.full_like(px, height * width))

    color_flat = torch.zeros(height * width + 1, 3, device=device, dtype=dtype)
    depth_flat = torch.zeros(height * width + 1, device=device, dtype=dtype)
    alpha_flat = torch.zeros(height * width + 1, device=device, dtype=dtype)
    coverage = torch.zeros(N, device=device, dtype=dtype) if stats else None
    hit_count = torch.zeros(N, device=device, dtype=torch.long) if stats else None
    max_weight = torch.zeros(N, device=device, dtype=dtype) if stats else None
    ext = {f: torch.zeros(N, device=device, dtype=dtype) for name in extra for f in EXTRA_STATS[name]}
    for f in ("top1_count", "top1_after_count"):
        if f in ext:
            ext[f] = ext[f].long()
    csum_ext = torch.cat([colors.sum(-1), colors.new_zeros(1)]).detach()  # [N+1] channel sum of each colour

    # Sentinel Gaussian at index N: zero opacity, used for padding.
    m2_ext = torch.cat([means2d, means2d.new_zeros(1, 2)])
    conic_ext = torch.cat([conic, conic.new_tensor([[1.0, 0.0, 1.0]])])
    log_op_ext = torch.cat([torch.log(opacities.clamp_min(1e-12)), opacities.new_full((1,), -1e4)])
    feat_ext = torch.cat([torch.cat([colors, z_paint[:, None]], 1), colors.new_zeros(1, 4)])  # [N+1, 4]
    fy_, fx_ = (
        t.reshape(-1).to(dtype)
        for t in torch.meshgrid(
            torch.arange(TILE_PX, device=device), torch.arange(TILE_PX, device=device), indexing="ij"
        )
    )
    feat = torch.stack([torch.ones_like(fx_), fx_, fy_, fx_ * fx_, fy_ * fy_, fx_ * fy_], -1)  # [256, 6]

    color_parts, depth_parts, alpha_parts, lin_parts = [], [], [], []
    tile_order = torch.argsort(per_tile, descending=True)
    counts_sorted = per_tile[tile_order].tolist()
    i = 0
    pix_per_tile = TILE_PX * TILE_PX
    while i < n_tiles:
        k_max = counts_sorted[i]
        n_chunk = max(1, CHUNK_ELEMS // max(1, k_max * pix_per_tile))
        tiles = tile_order[i : i + n_chunk]
        i += n_chunk
        lin = pix_lin[tiles].reshape(-1)
        if k_max == 0:
            continue
        with torch.no_grad():
            slot = torch.arange(k_max, device=device)
            idx = tile_start[tiles][:, None] + slot[None, :]  # [t, K]
            ok = slot[None, :] < per_tile[tiles][:, None]
            gidx = torch.where(ok, gid[idx.clamp(max=max(gid.numel() - 1, 0))], torch.full_like(idx, N))
        # The quadratic form, expanded in tile-local pixel coordinates, is one batched matmul:
        # power + log(o) = feat [256, 6] @ coef [t, 6, K], feat = [1, x, y, x^2, y^2, xy].
        origin = torch.stack([txx[tiles], tyy[tiles]], -1).to(dtype) * TILE_PX  # [t, 2]
        mu = m2_ext[gidx] - origin[:, None, :]  # [t, K, 2]
        co = conic_ext[gidx]  # [t, K, 3] = (A, B, C)
        A, B, C = co.unbind(-1)
        mx, my = mu.unbind(-1)
        coef = torch.stack(
            [
                -0.5 * (A * mx * mx + C * my * my) - B * mx * my + log_op_ext[gidx],
                A * mx + B * my,
                C * my + B * mx,
                -0.5 * A,
                -0.5 * C,
                -B,
            ],
            -2,
        )  # [t, 6, K]
        raw_alpha = torch.exp(torch.matmul(feat, coef))  # [t, 256, K]; o * exp(-d^T S^-1 d / 2)
        with torch.no_grad():
            keep = raw_alpha >= ALPHA_MIN
            log_t0 = torch.cumsum(torch.log1p(-torch.clamp(raw_alpha, max=ALPHA_MAX) * keep), dim=-1)
            keep &= log_t0 >= LOG_T_MIN  # prefix mask: compositing stops once T would drop below 1e-4
        alpha = torch.where(keep, torch.clamp(raw_alpha, max=ALPHA_MAX), 0.0)
        log1m = torch.log1p(-alpha)
        log_t = torch.cumsum(log1m, dim=-1)
        w = alpha * torch.exp(log_t - log1m)  # [t, 256, K] blending weight alpha * T_exclusive
        t_final = torch.exp(log_t[..., -1])  # [t, 256]
        cd = torch.matmul(w, feat_ext[gidx])  # [t, 256, 4] = colour, depth
        col = cd[..., :3] + t_final[..., None] * bg
        dep = cd[..., 3]
        color_parts.append(col.reshape(-1, 3))
        depth_parts.append(dep.reshape(-1))
        alpha_parts.append((1.0 - t_final).reshape(-1))
        lin_parts.append(lin)
        if stats:
            assert coverage is not None and hit_count is not None and max_weight is not None  # set when stats
            with torch.no_grad():
                valid_pix = pix_valid[tiles][:, :, None].to(dtype)
                flat_g = gidx[:, None, :].expand_as(w).reshape(-1)
                coverage.index_add_(
                    0, flat_g.clamp(max=N - 1), (raw_alpha.detach() * valid_pix).reshape(-1) * (flat_g < N)
                )
                hits = (keep & (valid_pix > 0)).reshape(-1)
                hit_count.index_add_(0, flat_g[hits], torch.ones_like(flat_g[hits]))
                max_weight.scatter_reduce_(0, flat_g[hits], w.detach().reshape(-1)[hits], reduce="amax")
        if extra:
            with torch.no_grad():
                _extra_torch(
                    ext,
                    extra,
                    gidx,
                    keep & pix_valid[tiles][:, :, None],
                    w.detach(),
                    alpha.detach(),
                    log_t.detach(),
                    log1m.detach(),
                    torch.exp(log_op_ext[gidx]).detach(),
                    csum_ext[gidx],
                    float(bg.sum()),
                    N,
                )

    # tiles with no Gaussians show the background
    empty = (per_tile == 0).nonzero().flatten()
    if empty.numel():
        lin = pix_lin[empty].reshape(-1)
        color_parts.append(bg.expand(lin.numel(), 3))
        depth_parts.append(torch.zeros(lin.numel(), device=device, dtype=dtype))
        alpha_parts.append(torch.zeros(lin.numel(), device=device, dtype=dtype))
        lin_parts.append(lin)
    lin_all = torch.cat(lin_parts)
    color_flat = color_flat.index_put((lin_all,), torch.cat(color_parts))
    depth_flat = depth_flat.index_put((lin_all,), torch.cat(depth_parts))
    alpha_flat = alpha_flat.index_put((lin_all,), torch.cat(alpha_parts))
    return RasterOutput(
        color=color_flat[:-1].reshape(height, width, 3),
        depth=depth_flat[:-1].reshape(height, width),
        alpha=alpha_flat[:-1].reshape(height, width),
        means2d=means2d,
        cov2d=fr.cov2d,
        depths=z,
        radius_px=fr.radius_px,
        tile_id=fr.tile_id,
        tiles_xy=(tiles_x, tiles_y),
        coverage=coverage,
        hit_count=hit_count,
        max_weight=max_weight,
        **ext,
    )


def _extra_torch(ext, extra, gidx, use, w, alpha, log_t, log1m, o, csum, bg_sum, N) -> None:
    """The ``extra`` statistics of one block of tiles added into ``ext`` (the reference for
    ``raster_fused/criteria_stats.py``). gidx [t, K]; use, w, alpha, log_t, log1m [t, 256, K] (use: the
    pair is blended at a pixel of the image); o, csum [t, K]."""
    t, P, K = w.shape
    g = gidx[:, None, :].expand(t, P, K)
    w = torch.where(use, w, 0.0)
    t_before = torch.exp(log_t - log1m)  # [t, 256, K]
    if "weight_sum" in extra:
        ext["weight_sum"].index_add_(0, g[use], w[use])
        ext["opacity_t_sum"].index_add_(0, g[use], (o[:, None, :] * t_before)[use])
    if "top1" in extra:
        for field, wt in (("top1_count", w), ("top1_after_count", torch.where(use, alpha * torch.exp(log_t), 0.0))):
            best, k = wt.max(-1)  # [t, 256]: the first (front-most) of equal maxima
            has = best > 0
            winner = torch.gather(gidx, 1, k.reshape(t, -1)).reshape(t, P)[has]
            ext[field].index_add_(0, winner, torch.ones_like(winner))
    if "alpha_grad_sq" in extra:
        cw = w * csum[:, None, :]  # [t, 256, K]
        front = torch.cumsum(cw, -1)  # colour of the Gaussians up to and including each one
        col = front[..., -1:]
        t_final = torch.exp(log_t[..., -1:])
        inv = 1.0 / (1.0 - alpha)
        d = t_before * csum[:, None, :] - (col - front) * inv - t_final * bg_sum * inv
        v = (o[:, None, :] * d) ** 2
        ext["alpha_grad_sq"].index_add_(0, g[use], v[use])
