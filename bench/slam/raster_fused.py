"""The ``fused`` rasterizer backend: compiled CPU kernels for binning, compositing and its gradient.

The torch backend pads every tile's list into dense ``[tiles, 256, K]`` blocks that autograd keeps
for the backward pass, so its memory follows the tile overlaps of the largest Gaussians rather than
the number of Gaussians. This backend keeps what the CUDA rasterizer of 3DGS keeps: the
(tile, Gaussian) list sorted by tile then depth, each Gaussian's projected quantities, and per pixel
the final transmittance and the index of its last contributor. The backward pass walks each
pixel's contributors back to front and recomputes the rest.

Design choices, and why:
- Gaussian-major loops inside a tile: the depth-sorted list is walked once and each Gaussian visits
  only the pixels of its exact 1/255 bounding box (the ellipse where ``o exp(-d^T S^-1 d / 2)``
  reaches 1/255), so the cost is the sum of box areas, not pixels x list length. Per-pixel
  compositing order is still front to back because the list is depth-sorted.
- Vectorised pixels: a Gaussian updates its box 8 or 16 pixels (one AVX2 or AVX-512 register, as
  LLVM picks for the host) at a time, with masks instead of branches, so a pixel outside the
  ellipse costs a lane rather than a mispredicted branch. How the loops are written so that LLVM
  vectorises them is said where the tile state is laid out (``S_X``); check it in the assembly
  (ymm or zmm registers) after a change.
- Work per Gaussian in view: the projection runs over the whole map, but a Gaussian culled by its
  centre costs a few operations there, and everything after it (``raster._render_fused``) runs on
  the Gaussians with a tile. The backward walks a tile's list only down from the last contributor
  of a pixel that a gradient reaches (tracking masks most of the sky and unmapped street).
- Determinism: tiles run in parallel but each writes only its own pixels and its own slice of the
  pair list. Per-Gaussian sums (gradients, pruning statistics) are first written per pair, then
  reduced over pairs in list order by one sequential loop. The result does not depend on the
  thread count or the schedule: bit-identical from run to run.
- Tiles are dealt to threads by their pair count (largest first, round robin) rather than split
  into contiguous halves of the image, so that a thread given the sky does not wait for the one
  given the road. Which thread runs a tile changes nothing in its result.
- Every buffer the kernels fill is a torch tensor (they receive numpy views), so the live-tensor
  memory probe of ``bench/measure/memory.py`` counts it. Only each thread's tile state (10-15 floats per
  pixel of one tile, under 16 KiB) and the kernels' scalars live outside torch.
- float32 throughout, with float32 literals: numba promotes mixed int/float32 arithmetic to float64.
"""

from __future__ import annotations

import math
import os
import subprocess
import sys
from pathlib import Path

import numba
import numpy as np
import torch
from llvmlite import ir as llvm_ir
from numba import njit, prange, types
from numba.extending import intrinsic

from bench.slam.conic import conic

# numba's threading layer: OpenMP first, the work queue where no OpenMP runtime is installed. A
# work-queue worker wakes and parks through the OS on every kernel and then shares the cores with
# torch's spinning OpenMP pool, which slowed the whole SLAM loop on a 2-core machine (measured with
# profiling/loop_profile.py; the README gives the figures). numba chooses when its first parallel kernel runs,
# from its config, which it re-reads from the environment; both are set, whichever module
# imported numba first. A layer named in NUMBA_THREADING_LAYER still wins.
_LAYERS = "omp workqueue tbb"
os.environ.setdefault("NUMBA_THREADING_LAYER_PRIORITY", _LAYERS)
numba.config.THREADING_LAYER_PRIORITY = os.environ["NUMBA_THREADING_LAYER_PRIORITY"].split()

TILE = 16
_F = np.float32
ALPHA_MIN = _F(1.0 / 255.0)
ALPHA_MAX = _F(0.99)
T_MIN = _F(1e-4)
LN255 = _F(math.log(255.0))
# the pruning statistic C_i sums o exp(power) over whole tiles; terms below exp(-20) of the peak are
# dropped, which changes no float32 sum
COVERAGE_POWER_MIN = _F(-20.0)
N_FEAT = 4  # r, g, b, depth
PROJECT_BLOCK = 256  # Gaussians per block of the projection's backward (one set of scratch matrices each)


@njit(cache=True)
def _bin_pairs(order, rect, n_tiles, tiles_x):  # pragma: no cover - compiled
    """Counting sort of (tile, Gaussian) pairs by tile; within a tile by depth (``order`` is depth-sorted).

    rect: [N, 4] int32 tile rectangle (x0, x1, y0, y1), empty when x0 == x1 or y0 == y1.
    Returns tile_start [n_tiles + 1] (int64) and gid [P] (int32).
    """
    counts = np.zeros(n_tiles + 1, np.int64)
    for j in range(order.shape[0]):
        g = order[j]
        for ty in range(rect[g, 2], rect[g, 3]):
            for tx in range(rect[g, 0], rect[g, 1]):
                counts[ty * tiles_x + tx + 1] += 1
    for t in range(n_tiles):
        counts[t + 1] += counts[t]
    gid = np.empty(counts[n_tiles], np.int32)
    fill = counts[:n_tiles].copy()
    for j in range(order.shape[0]):
        g = order[j]
        for ty in range(rect[g, 2], rect[g, 3]):
            for tx in range(rect[g, 0], rect[g, 1]):
                t = ty * tiles_x + tx
                gid[fill[t]] = g
                fill[t] += 1
    return counts, gid


@njit(cache=True)
def _depth_order(z, rect):  # pragma: no cover - compiled
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


# The compositing kernels are written so that LLVM vectorises their pixel loops (8 float32 lanes of
# AVX2, or 16 of AVX-512 where the host runs it at full width); breaking one of these rules gives
# scalar code and still passes every value test (tests/slam/test_raster_fused.py reads the assembly):
# - a tile's per-pixel state is one flat float32 buffer allocated inside the kernel, each quantity
#   at a fixed offset (structure of arrays): one base pointer with constant distances leaves LLVM
#   no aliasing to check at run time (separate arrays, or a per-lane accumulator indexed apart from
#   the pixel, made it check, and fall back to scalar code);
# - indices are unsigned: numba wraps negative signed indices, which makes every load a select;
# - error_model="numpy": with Python's model a float division carries a zero-division branch;
# - no branch in the loop body: a lane that takes no part adds zero and keeps its state (selects);
# - a span is whole rows of 8 px, so the vector loop has no scalar remainder.
# A tile's pixels are stored as two 8-px column halves, each row-major, so the rows of a Gaussian's
# box inside one half are one contiguous span whose length is a multiple of 8.
_U = np.uint64
HALF = TILE // 2
NPIX = TILE * TILE
_UH = _U(HALF)
_UHALF_PIX = _U(NPIX // 2)
# forward state: pixel coordinates, transmittance, accumulated features, last contributor (an index
# into the tile's list, -1 none), saturated flag, and the visiting Gaussian's blending weight
S_X, S_Y, S_T, S_A0, S_A1, S_A2, S_A3, S_LAST, S_DONE, S_W = (_U(j * NPIX) for j in range(10))
S_SIZE = 10 * NPIX
# backward state: pixel coordinates, transmittance in front of the visited Gaussian, last
# contributor, dL/d acc (4), dL/dT_final * T_final, the features accumulated behind the visited
# Gaussian (4), and the visited Gaussian's w and u (see ``_backward_span``)
B_X, B_Y, B_TC, B_LK, B_Q0, B_Q1, B_Q2, B_Q3, B_QT, B_B0, B_B1, B_B2, B_B3, B_W, B_U = (
    _U(j * NPIX) for j in range(15))
B_SIZE = 15 * NPIX
# the forward counts a tile's saturated pixels (to stop early) once per this many list entries; an
# entry after saturation changes nothing, so the period changes no result
SATURATION_CHECK = 8
# one row per Gaussian, one 64-byte cache line: what the compositing reads of a Gaussian
G_MX, G_MY, G_A, G_B, G_C, G_O, G_F0, G_EX, G_EY, G_PMIN = 0, 1, 2, 3, 4, 5, 6, 10, 11, 12
G_SIZE = 16
ALIGN_F32 = 16  # float32s in 64 bytes: a cache line, and an AVX-512 register
_KERNEL = dict(cache=True, fastmath=True, error_model="numpy")  # numpy's model: no zero-division branch


@intrinsic
def _bits_to_f32(typingctx, bits):  # pragma: no cover - compiled
    """The float32 whose bit pattern is the int32 ``bits`` (a bitcast, which LLVM vectorises)."""
    sig = types.float32(types.int32)

    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], llvm_ir.FloatType())

    return sig, codegen


@njit(inline="always", **_KERNEL)
def _exp(x):  # pragma: no cover - compiled
    """float32 exp(x) for x <= 0 as 2^n p(f) (Cephes' expf polynomial), relative error ~1e-7.

    np.exp compiles to a scalar libm call (pip's llvmlite has no vector maths library), which keeps
    every loop around it scalar; this is plain arithmetic, with 2^n put into the exponent bits."""
    x = min(max(x, _F(-87.0)), _F(0.0))
    n = np.floor(x * _F(1.44269504) + _F(0.5))
    f = x - n * _F(0.693359375) + n * _F(2.12194440e-4)
    p = _F(1.9875691500e-4)
    p = p * f + _F(1.3981999507e-3)
    p = p * f + _F(8.3334519073e-3)
    p = p * f + _F(4.1665795894e-2)
    p = p * f + _F(1.6666665459e-1)
    p = p * f + _F(5.0000001201e-1)
    p = p * f * f + f + _F(1.0)
    return p * _bits_to_f32(np.int32(n + _F(127.0)) << np.int32(23))


@njit(parallel=True, **_KERNEL)
def _pack(m2, conic, opac, feat, gp):  # pragma: no cover - compiled
    """gp [N, 16]: each Gaussian's mean, conic, opacity, features, and the half-extents of its 1/255
    box and its exponent threshold, computed once per Gaussian rather than once per (tile, Gaussian)."""
    for g in prange(m2.shape[0]):
        mx, my = m2[g, 0], m2[g, 1]
        a, b, c = conic[g, 0], conic[g, 1], conic[g, 2]
        o = opac[g]
        gp[g, G_MX], gp[g, G_MY], gp[g, G_A], gp[g, G_B], gp[g, G_C], gp[g, G_O] = mx, my, a, b, c, o
        for ch in range(N_FEAT):
            gp[g, G_F0 + ch] = feat[g, ch]
        det = a * c - b * b
        ex = ey = _F(-1.0)  # an empty box
        if o >= ALPHA_MIN and det > _F(0.0):
            r2 = _F(2.0) * (LN255 + np.log(o))  # d^T S^-1 d <= r2  <=>  o exp(power) >= 1/255
            ex = np.sqrt(r2 * c / det) + _F(1e-3)  # axis extents (S_xx = c / det, S_yy = a / det) + a margin
            ey = np.sqrt(r2 * a / det) + _F(1e-3)
        gp[g, G_EX], gp[g, G_EY] = ex, ey
        # below this exponent o exp(power) < 1/255 (with a margin, so the exact test decides at the edge)
        gp[g, G_PMIN] = -LN255 - np.log(o) - _F(1e-3) if o > _F(0.0) else _F(np.inf)
        for j in range(G_PMIN + 1, G_SIZE):
            gp[g, j] = _F(0.0)


@njit(inline="always", **_KERNEL)
def _aligned_state(size):  # pragma: no cover - compiled
    """A tile-state buffer that starts on a 64-byte boundary.

    LLVM's vectorised sums peel scalar iterations until their loads are aligned, so with a buffer at
    an arbitrary address the order of the additions, and their rounding, followed the heap's state:
    a process that had just compiled the kernels got other numbers than one that loaded them from
    numba's cache."""
    raw = np.empty(size + ALIGN_F32, np.float32)
    skip = (ALIGN_F32 - (raw.ctypes.data // 4) % ALIGN_F32) % ALIGN_F32
    return raw[skip:skip + size]


@njit(inline="always", **_KERNEL)
def _box(mx, my, ex, ey, x0, x1, y0, y1):  # pragma: no cover - compiled
    """Pixels [bx0, bx1) x [by0, by1) of the tile within (ex, ey) of (mx, my) (empty if none, or ex < 0)."""
    if ex < _F(0.0):
        return 0, 0, 0, 0
    bx0 = max(x0, int(np.ceil(mx - ex)))
    bx1 = min(x1, int(np.floor(mx + ex)) + 1)
    by0 = max(y0, int(np.ceil(my - ey)))
    by1 = min(y1, int(np.floor(my + ey)) + 1)
    if bx0 >= bx1 or by0 >= by1:
        return 0, 0, 0, 0
    return bx0, bx1, by0, by1


@njit(inline="always", **_KERNEL)
def _row_meets(y, mx, my, a, b, c, slope, q2, dx0, dx1):  # pragma: no cover - compiled
    """Whether row y of the ellipse a dx^2 + 2 b dx dy + c dy^2 <= q2 reaches dx in [dx0, dx1] (float64):
    the quadratic is convex in dx, so its least value there is at its minimiser slope dy, clamped."""
    dy = float(y) - my
    dx = min(max(slope * dy, dx0), dx1)
    return a * dx * dx + 2.0 * b * dx * dy + c * dy * dy <= q2


@njit(inline="always", **_KERNEL)
def _rows(mx, my, a, b, c, p_min, cx0, cx1, by0, by1):  # pragma: no cover - compiled
    """Rows [lo, hi) of [by0, by1) where the 1/255 ellipse meets columns [cx0, cx1).

    A rotated, elongated ellipse leaves the corners of its box empty; the rows dropped here are
    ones where every pixel fails the exact test anyway (power < p_min, i.e. Q > -2 p_min; the
    threshold and the columns are widened, so float32 rounding of the exact test cannot matter)."""
    q2 = -2.0 * float(p_min) * 1.001 + 0.01
    mxd, myd, ad, bd, cd = float(mx), float(my), float(a), float(b), float(c)
    slope = -bd / ad
    dx0, dx1 = float(cx0) - 0.01 - mxd, float(cx1) - 0.99 - mxd
    lo = by0
    while lo < by1 and not _row_meets(lo, mxd, myd, ad, bd, cd, slope, q2, dx0, dx1):
        lo += 1
    hi = by1
    while hi > lo and not _row_meets(hi - 1, mxd, myd, ad, bd, cd, slope, q2, dx0, dx1):
        hi -= 1
    return lo, hi


@njit(inline="always", **_KERNEL)
def _span(h, ry0, ry1, y0):  # pragma: no cover - compiled
    """Flat state indices [lo, hi) of rows [ry0, ry1) of column half h."""
    return _U(h) * _UHALF_PIX + _U(ry0 - y0) * _UH, _U(h) * _UHALF_PIX + _U(ry1 - y0) * _UH


@njit(inline="always", **_KERNEL)
def _tile_pixels(t, tiles_x, width, height):  # pragma: no cover - compiled
    """Pixel range [x0, x1) x [y0, y1) of tile t, clipped at the image border."""
    x0 = (t % tiles_x) * TILE
    y0 = (t // tiles_x) * TILE
    return x0, min(x0 + TILE, width), y0, min(y0 + TILE, height)


@njit(cache=True)
def _schedule(tile_start, n_threads):  # pragma: no cover - compiled
    """Tiles dealt to threads by cost (pairs per tile, largest first, round robin), so that the
    threads finish together: the work of a tile, not its position, decides its thread.

    Returns order [n_tiles] and bounds [n_threads + 1]: thread i runs order[bounds[i]:bounds[i + 1]].
    """
    n_tiles = tile_start.shape[0] - 1
    cost = tile_start[1:] - tile_start[:-1]
    by_cost = np.argsort(-cost, kind="mergesort")
    order = np.empty(n_tiles, np.int64)
    bounds = np.zeros(n_threads + 1, np.int64)
    j = 0
    for th in range(n_threads):
        for r in range(th, n_tiles, n_threads):
            order[j] = by_cost[r]
            j += 1
        bounds[th + 1] = j
    return order, bounds


@njit(inline="always", **_KERNEL)
def _forward_span(st, lo, hi, fx0, fx1, mx, my, a, b, c, o, p_min, f0, f1, f2, f3, kl):  # pragma: no cover
    """One Gaussian over state pixels [lo, hi), masked to its box columns [fx0, fx1): branch-free, so
    that it compiles to 8-lane vector code (a lane that takes no part adds zero and keeps its state)."""
    for i in range(lo, hi):
        xv = st[S_X + i]
        dx = xv - mx
        dy = st[S_Y + i] - my
        power = _F(-0.5) * (a * dx * dx + c * dy * dy) - b * dx * dy
        raw = o * _exp(power)
        alpha = min(raw, ALPHA_MAX)
        tp = st[S_T + i]
        test_t = tp * (_F(1.0) - alpha)
        ok = (xv >= fx0) & (xv < fx1) & (st[S_DONE + i] == _F(0.0)) & (power >= p_min) & (raw >= ALPHA_MIN)
        use = ok & (test_t >= T_MIN)
        w = alpha * tp if use else _F(0.0)
        st[S_A0 + i] += w * f0
        st[S_A1 + i] += w * f1
        st[S_A2 + i] += w * f2
        st[S_A3 + i] += w * f3
        st[S_T + i] = test_t if use else tp
        st[S_LAST + i] = kl if use else st[S_LAST + i]
        st[S_DONE + i] = _F(1.0) if ok & (test_t < T_MIN) else st[S_DONE + i]
        st[S_W + i] = w


@njit(inline="always", **_KERNEL)
def _coverage_span(st, lo, hi, fx0, fx1, mx, my, a, b, c, o):  # pragma: no cover - compiled
    """Sum of o exp(power) over state pixels [lo, hi) in columns [fx0, fx1): the pruning statistic's share."""
    cov = _F(0.0)
    for i in range(lo, hi):
        xv = st[S_X + i]
        dx = xv - mx
        dy = st[S_Y + i] - my
        power = _F(-0.5) * (a * dx * dx + c * dy * dy) - b * dx * dy
        cov += o * _exp(power) if (xv >= fx0) & (xv < fx1) else _F(0.0)
    return cov


@njit(parallel=True, **_KERNEL)
def _forward(gid, tile_start, gp, width, height, tiles_x, stats, order, bounds,
             acc, t_final, last, pair_cov, pair_hits, pair_maxw):  # pragma: no cover - compiled
    """Front-to-back compositing per tile; fills acc [H*W, 4], t_final [H*W], last [H*W] (pair index).

    Each Gaussian of a tile's depth-sorted list updates the rows of its box, one 8-px vector per row
    and column half, so per pixel the order stays front to back. With ``stats`` it also fills, per
    pair, the coverage sum over the tile, the pixels contributed to and the largest blending weight.
    """
    for th in prange(bounds.shape[0] - 1):
        st = _aligned_state(S_SIZE)
        for j in range(bounds[th], bounds[th + 1]):
            t = order[j]
            x0, x1, y0, y1 = _tile_pixels(t, tiles_x, width, height)
            for i in range(NPIX):
                st[S_X + i] = _F(x0 + (i // (NPIX // 2)) * HALF + i % HALF)
                st[S_Y + i] = _F(y0 + (i // HALF) % TILE)
                st[S_T + i] = _F(1.0)
                st[S_A0 + i] = st[S_A1 + i] = st[S_A2 + i] = st[S_A3 + i] = _F(0.0)
                st[S_LAST + i] = _F(-1.0)
                st[S_DONE + i] = _F(0.0)
            s = tile_start[t]
            n_pix = (x1 - x0) * (y1 - y0)
            n_active = n_pix
            for k in range(s, tile_start[t + 1]):
                if (k - s) % SATURATION_CHECK == 0 and n_active > 0:
                    n_done = _F(0.0)
                    for i in range(NPIX):
                        n_done += st[S_DONE + i]
                    n_active = n_pix - int(n_done)
                if n_active == 0 and not stats:
                    break
                g = gid[k]
                mx, my = gp[g, G_MX], gp[g, G_MY]
                a, b, c, o = gp[g, G_A], gp[g, G_B], gp[g, G_C], gp[g, G_O]
                hits = 0
                maxw = _F(0.0)
                bx0, bx1, by0, by1 = _box(mx, my, gp[g, G_EX], gp[g, G_EY], x0, x1, y0, y1)
                if n_active > 0 and by1 > by0:
                    p_min = gp[g, G_PMIN]
                    for h in range((bx0 - x0) // HALF, (bx1 - x0 + HALF - 1) // HALF):
                        ry0, ry1 = _rows(mx, my, a, b, c, p_min, max(bx0, x0 + h * HALF),
                                         min(bx1, x0 + (h + 1) * HALF), by0, by1)
                        lo, hi = _span(h, ry0, ry1, y0)
                        _forward_span(st, lo, hi, _F(bx0), _F(bx1), mx, my, a, b, c, o, p_min, gp[g, G_F0],
                                      gp[g, G_F0 + 1], gp[g, G_F0 + 2], gp[g, G_F0 + 3], _F(k - s))
                        if stats:
                            for i in range(lo, hi):
                                w = st[S_W + i]
                                hits += 1 if w > _F(0.0) else 0
                                maxw = max(maxw, w)
                if stats:
                    pair_hits[k] = hits
                    pair_maxw[k] = maxw
                    cov = _F(0.0)
                    det = a * c - b * b
                    if o > _F(0.0) and det > _F(0.0):
                        r2 = _F(-2.0) * COVERAGE_POWER_MIN
                        cx0, cx1, cy0, cy1 = _box(mx, my, np.sqrt(r2 * c / det) + _F(1.0),
                                                  np.sqrt(r2 * a / det) + _F(1.0), x0, x1, y0, y1)
                        if cy1 > cy0:
                            for h in range((cx0 - x0) // HALF, (cx1 - x0 + HALF - 1) // HALF):
                                lo, hi = _span(h, cy0, cy1, y0)
                                cov += _coverage_span(st, lo, hi, _F(cx0), _F(cx1), mx, my, a, b, c, o)
                    pair_cov[k] = cov
            for y in range(y0, y1):
                for x in range(x0, x1):
                    p = y * width + x
                    i = _U((x - x0) // HALF * (NPIX // 2) + (y - y0) * HALF + (x - x0) % HALF)
                    t_final[p] = st[S_T + i]
                    k_loc = st[S_LAST + i]
                    last[p] = s + int(k_loc) if k_loc >= _F(0.0) else -1
                    acc[p, 0] = st[S_A0 + i]
                    acc[p, 1] = st[S_A1 + i]
                    acc[p, 2] = st[S_A2 + i]
                    acc[p, 3] = st[S_A3 + i]


@njit(inline="always", **_KERNEL)
def _backward_span(st, lo, hi, fx0, fx1, mx, my, a, b, c, o, p_min, f0, f1, f2, f3, kl):  # pragma: no cover
    """One Gaussian over state pixels [lo, hi), back to front: its 10 gradient sums over the span.

    Two loops: the first updates each pixel's state and keeps its blending weight w and
    u = dL/dalpha * exp(power), the second sums them. In one loop the ten running sums and the
    per-Gaussian constants need more than AVX2's 16 vector registers, and the spills cost more
    than the second pass. The mean and conic gradients are linear in (a, b, c) and o, so only the
    moments u dx, u dy, u dx^2, u dy^2, u dx dy are summed."""
    for i in range(lo, hi):
        xv = st[B_X + i]
        dx = xv - mx
        dy = st[B_Y + i] - my
        power = _F(-0.5) * (a * dx * dx + c * dy * dy) - b * dx * dy
        gauss = _exp(power)
        raw = o * gauss
        alpha = min(raw, ALPHA_MAX)
        ok = (xv >= fx0) & (xv < fx1) & (st[B_LK + i] >= kl) & (power >= p_min) & (raw >= ALPHA_MIN)
        okf = _F(1.0) if ok else _F(0.0)
        inv_one_m = _F(1.0) / (_F(1.0) - alpha)
        tcur = st[B_TC + i]
        t_before = tcur * inv_one_m
        w = alpha * t_before * okf
        q0, q1, q2, q3 = st[B_Q0 + i], st[B_Q1 + i], st[B_Q2 + i], st[B_Q3 + i]
        b0, b1, b2, b3 = st[B_B0 + i], st[B_B1 + i], st[B_B2 + i], st[B_B3 + i]
        # d acc / d alpha = f T_before - behind / (1 - alpha); d T_final / d alpha = -T_final / (1 - alpha)
        g_alpha = (t_before * (q0 * f0 + q1 * f1 + q2 * f2 + q3 * f3)
                   - inv_one_m * (q0 * b0 + q1 * b1 + q2 * b2 + q3 * b3 + st[B_QT + i]))
        st[B_B0 + i] = b0 + w * f0
        st[B_B1 + i] = b1 + w * f1
        st[B_B2 + i] = b2 + w * f2
        st[B_B3 + i] = b3 + w * f3
        st[B_TC + i] = tcur * (inv_one_m * okf + (_F(1.0) - okf))
        st[B_W + i] = w
        # the clamp at 0.99 passes no gradient
        st[B_U + i] = g_alpha * gauss * (_F(1.0) if ok & (raw < ALPHA_MAX) else _F(0.0))
    s1 = s2 = sxx = syy = sxy = go = _F(0.0)
    gf0 = gf1 = gf2 = gf3 = _F(0.0)
    for i in range(lo, hi):
        dx = st[B_X + i] - mx
        dy = st[B_Y + i] - my
        w = st[B_W + i]
        u = st[B_U + i]
        gf0 += w * st[B_Q0 + i]
        gf1 += w * st[B_Q1 + i]
        gf2 += w * st[B_Q2 + i]
        gf3 += w * st[B_Q3 + i]
        go += u
        s1 += u * dx
        s2 += u * dy
        sxx += u * (dx * dx)
        syy += u * (dy * dy)
        sxy += u * (dx * dy)
    # d power / d mean = (a dx + b dy, b dx + c dy); d power / d(a, b, c) = -(dx^2 / 2, dx dy, dy^2 / 2)
    return (o * (a * s1 + b * s2), o * (b * s1 + c * s2), _F(-0.5) * o * sxx, -o * sxy, _F(-0.5) * o * syy,
            go, gf0, gf1, gf2, gf3)


@njit(parallel=True, **_KERNEL)
def _backward(gid, tile_start, gp, width, height, tiles_x, order, bounds,
              t_final, last, g_acc, g_t, pair_grad):  # pragma: no cover - compiled
    """Per tile, its list back to front from the last contributor (3DGS's backward pass), each
    Gaussian over the rows of its box as in ``_forward``.

    pair_grad [P, 10]: d/d(mean2d x, y), d/d(conic a, b, c), d/d opacity, d/d features (4) of the
    pair's Gaussian, summed over the tile's pixels in a fixed order.
    """
    for th in prange(bounds.shape[0] - 1):
        st = _aligned_state(B_SIZE)
        for j in range(bounds[th], bounds[th + 1]):
            t = order[j]
            x0, x1, y0, y1 = _tile_pixels(t, tiles_x, width, height)
            s, e = tile_start[t], tile_start[t + 1]
            for k in range(s, e):
                for m in range(10):
                    pair_grad[k, m] = _F(0.0)
            k_last = -1
            for i in range(NPIX):
                x = x0 + (i // (NPIX // 2)) * HALF + i % HALF
                y = y0 + (i // HALF) % TILE
                st[B_X + i] = _F(x)
                st[B_Y + i] = _F(y)
                st[B_B0 + i] = st[B_B1 + i] = st[B_B2 + i] = st[B_B3 + i] = _F(0.0)
                inside = y < y1 and x < x1
                p = y * width + x if inside else 0
                # a pixel no gradient reaches (outside tracking's mask, say) adds exact zeros: none walked
                flows = inside and (g_acc[p, 0] != 0 or g_acc[p, 1] != 0 or g_acc[p, 2] != 0 or g_acc[p, 3] != 0
                                    or g_t[p] != 0)
                k_pix = last[p] if flows else -1
                k_last = max(k_last, k_pix)
                st[B_LK + i] = _F(k_pix - s) if k_pix >= 0 else _F(-1.0)
                st[B_TC + i] = t_final[p] if inside else _F(1.0)
                st[B_Q0 + i] = g_acc[p, 0] if inside else _F(0.0)
                st[B_Q1 + i] = g_acc[p, 1] if inside else _F(0.0)
                st[B_Q2 + i] = g_acc[p, 2] if inside else _F(0.0)
                st[B_Q3 + i] = g_acc[p, 3] if inside else _F(0.0)
                st[B_QT + i] = g_t[p] * t_final[p] if inside else _F(0.0)
            for k in range(k_last, s - 1, -1):
                g = gid[k]
                mx, my = gp[g, G_MX], gp[g, G_MY]
                bx0, bx1, by0, by1 = _box(mx, my, gp[g, G_EX], gp[g, G_EY], x0, x1, y0, y1)
                if by1 <= by0:
                    continue
                a, b, c, o = gp[g, G_A], gp[g, G_B], gp[g, G_C], gp[g, G_O]
                p_min = gp[g, G_PMIN]
                for h in range((bx0 - x0) // HALF, (bx1 - x0 + HALF - 1) // HALF):
                    ry0, ry1 = _rows(mx, my, a, b, c, p_min, max(bx0, x0 + h * HALF),
                                     min(bx1, x0 + (h + 1) * HALF), by0, by1)
                    lo, hi = _span(h, ry0, ry1, y0)
                    gr = _backward_span(st, lo, hi, _F(bx0), _F(bx1), mx, my, a, b, c, o, p_min, gp[g, G_F0],
                                        gp[g, G_F0 + 1], gp[g, G_F0 + 2], gp[g, G_F0 + 3], _F(k - s))
                    for m in range(10):
                        pair_grad[k, m] += gr[m]


@njit(cache=True)
def _reduce_sum(gid, pair_vals, out):  # pragma: no cover - compiled
    """out[gid[k]] += pair_vals[k] in list order: one fixed summation order, whatever the threads."""
    for k in range(gid.shape[0]):
        g = gid[k]
        for j in range(pair_vals.shape[1]):
            out[g, j] += pair_vals[k, j]


@njit(cache=True)
def _reduce_stats(gid, pair_cov, pair_hits, pair_maxw, coverage, hit_count, max_weight):  # pragma: no cover
    for k in range(gid.shape[0]):
        g = gid[k]
        coverage[g] += pair_cov[k]
        hit_count[g] += pair_hits[k]
        if pair_maxw[k] > max_weight[g]:
            max_weight[g] = pair_maxw[k]


@njit(cache=True, inline="always")
def _rotmat(qw, qx, qy, qz):  # pragma: no cover - compiled
    return (_F(1.0) - _F(2.0) * (qy * qy + qz * qz), _F(2.0) * (qx * qy - qw * qz), _F(2.0) * (qx * qz + qw * qy),
            _F(2.0) * (qx * qy + qw * qz), _F(1.0) - _F(2.0) * (qx * qx + qz * qz), _F(2.0) * (qy * qz - qw * qx),
            _F(2.0) * (qx * qz - qw * qy), _F(2.0) * (qy * qz + qw * qx), _F(1.0) - _F(2.0) * (qx * qx + qy * qy))


@njit(cache=True, inline="always")
def _to_camera(means, i, rc, tc):  # pragma: no cover - compiled
    """Camera-frame position of Gaussian i (the backward recomputes it rather than storing it)."""
    mw0, mw1, mw2 = means[i, 0], means[i, 1], means[i, 2]
    return (rc[0, 0] * mw0 + rc[0, 1] * mw1 + rc[0, 2] * mw2 + tc[0],
            rc[1, 0] * mw0 + rc[1, 1] * mw1 + rc[1, 2] * mw2 + tc[1],
            rc[2, 0] * mw0 + rc[2, 1] * mw1 + rc[2, 2] * mw2 + tc[2])


@njit(cache=True, inline="always")
def _jacobian_limits(fx, fy, width, height):  # pragma: no cover - compiled
    """3DGS clamps the Jacobian's lever arm at 1.3x the half field of view (as ``raster.project``)."""
    return _F(1.3) * (_F(0.5) * _F(width) / fx), _F(1.3) * (_F(0.5) * _F(height) / fy)


@njit(parallel=True, cache=True)
def _project_fwd(means, log_scales, quats, rc, tc, cam, width, height, near_m, tiles_x, tiles_y,
                 m2, cov, z_out, rect, radius_px, tile_id):  # pragma: no cover - compiled
    """EWA projection as ``raster.project`` computes it, plus culling and the tile rectangle.

    cam: (fx, fy, cx, cy); cov [N, 3] = (a, b, c) of the screen covariance incl. the 0.3 px low-pass,
    zero for a Gaussian culled by its centre (behind the near plane or outside the widened frustum).
    """
    fx, fy, cx, cy = cam[0], cam[1], cam[2], cam[3]
    lim_x, lim_y = _jacobian_limits(fx, fy, width, height)
    for i in prange(means.shape[0]):
        px, py, pz = _to_camera(means, i, rc, tc)
        zs = pz if abs(pz) >= _F(1e-6) else _F(1e-6)
        mx = fx * px / zs + cx
        my = fy * py / zs + cy
        m2[i, 0], m2[i, 1] = mx, my
        z_out[i] = pz
        if not (pz > near_m and abs(mx - cx) < _F(1.3) * _F(0.5) * _F(width)
                and abs(my - cy) < _F(1.3) * _F(0.5) * _F(height)):
            # culled by its centre (behind the near plane or outside the widened frustum): on a long
            # drive most of the map, whose screen covariance nothing reads, so it is left at zero
            cov[i, 0] = cov[i, 1] = cov[i, 2] = _F(0.0)
            rect[i, 0] = rect[i, 1] = rect[i, 2] = rect[i, 3] = 0
            radius_px[i] = 0
            tile_id[i] = -1
            continue
        tx = min(max(px / zs, -lim_x), lim_x) * zs
        ty = min(max(py / zs, -lim_y), lim_y) * zs
        j00, j02 = fx / zs, -fx * tx / (zs * zs)
        j11, j12 = fy / zs, -fy * ty / (zs * zs)
        # T = J Rc  [2, 3]
        t00 = j00 * rc[0, 0] + j02 * rc[2, 0]
        t01 = j00 * rc[0, 1] + j02 * rc[2, 1]
        t02 = j00 * rc[0, 2] + j02 * rc[2, 2]
        t10 = j11 * rc[1, 0] + j12 * rc[2, 0]
        t11 = j11 * rc[1, 1] + j12 * rc[2, 1]
        t12 = j11 * rc[1, 2] + j12 * rc[2, 2]
        qw, qx, qy, qz = quats[i, 0], quats[i, 1], quats[i, 2], quats[i, 3]
        qn = max(np.sqrt(qw * qw + qx * qx + qy * qy + qz * qz), _F(1e-12))
        r00, r01, r02, r10, r11, r12, r20, r21, r22 = _rotmat(qw / qn, qx / qn, qy / qn, qz / qn)
        s0, s1, s2 = np.exp(log_scales[i, 0]), np.exp(log_scales[i, 1]), np.exp(log_scales[i, 2])
        # U = T M with M = R diag(s): cov2d = U U^T
        u00 = (t00 * r00 + t01 * r10 + t02 * r20) * s0
        u01 = (t00 * r01 + t01 * r11 + t02 * r21) * s1
        u02 = (t00 * r02 + t01 * r12 + t02 * r22) * s2
        u10 = (t10 * r00 + t11 * r10 + t12 * r20) * s0
        u11 = (t10 * r01 + t11 * r11 + t12 * r21) * s1
        u12 = (t10 * r02 + t11 * r12 + t12 * r22) * s2
        a = u00 * u00 + u01 * u01 + u02 * u02 + _F(0.3)
        b = u00 * u10 + u01 * u11 + u02 * u12
        c = u10 * u10 + u11 * u11 + u12 * u12 + _F(0.3)
        cov[i, 0], cov[i, 1], cov[i, 2] = a, b, c
        det = a * c - b * b
        mid = _F(0.5) * (a + c)
        lam = mid + np.sqrt(max(mid * mid - det, _F(0.1)))
        radius = np.ceil(_F(3.0) * np.sqrt(lam))
        front = det > _F(0.0)  # and the centre tests above
        x0 = int(min(max(np.floor((mx - radius) / _F(TILE)), _F(0.0)), _F(tiles_x)))
        x1 = int(min(max(np.floor((mx + radius) / _F(TILE)) + _F(1.0), _F(0.0)), _F(tiles_x)))
        y0 = int(min(max(np.floor((my - radius) / _F(TILE)), _F(0.0)), _F(tiles_y)))
        y1 = int(min(max(np.floor((my + radius) / _F(TILE)) + _F(1.0), _F(0.0)), _F(tiles_y)))
        visible = front and x1 > x0 and y1 > y0
        rect[i, 0], rect[i, 1], rect[i, 2], rect[i, 3] = x0, (x1 if visible else x0), y0, y1
        radius_px[i] = int(radius) if visible else 0
        if front and mx >= _F(0.0) and mx < _F(width) and my >= _F(0.0) and my < _F(height):
            tile_id[i] = int(min(my, _F(height - 1)) // _F(TILE)) * tiles_x + int(min(mx, _F(width - 1)) // _F(TILE))
        else:
            tile_id[i] = -1


@njit(parallel=True, cache=True)
def _project_bwd(means, log_scales, quats, rc, tc, cam, width, height, g_m2, g_cov, g_z, gaussians,
                 g_means, g_log_scales, g_quats, g_pose):  # pragma: no cover - compiled
    """The chain rule of ``_project_fwd`` per Gaussian; g_pose [N, 12] holds each Gaussian's share of
    d/d(Rc row-major, tc), reduced afterwards in a fixed order. Without ``gaussians`` (tracking: only
    the pose is optimised) the gradients of means, log-scales and quaternions are left unwritten.

    The small per-Gaussian matrices are allocated once per block of Gaussians: an allocation per
    Gaussian cost more than its arithmetic."""
    fx, fy = cam[0], cam[1]
    lim_x, lim_y = _jacobian_limits(fx, fy, width, height)
    n = means.shape[0]
    for blk in prange((n + PROJECT_BLOCK - 1) // PROJECT_BLOCK):
        t = np.empty((2, 3), np.float32)
        rg = np.empty((3, 3), np.float32)
        sc = np.empty(3, np.float32)
        mm = np.empty((3, 3), np.float32)  # M = Rg diag(s)
        sig = np.empty((3, 3), np.float32)  # Sigma = M M^T
        ts = np.empty((2, 3), np.float32)  # T Sigma
        gt = np.empty((2, 3), np.float32)
        gsig = np.empty((3, 3), np.float32)
        grg = np.empty((3, 3), np.float32)
        for i in range(blk * PROJECT_BLOCK, min(n, (blk + 1) * PROJECT_BLOCK)):
            if (g_m2[i, 0] == 0 and g_m2[i, 1] == 0 and g_cov[i, 0] == 0 and g_cov[i, 1] == 0
                    and g_cov[i, 2] == 0 and g_z[i] == 0):
                # nothing flows back (out of view: on a long drive most of the map): every product below is 0
                for k in range(12):
                    g_pose[i, k] = _F(0.0)
                if gaussians:
                    for k in range(3):
                        g_means[i, k] = _F(0.0)
                        g_log_scales[i, k] = _F(0.0)
                    for k in range(4):
                        g_quats[i, k] = _F(0.0)
                continue
            mw0, mw1, mw2 = means[i, 0], means[i, 1], means[i, 2]
            px, py, pz = _to_camera(means, i, rc, tc)
            z_ok = abs(pz) >= _F(1e-6)
            zs = pz if z_ok else _F(1e-6)
            ux, uy = px / zs, py / zs
            clamp_x = ux < -lim_x or ux > lim_x
            clamp_y = uy < -lim_y or uy > lim_y
            tx = min(max(ux, -lim_x), lim_x) * zs
            ty = min(max(uy, -lim_y), lim_y) * zs
            zs2 = zs * zs
            j00, j02 = fx / zs, -fx * tx / zs2
            j11, j12 = fy / zs, -fy * ty / zs2
            for k in range(3):
                t[0, k] = j00 * rc[0, k] + j02 * rc[2, k]
                t[1, k] = j11 * rc[1, k] + j12 * rc[2, k]
            qw, qx, qy, qz = quats[i, 0], quats[i, 1], quats[i, 2], quats[i, 3]
            qn = max(np.sqrt(qw * qw + qx * qx + qy * qy + qz * qz), _F(1e-12))
            nw, nx, ny, nz = qw / qn, qx / qn, qy / qn, qz / qn
            rg[0, 0], rg[0, 1], rg[0, 2], rg[1, 0], rg[1, 1], rg[1, 2], rg[2, 0], rg[2, 1], rg[2, 2] = \
                _rotmat(nw, nx, ny, nz)
            for k in range(3):
                sc[k] = np.exp(log_scales[i, k])
            for j in range(3):
                for k in range(3):
                    mm[j, k] = rg[j, k] * sc[k]
            for j in range(3):
                for k in range(3):
                    sig[j, k] = mm[j, 0] * mm[k, 0] + mm[j, 1] * mm[k, 1] + mm[j, 2] * mm[k, 2]
            # symmetric upstream gradient of the 2x2 screen covariance (b is read once, off the diagonal)
            gs00, gs01, gs11 = g_cov[i, 0], _F(0.5) * g_cov[i, 1], g_cov[i, 2]
            # dL/dT = 2 Gs T Sigma ; dL/dSigma = T^T Gs T ; dL/dM = 2 dL/dSigma M
            for r in range(2):
                for k in range(3):
                    ts[r, k] = t[r, 0] * sig[0, k] + t[r, 1] * sig[1, k] + t[r, 2] * sig[2, k]
            for k in range(3):
                gt[0, k] = _F(2.0) * (gs00 * ts[0, k] + gs01 * ts[1, k])
                gt[1, k] = _F(2.0) * (gs01 * ts[0, k] + gs11 * ts[1, k])
            if gaussians:
                for j in range(3):
                    for k in range(3):
                        gsig[j, k] = (t[0, j] * (gs00 * t[0, k] + gs01 * t[1, k])
                                      + t[1, j] * (gs01 * t[0, k] + gs11 * t[1, k]))
                for k in range(3):
                    gsk = _F(0.0)
                    for j in range(3):
                        gm = _F(2.0) * (gsig[j, 0] * mm[0, k] + gsig[j, 1] * mm[1, k] + gsig[j, 2] * mm[2, k])
                        grg[j, k] = gm * sc[k]
                        gsk += gm * rg[j, k]
                    g_log_scales[i, k] = gsk * sc[k]
                d = grg
                gw = _F(2.0) * (-nz * d[0, 1] + ny * d[0, 2] + nz * d[1, 0] - nx * d[1, 2] - ny * d[2, 0]
                                + nx * d[2, 1])
                gx = _F(2.0) * (ny * d[0, 1] + nz * d[0, 2] + ny * d[1, 0] - _F(2.0) * nx * d[1, 1] - nw * d[1, 2]
                                + nz * d[2, 0] + nw * d[2, 1] - _F(2.0) * nx * d[2, 2])
                gy = _F(2.0) * (-_F(2.0) * ny * d[0, 0] + nx * d[0, 1] + nw * d[0, 2] + nx * d[1, 0] + nz * d[1, 2]
                                - nw * d[2, 0] + nz * d[2, 1] - _F(2.0) * ny * d[2, 2])
                gz = _F(2.0) * (-_F(2.0) * nz * d[0, 0] - nw * d[0, 1] + nx * d[0, 2] + nw * d[1, 0]
                                - _F(2.0) * nz * d[1, 1] + ny * d[1, 2] + nx * d[2, 0] + ny * d[2, 1])
                dot = nw * gw + nx * gx + ny * gy + nz * gz
                g_quats[i, 0] = (gw - nw * dot) / qn
                g_quats[i, 1] = (gx - nx * dot) / qn
                g_quats[i, 2] = (gy - ny * dot) / qn
                g_quats[i, 3] = (gz - nz * dot) / qn
            # T = J Rc: dL/dJ = dL/dT Rc^T, dL/dRc += J^T dL/dT
            gj00 = gt[0, 0] * rc[0, 0] + gt[0, 1] * rc[0, 1] + gt[0, 2] * rc[0, 2]
            gj02 = gt[0, 0] * rc[2, 0] + gt[0, 1] * rc[2, 1] + gt[0, 2] * rc[2, 2]
            gj11 = gt[1, 0] * rc[1, 0] + gt[1, 1] * rc[1, 1] + gt[1, 2] * rc[1, 2]
            gj12 = gt[1, 0] * rc[2, 0] + gt[1, 1] * rc[2, 1] + gt[1, 2] * rc[2, 2]
            for k in range(3):
                g_pose[i, k] = j00 * gt[0, k]
                g_pose[i, 3 + k] = j11 * gt[1, k]
                g_pose[i, 6 + k] = j02 * gt[0, k] + j12 * gt[1, k]
            # camera-space point: from J (through zs, tx, ty), the projected mean and z
            gmx, gmy = g_m2[i, 0], g_m2[i, 1]
            g_tx = gj02 * (-fx / zs2)
            g_ty = gj12 * (-fy / zs2)
            g_zs = (gj00 * (-fx / zs2) + gj02 * (_F(2.0) * fx * tx / (zs2 * zs)) + gj11 * (-fy / zs2)
                    + gj12 * (_F(2.0) * fy * ty / (zs2 * zs)) - (gmx * fx * px + gmy * fy * py) / zs2)
            gpx = gmx * fx / zs
            gpy = gmy * fy / zs
            if clamp_x:  # tx = +-lim_x zs
                g_zs += g_tx * (lim_x if ux > _F(0.0) else -lim_x)
            else:
                gpx += g_tx
            if clamp_y:
                g_zs += g_ty * (lim_y if uy > _F(0.0) else -lim_y)
            else:
                gpy += g_ty
            gpz = g_z[i] + (g_zs if z_ok else _F(0.0))
            if gaussians:
                for k in range(3):
                    g_means[i, k] = rc[0, k] * gpx + rc[1, k] * gpy + rc[2, k] * gpz
            g_pose[i, 0] += gpx * mw0
            g_pose[i, 1] += gpx * mw1
            g_pose[i, 2] += gpx * mw2
            g_pose[i, 3] += gpy * mw0
            g_pose[i, 4] += gpy * mw1
            g_pose[i, 5] += gpy * mw2
            g_pose[i, 6] += gpz * mw0
            g_pose[i, 7] += gpz * mw1
            g_pose[i, 8] += gpz * mw2
            g_pose[i, 9] = gpx
            g_pose[i, 10] = gpy
            g_pose[i, 11] = gpz


@njit(cache=True)
def _sum_rows(vals, out):  # pragma: no cover - compiled
    """out[j] = sum_i vals[i, j] in row order (a fixed order, unlike a threaded reduction)."""
    for i in range(vals.shape[0]):
        for j in range(vals.shape[1]):
            out[j] += vals[i, j]


class _Project(torch.autograd.Function):
    """World Gaussians -> screen (means2d [N, 2], cov [N, 3], z [N]) plus culling and tile rectangles."""

    @staticmethod
    def forward(ctx, means, log_scales, quats, w2c, cam, width, height, near_m, tiles_x, tiles_y):  # type: ignore[override]
        # a Gaussian's projection costs a fraction of a pair's compositing, so it goes parallel later
        _threads(int(means.shape[0]) // 2)
        mw, ls, q = (t.detach().float().contiguous() for t in (means, log_scales, quats))
        rc = w2c.detach()[:3, :3].float().contiguous()
        tc = w2c.detach()[:3, 3].float().contiguous()
        n = mw.shape[0]
        m2 = torch.empty(n, 2)
        cov = torch.empty(n, 3)
        z = torch.empty(n)
        rect = torch.empty(n, 4, dtype=torch.int32)
        radius_px = torch.empty(n, dtype=torch.int64)
        tile_id = torch.empty(n, dtype=torch.int64)
        _project_fwd(mw.numpy(), ls.numpy(), q.numpy(), rc.numpy(), tc.numpy(), cam.numpy(), width, height,
                     np.float32(near_m), tiles_x, tiles_y, m2.numpy(), cov.numpy(), z.numpy(), rect.numpy(),
                     radius_px.numpy(), tile_id.numpy())
        ctx.save_for_backward(mw, ls, q, rc, tc, cam)
        ctx.dims = (width, height)
        ctx.mark_non_differentiable(rect, radius_px, tile_id)
        return m2, cov, z, rect, radius_px, tile_id

    @staticmethod
    def backward(ctx, g_m2, g_cov, g_z, *_):  # type: ignore[override]
        mw, ls, q, rc, tc, cam = ctx.saved_tensors
        _threads(int(mw.shape[0]) // 2)
        width, height = ctx.dims
        n = mw.shape[0]
        g_m2 = torch.zeros(n, 2) if g_m2 is None else g_m2.float().contiguous()
        g_cov = torch.zeros(n, 3) if g_cov is None else g_cov.float().contiguous()
        g_z = torch.zeros(n) if g_z is None else g_z.float().contiguous()
        g_means, g_ls, g_q = torch.empty(n, 3), torch.empty(n, 3), torch.empty(n, 4)
        g_pose_rows = torch.empty(n, 12)  # [N, 12]
        gaussians = any(ctx.needs_input_grad[:3])
        _project_bwd(mw.numpy(), ls.numpy(), q.numpy(), rc.numpy(), tc.numpy(), cam.numpy(), width, height,
                     g_m2.numpy(), g_cov.numpy(), g_z.numpy(), gaussians, g_means.numpy(), g_ls.numpy(), g_q.numpy(),
                     g_pose_rows.numpy())
        g_pose = torch.zeros(12)
        _sum_rows(g_pose_rows.numpy(), g_pose.numpy())
        g_w2c = torch.zeros(4, 4)
        g_w2c[:3, :3] = g_pose[:9].reshape(3, 3)
        g_w2c[:3, 3] = g_pose[9:]
        if not gaussians:
            g_means = g_ls = g_q = None
        return g_means, g_ls, g_q, g_w2c, None, None, None, None, None, None


def project(
    means: torch.Tensor, log_scales: torch.Tensor, quats: torch.Tensor, w2c: torch.Tensor, K: torch.Tensor,
    width: int, height: int, near_m: float, tiles_x: int, tiles_y: int,
) -> tuple[torch.Tensor, ...]:
    """means2d [N, 2], cov [N, 3] (a, b, c), z [N] (differentiable in means, log-scales, quats and the
    pose w2c [4, 4]); rect [N, 4] int32, radius_px [N], tile_id [N] as ``raster._front`` defines them."""
    _load_from_cache()
    cam = torch.stack([K[0, 0], K[1, 1], K[0, 2], K[1, 2]]).detach().float().cpu()
    return _Project.apply(means, log_scales, quats, w2c, cam, width, height, near_m, tiles_x, tiles_y)


_COMPILING_ENV = "POCKETBENCH_COMPILING_KERNELS"
_cache_checked = False


def _load_from_cache() -> None:
    """Compile the kernels in a child process when numba's cache lacks them, so that this process
    loads them from the cache like every later one.

    Kernels compiled in the process that runs them gave other roundings than the same kernels loaded
    from numba's cache (the compositing forward, on identical inputs), so a run that compiled them,
    the first after an install or a change, did not repeat bit for bit; with every process on cached
    code it does. Where the cache cannot be written (or numba's internals differ), the kernels
    compile here as before."""
    global _cache_checked
    if _cache_checked or os.environ.get(_COMPILING_ENV):
        return
    _cache_checked = True
    try:
        kernels = (_project_fwd, _project_bwd, _sum_rows, _in_view, _depth_order, _bin_pairs, _pack, _schedule,
                   _forward, _backward, _reduce_sum, _reduce_stats)
        if all(k._cache._cache_file._load_index() for k in kernels):
            return
    except Exception:  # noqa: BLE001 - a numba without these internals: compile in this process
        return
    root = str(Path(__file__).resolve().parents[2])  # the folder holding the bench package
    env = dict(os.environ, **{_COMPILING_ENV: "1"})
    env["PYTHONPATH"] = os.pathsep.join(p for p in (root, env.get("PYTHONPATH")) if p)
    subprocess.run([sys.executable, "-c", "from bench.slam.raster_fused import compile_kernels; compile_kernels()"],
                   env=env, capture_output=True, check=False)


def compile_kernels() -> None:
    """Call every kernel once on a small view (forward with and without statistics; backward to the
    Gaussians and to the pose), with the argument types of a real run, so that numba compiles and
    caches each of them. The same calls as ``raster._render_fused`` makes, without importing it."""
    n, size, tiles = 64, 64, 4
    g = torch.Generator().manual_seed(0)
    means = torch.cat([torch.rand(n, 2, generator=g) - 0.5, torch.full((n, 1), 3.0)], 1)
    params = [means, torch.full((n, 3), -3.0), torch.tensor([1.0, 0, 0, 0]).repeat(n, 1), torch.full((n,), 0.8),
              torch.rand(n, 3, generator=g)]
    K = torch.tensor([[40.0, 0, 32], [0, 40.0, 32], [0, 0, 1]])
    for stats, gaussians in ((False, True), (True, False)):
        m, ls, q, op, col = (p.clone().requires_grad_(gaussians) for p in params)
        w2c = torch.eye(4, requires_grad=True)
        m2, cov, z, rect, _, _ = project(m, ls, q, w2c, K, size, size, 0.2, tiles, tiles)
        vis = in_view(rect)
        tile_start, gid = bin_pairs(rect.index_select(0, vis), z.index_select(0, vis), tiles * tiles, tiles)
        feat = torch.cat([col.index_select(0, vis), z.index_select(0, vis)[:, None]], 1)  # [V, 4]
        inv = conic(*cov.index_select(0, vis).unbind(-1))  # [V, 3]
        acc, t_final, *_ = composite(m2.index_select(0, vis), inv, op.index_select(0, vis), feat, gid, tile_start,
                                     size, size, tiles, stats)
        (acc.sum() + t_final.sum()).backward()


# below this many work items a kernel runs on one thread: a parallel region ends at a barrier, and
# on a loaded machine (a sweep running jobs side by side) waiting there for a descheduled worker
# costs more than the work itself
PARALLEL_MIN_ITEMS = 32_768


def _threads(n_items: int) -> None:
    """Run the next kernel on as many threads as torch uses (``threads=``), or one for small work."""
    n = torch.get_num_threads() if n_items >= PARALLEL_MIN_ITEMS else 1
    numba.set_num_threads(max(1, min(n, numba.config.NUMBA_NUM_THREADS)))


def bin_pairs(
    rect: torch.Tensor, depths: torch.Tensor, n_tiles: int, tiles_x: int
) -> tuple[torch.Tensor, torch.Tensor]:
    """(tile_start [n_tiles + 1] int64, gid [P] int32): pairs sorted by tile, then by depth.

    rect: [N, 4] int32 (x0, x1, y0, y1) tile rectangle of each Gaussian, empty when culled.
    """
    z = depths.detach().contiguous()
    if z.dtype == torch.float32:
        order = _depth_order(z.numpy(), rect.numpy())  # [M] the Gaussians that touch a tile, by depth
    else:
        order = torch.argsort(z, stable=True).to(torch.int32).numpy()  # [N]
    tile_start, gid = _bin_pairs(order, rect.numpy(), n_tiles, tiles_x)
    return torch.from_numpy(tile_start), torch.from_numpy(gid)


@njit(cache=True)
def _in_view(rect, out):  # pragma: no cover - compiled
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
    return out[: _in_view(rect.numpy(), out.numpy())]


class _Composite(torch.autograd.Function):
    """Differentiable compositing of projected Gaussians; per-pixel outputs acc [H*W, 4] and T [H*W]."""

    @staticmethod
    def forward(ctx, means2d, conic, opac, feat, gid, tile_start, width, height, tiles_x, stats):  # type: ignore[override]
        _threads(int(gid.shape[0]))
        m2 = means2d.detach().contiguous()
        co = conic.detach().contiguous()
        op = opac.detach().contiguous()
        ft = feat.detach().contiguous()
        hw = width * height
        acc = torch.empty(hw, N_FEAT, dtype=torch.float32)  # [H*W, 4]
        t_final = torch.empty(hw, dtype=torch.float32)  # [H*W]
        last = torch.empty(hw, dtype=torch.int64)  # [H*W] pair index of the last contributor, -1 none
        n_pairs = int(gid.shape[0]) if stats else 0
        pair_cov = torch.empty(n_pairs, dtype=torch.float32)
        pair_hits = torch.empty(n_pairs, dtype=torch.int32)
        pair_maxw = torch.empty(n_pairs, dtype=torch.float32)
        gp = torch.empty(m2.shape[0], G_SIZE, dtype=torch.float32)  # [N, 16]
        _pack(m2.numpy(), co.numpy(), op.numpy(), ft.numpy(), gp.numpy())
        order, bounds = _schedule(tile_start.numpy(), numba.get_num_threads())
        _forward(gid.numpy(), tile_start.numpy(), gp.numpy(), width, height, tiles_x, stats, order, bounds,
                 acc.numpy(), t_final.numpy(), last.numpy(), pair_cov.numpy(), pair_hits.numpy(), pair_maxw.numpy())
        n = m2.shape[0]
        coverage = torch.zeros(n if stats else 0, dtype=torch.float32)
        hit_count = torch.zeros(n if stats else 0, dtype=torch.int64)
        max_weight = torch.zeros(n if stats else 0, dtype=torch.float32)
        if stats:
            _reduce_stats(gid.numpy(), pair_cov.numpy(), pair_hits.numpy(), pair_maxw.numpy(),
                          coverage.numpy(), hit_count.numpy(), max_weight.numpy())
        del pair_cov, pair_hits, pair_maxw
        ctx.save_for_backward(gp, gid, tile_start, t_final, last)
        ctx.dims = (width, height, tiles_x)
        ctx.mark_non_differentiable(coverage, hit_count, max_weight)
        return acc, t_final, coverage, hit_count, max_weight

    @staticmethod
    def backward(ctx, g_acc, g_t, *_):  # type: ignore[override]
        gp, gid, tile_start, t_final, last = ctx.saved_tensors
        _threads(int(gid.shape[0]))
        width, height, tiles_x = ctx.dims
        hw = width * height
        g_acc = torch.zeros(hw, N_FEAT) if g_acc is None else g_acc.contiguous().to(torch.float32)
        g_t = torch.zeros(hw) if g_t is None else g_t.contiguous().to(torch.float32)
        pair_grad = torch.empty(gid.shape[0], 10, dtype=torch.float32)  # [P, 10]
        order, bounds = _schedule(tile_start.numpy(), numba.get_num_threads())
        _backward(gid.numpy(), tile_start.numpy(), gp.numpy(), width, height, tiles_x, order, bounds,
                  t_final.numpy(), last.numpy(), g_acc.numpy(), g_t.numpy(), pair_grad.numpy())
        grad = torch.zeros(gp.shape[0], 10, dtype=torch.float32)  # [N, 10]
        _reduce_sum(gid.numpy(), pair_grad.numpy(), grad.numpy())
        del pair_grad
        return grad[:, 0:2], grad[:, 2:5], grad[:, 5], grad[:, 6:10], None, None, None, None, None, None


def composite(
    means2d: torch.Tensor,
    conic: torch.Tensor,
    opac: torch.Tensor,
    feat: torch.Tensor,
    gid: torch.Tensor,
    tile_start: torch.Tensor,
    width: int,
    height: int,
    tiles_x: int,
    stats: bool,
) -> tuple[torch.Tensor, ...]:
    """acc [H*W, 4], T_final [H*W], and (stats) coverage, hit_count, max_weight [N]; differentiable in
    means2d [N, 2], conic [N, 3] (a, b, c of the inverse covariance), opac [N] and feat [N, 4]."""
    return _Composite.apply(means2d, conic, opac, feat, gid, tile_start, width, height, tiles_x, stats)
