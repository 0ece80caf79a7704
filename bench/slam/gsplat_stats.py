"""The gsplat backend's per-Gaussian statistics in one GPU kernel (Triton), for ``slam.gsplat_stats=triton``.

``bench.slam.raster_gsplat.pair_stats`` computes coverage, hit count and max blending weight in torch, over chunks
of whole tiles that bound its temporaries; each chunk is a few dozen small kernels and a full-resolution frame has
thousands of tiles, so the host's launch time, not the GPU, sets the pace (profiling/gpu_profile.py;
reports/gpu/README.md has the profile). This kernel does the same work with one program per tile: it walks the tile's
pairs front to back over the tile's 256 pixels at once, as gsplat's compositing kernel does, keeps each pixel's
log-transmittance in float64, and adds each pair's figures into the Gaussian's with atomics. It holds no pair x
pixel temporaries, so the statistics add nothing to the peak beyond their outputs.

Same rules as ``pair_stats`` (the agreement test in tests/slam/test_raster_gsplat.py holds the two together):
raw = o exp(-d^T S'^-1 d / 2) at pixel (x, y) sampled at (x, y); coverage sums raw over the tile's pixels inside
the image; alpha = min(alpha_max, raw), skipped below 1/255; a pixel stops before the Gaussian that brings its
transmittance T to 1e-4 or below (``strict_stop``; else below 1e-4); the weight is alpha * T before the pair. The
sums run in another order (a tile's pixels summed in the kernel, pairs added by atomics), so the figures agree to
float rounding, not bit for bit; coverage accumulates in float64 as ``pair_stats`` does.

Triton is not a dependency of the package: it comes with CUDA builds of torch. Without it (or without CUDA) the
torch path runs; ``unavailable_reason()`` says why.
"""

from __future__ import annotations

import functools
from typing import Any

import torch

from bench.slam.gsplat_rules import ALPHA_MIN, LOG_T_STOP, TILE_PX  # gsplat's rules, as the torch chunks use them


@functools.lru_cache(maxsize=1)
def unavailable_reason() -> str | None:
    """None when the Triton kernel can run here; otherwise why not (one line)."""
    if not torch.cuda.is_available():
        return "no CUDA device"
    try:
        import triton  # noqa: F401
    except ImportError as exc:
        return f"triton is not importable ({exc})"
    return None


@functools.lru_cache(maxsize=1)
def _kernel() -> Any:
    """The jitted kernel, built on first use (importing this module needs no Triton)."""
    import triton
    import triton.language as tl

    @triton.jit
    def stats_kernel(
        starts_ptr,  # [T] int64: first pair of each tile
        ends_ptr,  # [T] int64: one past its last pair
        gid_ptr,  # [P] int64: the Gaussian of each pair, front to back inside a tile
        mean_ptr,  # [M, 2] float32 (x, y)
        conic_ptr,  # [M, 3] float32 (a, b, c)
        opac_ptr,  # [M] float32
        cov_ptr,  # [M] float64 out: coverage
        hits_ptr,  # [M] int64 out: hit count
        maxw_ptr,  # [M] float32 out: max weight (starts at 0: weights are >= 0)
        tiles_x,
        width,
        height,
        alpha_max,
        alpha_min,
        log_stop,
        STRICT: tl.constexpr,
        TILE: tl.constexpr,
    ):
        tile = tl.program_id(0)
        start = tl.load(starts_ptr + tile)
        end = tl.load(ends_ptr + tile)
        lane = tl.arange(0, TILE * TILE)
        px = ((tile % tiles_x) * TILE + lane % TILE).to(tl.float32)
        py = ((tile // tiles_x) * TILE + lane // TILE).to(tl.float32)
        valid = (px < width) & (py < height)
        log_t = tl.zeros([TILE * TILE], dtype=tl.float64)  # log T before the pair, per pixel
        k = start
        while k < end:  # a while loop, not range(start, end): Triton's interpreter takes no tensor bounds
            g = tl.load(gid_ptr + k)
            mx = tl.load(mean_ptr + 2 * g)
            my = tl.load(mean_ptr + 2 * g + 1)
            a = tl.load(conic_ptr + 3 * g)
            b = tl.load(conic_ptr + 3 * g + 1)
            c = tl.load(conic_ptr + 3 * g + 2)
            o = tl.load(opac_ptr + g)
            dx = px - mx
            dy = py - my
            power = -0.5 * (a * dx * dx + c * dy * dy) - b * dx * dy
            raw = o * tl.exp(power)
            tl.atomic_add(cov_ptr + g, tl.sum(tl.where(valid, raw, 0.0).to(tl.float64), 0))
            ok = (raw >= alpha_min) & valid
            alpha = tl.where(ok, tl.minimum(raw, alpha_max), 0.0)
            log1m = tl.log(1.0 - alpha.to(tl.float64))
            after = log_t + log1m
            if STRICT:
                keep = ok & (after > log_stop)
            else:
                keep = ok & (after >= log_stop)
            w = tl.where(keep, alpha * tl.exp(log_t).to(tl.float32), 0.0)
            tl.atomic_add(hits_ptr + g, tl.sum(keep.to(tl.int64), 0))
            tl.atomic_max(maxw_ptr + g, tl.max(w, 0))
            log_t = after
            k += 1

    return stats_kernel


def warm(device: torch.device) -> None:
    """Compile (or load from Triton's cache) the kernel for both stop rules on a one-tile scene, before a timed loop."""
    means = torch.tensor([[3.0, 4.0]], device=device)
    conic = torch.tensor([[1.0, 0.0, 1.0]], device=device)
    opacity = torch.tensor([0.5], device=device)
    gid = torch.zeros(1, dtype=torch.long, device=device)
    per_tile = torch.ones(1, dtype=torch.long, device=device)
    for strict in (True, False):
        pair_stats_triton(means, conic, opacity, gid, per_tile, 1, 16, 16, 0.99, strict)


def pair_stats_triton(
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
    """``bench.slam.raster_gsplat.pair_stats`` in one kernel: coverage, hit count and max weight [M].

    Arguments as there: ``means2d`` [M, 2], ``conic`` [M, 3], ``opacity`` [M]; ``pair_gid`` [P] grouped by tile in
    row-major order, front to back inside a tile; ``per_tile`` [T] the pairs of each tile."""
    dev = means2d.device
    m = means2d.shape[0]
    coverage = torch.zeros(m, device=dev, dtype=torch.float64)
    hits = torch.zeros(m, device=dev, dtype=torch.long)
    maxw = torch.zeros(m, device=dev, dtype=torch.float32)
    n_tiles = per_tile.numel()
    if pair_gid.numel() == 0 or n_tiles == 0:
        return coverage.float(), hits, maxw
    ends = torch.cumsum(per_tile.long(), 0)  # [T]
    starts = ends - per_tile.long()
    _kernel()[(n_tiles,)](
        starts,
        ends,
        pair_gid.long().contiguous(),
        means2d.float().contiguous(),
        conic.float().contiguous(),
        opacity.float().contiguous(),
        coverage,
        hits,
        maxw,
        tiles_x,
        width,
        height,
        float(alpha_max),
        ALPHA_MIN,
        LOG_T_STOP,
        STRICT=bool(strict_stop),
        TILE=TILE_PX,
    )
    return coverage.float(), hits, maxw
