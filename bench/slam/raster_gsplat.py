"""The ``gsplat`` backend: gsplat's CUDA projection, tile binning and compositing behind ``RasterOutput``.

Why: on CUDA the dense torch reference measures its own [tiles, 256, K] blocks rather than the
method; gsplat (nerfstudio-project/gsplat) is the CUDA rasterizer the field runs. This module calls
its building blocks (``fully_fused_projection`` with ``packed=True``, ``isect_tiles``,
``isect_offset_encode``, ``rasterize_to_pixels``), the steps ``gsplat.rasterization`` chains, so
that the [N, 2] screen means a strategy reads are the tensor the loss flows through (their
``.grad`` is then dL/d mean2d, as on the other backends).

Where gsplat's conventions differ from the reference (``bench/slam/raster.py``), what this backend
returns follows gsplat, and the agreement tests bound the difference:

* pixel centres: gsplat samples pixel (x, y) at (x + 0.5, y + 0.5), the reference at (x, y). The
  principal point is shifted by half a pixel before the call and back after it, so the images and
  ``means2d`` are on the reference's pixel grid.
* footprint: gsplat bins a Gaussian into the tiles of an axis-aligned box of min(3.33,
  sqrt(2 ln(255 o))) sigma per axis (the extent where alpha >= 1/255), and culls it when that box
  misses the image, when z <= ``near_m``, or when o < 1/255; the reference bins a square of
  ceil(3 sigma_max) px and culls by the centre (the frustum widened by 30%). Pixels at the rim of
  a footprint and Gaussians whose centre lies outside the image but whose footprint reaches in
  therefore differ. ``radius_px`` is max(gsplat's per-axis radii), 0 where gsplat culls.
* opacity clamp: alpha is clamped at 0.999 (the reference, like 3DGS, at 0.99), and a pixel stops
  before the Gaussian that would bring its transmittance to 1e-4 or below.

Statistics (``stats=True``; computed only then, as on CPU): gsplat's compositing kernel yields no
per-Gaussian coverage, hit count or max weight, so ``pair_stats`` computes them here in torch,
without autograd, over gsplat's own (tile, Gaussian) pairs and with its compositing rules, in
chunks of whole tiles that bound their memory. The values are those of gsplat's image: C_i sums
o_i exp(-d^T S'^-1 d / 2) over the pixels of the tiles gsplat binned Gaussian i into, hit counts
and max weights follow its alpha clamp and stopping rule. Gradient norms come from autograd
through gsplat's backward, as on the other backends; gsplat's ``absgrad`` is not used (no
strategy reads it).
"""

from __future__ import annotations

import functools

import torch

from bench.errors import ConfigError
from bench.slam.gsplat_rules import ALPHA_MIN, GSPLAT_ALPHA_MAX, LOG_T_STOP, TILE_PX

STATS_CHUNK_ELEMS = 1 << 18  # pair x pixel elements per statistics chunk: its temporaries stay a few tens of MiB


@functools.lru_cache(maxsize=1)
def unavailable_reason() -> str | None:
    """None when gsplat can rasterize here; otherwise why not (one line).

    Importing gsplat is cheap; its CUDA extension compiles with nvcc on first use (minutes, once
    per machine: torch's extension cache keeps it), so this loads it once and caches the answer.
    """
    if not torch.cuda.is_available():
        return "gsplat needs a CUDA device and this machine has none"
    try:
        from gsplat.cuda._backend import _C
    except ImportError as exc:
        return f"gsplat is not importable ({exc}); pip install 'pocketbench[gpu]'"
    if _C is None:
        return "gsplat's CUDA extension did not load (no CUDA toolkit found for its JIT build)"
    return None


@functools.lru_cache(maxsize=8)
def _half_pixel(device: torch.device, dtype: torch.dtype) -> torch.Tensor:
    """[3, 3] adds half a pixel to a K's principal point: built once per device, not per call (each element set on a
    CUDA tensor from Python is a copy from the host, which waits for the GPU)."""
    half = torch.zeros(3, 3, dtype=dtype)
    half[0, 2] = half[1, 2] = 0.5
    return half.to(device)


def stats_impl(choice: str, device: torch.device | None = None) -> str:
    """``slam.gsplat_stats`` resolved for tensors on ``device``: ``torch`` or ``triton`` (``auto``: triton where it
    can run; tensors on the CPU, as the tests' stand-in for gsplat passes them, always take the torch chunks)."""
    from bench.slam.gsplat_stats import unavailable_reason

    if choice == "torch" or (device is not None and device.type != "cuda"):
        return "torch"
    reason = unavailable_reason()
    if choice == "triton" and reason is not None:
        raise ConfigError(f"slam.gsplat_stats=triton: {reason} (use slam.gsplat_stats=torch or auto)")
    return "triton" if reason is None else "torch"


def rasterize_gsplat(
    means,
    log_scales,
    quats,
    opacities,
    colors,
    z,
    z_paint,
    w2c,
    K,
    width,
    height,
    bg,
    near_m,
    stats,
    antialiased=False,
    gsplat_stats="auto",
) -> dict:
    """Render with gsplat (CUDA tensors): the fields of ``RasterOutput``, as a dict.

    Arguments as ``bench.slam.raster.rasterize``, plus ``z`` [N], the camera z of every Gaussian, and
    ``z_paint`` [N], the depth each paints; both come from the caller, which keeps this module free
    of imports from ``raster`` (that imports it)."""
    from gsplat import fully_fused_projection, isect_offset_encode, isect_tiles, rasterize_to_pixels

    n = means.shape[0]
    device, dtype = means.device, means.dtype
    tiles_x = (width + TILE_PX - 1) // TILE_PX
    tiles_y = (height + TILE_PX - 1) // TILE_PX
    half = _half_pixel(device, K.dtype)
    _, _, gids, radii, m2_g, depth_g, conics, comps = fully_fused_projection(
        means,
        None,
        quats,
        torch.exp(log_scales),
        w2c[None],
        (K + half)[None],
        width,
        height,
        eps2d=0.3,
        near_plane=near_m,
        far_plane=1e10,
        packed=True,
        opacities=opacities.detach(),
        calc_compensations=antialiased,  # gsplat's rasterize_mode="antialiased" (raster.antialias_compensation)
    )
    gid = gids.long()  # [V] the Gaussians gsplat renders
    # [N, 2] on the reference's pixel grid; the rasterizer reads it back through ``gid``, so the loss
    # flows through this tensor and a strategy's retain_grad on it sees dL/d mean2d
    means2d = torch.zeros(n, 2, device=device, dtype=dtype).index_put((gid,), m2_g - 0.5)
    cov2d = torch.zeros(n, 2, 2, device=device, dtype=dtype)
    radius_px = torch.zeros(n, device=device, dtype=torch.long)
    tile_id = torch.full((n,), -1, device=device, dtype=torch.long)
    coverage = hit_count = max_weight = None
    if stats:
        coverage = torch.zeros(n, device=device, dtype=dtype)
        hit_count = torch.zeros(n, device=device, dtype=torch.long)
        max_weight = torch.zeros(n, device=device, dtype=dtype)
    with torch.no_grad():
        if gid.numel():
            a, b, c = conics.detach().unbind(-1)
            det = a * c - b * b
            cov2d[gid] = torch.stack([c, -b, -b, a], -1).reshape(-1, 2, 2) / det[:, None, None]
            radius_px[gid] = radii.long().amax(-1)
            m2 = means2d[gid].detach()
            inside = (m2[:, 0] >= 0) & (m2[:, 0] < width) & (m2[:, 1] >= 0) & (m2[:, 1] < height)
            tile_id[gid] = torch.where(
                inside, (m2[:, 1] // TILE_PX).long() * tiles_x + (m2[:, 0] // TILE_PX).long(), torch.full_like(gid, -1)
            )
    flatten_ids = None
    if gid.numel():
        _, isect_ids, flatten_ids = isect_tiles(
            m2_g,
            radii,
            depth_g,
            TILE_PX,
            tiles_x,
            tiles_y,
            packed=True,
            n_images=1,
            image_ids=torch.zeros_like(gids),
            gaussian_ids=gids,
        )
        offsets = isect_offset_encode(isect_ids, 1, tiles_x, tiles_y)  # [1, tiles_y, tiles_x]
    if flatten_ids is None or not flatten_ids.numel():  # nothing in view: constant images, no gradient
        return dict(
            color=bg.expand(height, width, 3).clone(),
            depth=torch.zeros(height, width, device=device, dtype=dtype),
            alpha=torch.zeros(height, width, device=device, dtype=dtype),
            means2d=means2d,
            cov2d=cov2d,
            depths=z,
            radius_px=radius_px,
            tile_id=tile_id,
            tiles_xy=(tiles_x, tiles_y),
            coverage=coverage,
            hit_count=hit_count,
            max_weight=max_weight,
        )
    feat = torch.cat([colors, z_paint[:, None]], 1)[gid]  # [V, 4] colour, painted depth
    op_v = opacities[gid] if comps is None else opacities[gid] * comps
    render, alphas = rasterize_to_pixels(
        means2d[gid] + 0.5,
        conics,
        feat.contiguous(),
        op_v.contiguous(),
        width,
        height,
        TILE_PX,
        offsets,
        flatten_ids,
        packed=True,
    )  # no background here: gsplat's packed path checks its shape as [channels]
    render, alpha = render[0], alphas[0, ..., 0]  # [H, W, 4], [H, W]
    if stats:
        with torch.no_grad():
            per_tile = torch.diff(offsets.reshape(-1).long(), append=offsets.new_full((1,), flatten_ids.numel()).long())
            from bench.slam.gsplat_stats import pair_stats_triton

            impl = pair_stats_triton if stats_impl(gsplat_stats, device) == "triton" else pair_stats
            cov_v, hits_v, maxw_v = impl(
                means2d[gid].detach(),
                conics.detach(),
                op_v.detach(),
                flatten_ids.long(),
                per_tile,
                tiles_x,
                width,
                height,
                GSPLAT_ALPHA_MAX,
                strict_stop=True,
            )
            assert coverage is not None and hit_count is not None and max_weight is not None  # set when stats
            coverage[gid], hit_count[gid], max_weight[gid] = cov_v.to(dtype), hits_v, maxw_v.to(dtype)
    return dict(
        color=render[..., :3] + (1.0 - alpha)[..., None] * bg,
        depth=render[..., 3],
        alpha=alpha,
        means2d=means2d,
        cov2d=cov2d,
        depths=z,
        radius_px=radius_px,
        tile_id=tile_id,
        tiles_xy=(tiles_x, tiles_y),
        coverage=coverage,
        hit_count=hit_count,
        max_weight=max_weight,
    )


def pair_stats(
    means2d: torch.Tensor,
    conic: torch.Tensor,
    opacity: torch.Tensor,
    pair_gid: torch.Tensor,
    per_tile: torch.Tensor,
    tiles_x: int,
    width: int,
    height: int,
    alpha_max: float,
    strict_stop: bool,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Coverage C_i, hit count and max blending weight [M] from a tile-sorted pair list, in torch.

    ``means2d`` [M, 2] (pixel (x, y) sampled at (x, y)), ``conic`` [M, 3] (a, b, c) of the inverse
    covariance, ``opacity`` [M]; ``pair_gid`` [P] indexes them, grouped by tile in row-major order,
    front to back inside a tile; ``per_tile`` [T] counts each tile's pairs. A pair's weight is
    alpha * T with alpha = min(alpha_max, raw), raw = o exp(-d^T S'^-1 d / 2), skipped below 1/255;
    a pixel stops before the Gaussian that brings T below 1e-4 (``strict_stop``: to 1e-4 or below,
    gsplat's rule). The rules are those of the compositing kernel whose image the statistics
    describe, so they are parameters. Coverage sums raw over the valid pixels of every tile the
    Gaussian is binned into, as the reference does.

    Work runs over chunks of whole tiles of about ``STATS_CHUNK_ELEMS`` pair x pixel elements, so
    memory stays bounded whatever the map; transmittance is a per-tile prefix sum of
    log(1 - alpha) in float64 (a chunk's prefix sums span many tiles).
    """
    dev = means2d.device
    m = means2d.shape[0]
    coverage = torch.zeros(m, device=dev, dtype=torch.float64)
    hits = torch.zeros(m, device=dev, dtype=torch.long)
    maxw = torch.zeros(m, device=dev, dtype=torch.float32)
    n_pairs = pair_gid.numel()
    if n_pairs == 0:
        return coverage.float(), hits, maxw
    ly, lx = torch.meshgrid(
        torch.arange(TILE_PX, device=dev, dtype=torch.int32),
        torch.arange(TILE_PX, device=dev, dtype=torch.int32),
        indexing="ij",
    )
    lx, ly = lx.reshape(1, -1), ly.reshape(1, -1)  # [1, 256]
    tile_of_pair = torch.repeat_interleave(
        torch.arange(per_tile.numel(), device=dev, dtype=torch.int32), per_tile
    )  # [P]
    ends = torch.cumsum(per_tile, 0).tolist()
    starts = [e - k for e, k in zip(ends, per_tile.tolist(), strict=True)]
    budget = max(1, STATS_CHUNK_ELEMS // (TILE_PX * TILE_PX))
    log_stop = LOG_T_STOP
    t0 = 0
    n_tiles = per_tile.numel()
    while t0 < n_tiles:
        t1 = t0 + 1  # whole tiles, at least one, up to the pair budget
        while t1 < n_tiles and ends[t1] - starts[t0] <= budget:
            t1 += 1
        s, e = starts[t0], ends[t1 - 1]
        t0 = t1
        if e == s:
            continue
        g = pair_gid[s:e]  # [p]
        tile = tile_of_pair[s:e]
        px = (tile % tiles_x)[:, None] * TILE_PX + lx  # [p, 256] int32
        py = (tile // tiles_x)[:, None] * TILE_PX + ly
        valid = (px < width) & (py < height)
        dx = px - means2d[g, 0:1]  # [p, 256] float
        dy = py - means2d[g, 1:2]
        del px, py
        a, b, c = conic[g].unbind(-1)
        power = -0.5 * (a[:, None] * dx * dx + c[:, None] * dy * dy) - b[:, None] * dx * dy
        raw = opacity[g][:, None] * torch.exp(power)  # [p, 256]
        coverage.index_add_(0, g, (raw * valid).sum(1, dtype=torch.float64))
        ok = (raw >= ALPHA_MIN) & valid
        alpha = torch.where(ok, raw.clamp(max=alpha_max), torch.zeros_like(raw))
        log1m = torch.log1p(-alpha.double())  # [p, 256]
        first = torch.searchsorted(tile.contiguous(), tile, right=False)  # [p] first pair of the same tile
        log_t = torch.cumsum(log1m, 0)
        log_t -= (log_t - log1m)[first]  # inclusive log-transmittance inside each tile
        keep = ok & ((log_t > log_stop) if strict_stop else (log_t >= log_stop))
        w = torch.where(keep, alpha * torch.exp(log_t - log1m).float(), torch.zeros_like(alpha))
        hits.index_add_(0, g, keep.sum(1))
        maxw.scatter_reduce_(0, g, w.amax(1), reduce="amax")
    return coverage.float(), hits, maxw
