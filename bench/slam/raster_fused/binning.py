"""Tile intersection and sort: the Gaussians that touch a tile, and the (tile, Gaussian) pairs by tile, then depth."""

from __future__ import annotations

import numba
import numpy as np
import torch
from numba import njit, prange

from bench.slam.raster_fused.threads import set_threads


@njit(cache=True, inline="always")
def _band_rows(band, n_bands, tiles_y):  # pragma: no cover - compiled
    """Tile rows [lo, hi) of band ``band`` of ``n_bands``."""
    return band * tiles_y // n_bands, (band + 1) * tiles_y // n_bands


@njit(parallel=True, cache=True)
def bin_pairs_kernel(order, rect, n_tiles, tiles_x, n_bands):  # pragma: no cover - compiled
    """Counting sort of (tile, Gaussian) pairs by tile; within a tile by depth (``order`` is depth-sorted).

    rect: [N, 4] int32 tile rectangle (x0, x1, y0, y1), empty when x0 == x1 or y0 == y1.
    Returns tile_start [n_tiles + 1] (int64) and gid [P] (int32).

    ``n_bands`` bands of tile rows, one a thread: each walks the whole depth order for the pairs in its
    band, so every tile's list is written by one thread in depth order, the same lists on any count.
    """
    tiles_y = n_tiles // tiles_x
    counts = np.zeros(n_tiles + 1, np.int64)
    for band in prange(n_bands):
        y_lo, y_hi = _band_rows(band, n_bands, tiles_y)
        for j in range(order.shape[0]):
            g = order[j]
            for ty in range(max(rect[g, 2], y_lo), min(rect[g, 3], y_hi)):
                for tx in range(rect[g, 0], rect[g, 1]):
                    counts[ty * tiles_x + tx + 1] += 1
    for t in range(n_tiles):
        counts[t + 1] += counts[t]
    gid = np.empty(counts[n_tiles], np.int32)
    fill = counts[:n_tiles].copy()
    for band in prange(n_bands):
        y_lo, y_hi = _band_rows(band, n_bands, tiles_y)
        for j in range(order.shape[0]):
            g = order[j]
            for ty in range(max(rect[g, 2], y_lo), min(rect[g, 3], y_hi)):
                for tx in range(rect[g, 0], rect[g, 1]):
                    t = ty * tiles_x + tx
                    gid[fill[t]] = g
                    fill[t] += 1
    return counts, gid


@njit(cache=True)
def depth_order(z, rect):  # pragma: no cover - compiled
    """The Gaussians with a non-empty tile rectangle, in the order ``torch.argsort(z, stable=True)`` puts them.

    An LSD radix sort (four stable 8-bit passes) on keys that order as the float32 values do; a general
    comparison sort of every Gaussian was most of the binning's time, and culled Gaussians add no pair.
    z: [N] float32; rect: [N, 4] int32. Returns [M] int32.
    """
    n = z.shape[0]
    m = 0
    for g in range(n):
        if rect[g, 0] < rect[g, 1] and rect[g, 2] < rect[g, 3]:
            m += 1
    idx = np.empty(m, np.int32)
    key = np.empty(m, np.int64)
    bits = z.view(np.uint32)
    j = 0
    for g in range(n):
        if rect[g, 0] < rect[g, 1] and rect[g, 2] < rect[g, 3]:
            b = np.int64(bits[g]) if z[g] != 0 else np.int64(0)  # -0.0 ties with 0.0, as in argsort
            # negative values: all bits flipped (larger magnitude first); positive: above every negative
            key[j] = b ^ 0xFFFFFFFF if b >= 0x80000000 else b | 0x80000000
            idx[j] = g
            j += 1
    idx2 = np.empty(m, np.int32)
    key2 = np.empty(m, np.int64)
    start = np.empty(257, np.int64)
    for shift in range(0, 32, 8):
        start[:] = 0
        for i in range(m):
            start[((key[i] >> shift) & 255) + 1] += 1
        for d in range(256):
            start[d + 1] += start[d]
        for i in range(m):
            d = (key[i] >> shift) & 255
            p = start[d]
            idx2[p] = idx[i]
            key2[p] = key[i]
            start[d] = p + 1
        idx, idx2 = idx2, idx
        key, key2 = key2, key
    return idx


def bin_pairs(
    rect: torch.Tensor, depths: torch.Tensor, n_tiles: int, tiles_x: int
) -> tuple[torch.Tensor, torch.Tensor]:
    """(tile_start [n_tiles + 1] int64, gid [P] int32): pairs sorted by tile, then by depth.

    rect: [N, 4] int32 (x0, x1, y0, y1) tile rectangle of each Gaussian, empty when culled.
    """
    z = depths.detach().contiguous()
    if z.dtype == torch.float32:
        order = depth_order(z.numpy(), rect.numpy())  # [M] the Gaussians that touch a tile, by depth
    else:
        order = torch.argsort(z, stable=True).to(torch.int32).numpy()  # [N]
    set_threads(int(order.shape[0]))
    n_bands = max(1, min(numba.get_num_threads(), n_tiles // tiles_x))  # bands of tile rows, one a thread
    tile_start, gid = bin_pairs_kernel(order, rect.numpy(), n_tiles, tiles_x, n_bands)
    return torch.from_numpy(tile_start), torch.from_numpy(gid)


@njit(cache=True)
def in_view_kernel(rect, out):  # pragma: no cover - compiled
    """out[:V] = indices of the Gaussians with a non-empty tile rectangle, ascending; returns V."""
    v = 0
    for g in range(rect.shape[0]):
        if rect[g, 0] < rect[g, 1] and rect[g, 2] < rect[g, 3]:
            out[v] = g
            v += 1
    return v


def in_view(rect: torch.Tensor) -> torch.Tensor:
    """[V] int64: the Gaussians that touch a tile (rect [N, 4] int32 as ``project`` returns it), in index order."""
    out = torch.empty(rect.shape[0], dtype=torch.int64)
    return out[: in_view_kernel(rect.numpy(), out.numpy())]
