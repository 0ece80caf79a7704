"""Compositing forward and backward: the tile kernels, their state layout, and the reductions over pairs."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from llvmlite import ir as llvm_ir
from numba import njit, prange, types
from numba.extending import intrinsic

from bench.slam.raster_fused.constants import ALPHA_MAX, ALPHA_MIN, COVERAGE_POWER_MIN, F32, N_FEAT, T_MIN, TILE

LN255 = F32(math.log(255.0))

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
# - a span is whole rows of pixels. A tile's pixels are stored as two 8-px column halves, each
#   row-major, so the rows of a Gaussian's box inside one half are one contiguous span whose length
#   is a multiple of 8. The backward widens its spans to whole pairs of rows from an even row (16
#   lanes, 64 bytes) and writes the length as pairs << 4: LLVM then sees a multiple of 16 lanes and
#   emits no remainder loop (a span of an odd number of rows ran its last 8 lanes through a 4-lane
#   epilogue, then a scalar loop), and every vector load and store is aligned.
_U = np.uint64
HALF = TILE // 2
NPIX = TILE * TILE
_UH = _U(HALF)
_UHALF_PIX = _U(NPIX // 2)
_UPAIR = _U(2 * HALF)  # two 8-px rows of a half: 16 lanes
_UPAIR_SHIFT = _U(4)  # log2(16): n << _UPAIR_SHIFT is n pairs of rows
# forward state: pixel coordinates, transmittance, accumulated features, last contributor (an index
# into the tile's list, -1 none), saturated flag, and the visiting Gaussian's blending weight
S_X, S_Y, S_T, S_A0, S_A1, S_A2, S_A3, S_LAST, S_DONE, S_W = (_U(j * NPIX) for j in range(10))
S_SIZE = 10 * NPIX
# backward state (the forward's layout): pixel coordinates, transmittance in front of the visited
# Gaussian, last contributor, q = dL/d acc (4), and r = q . (the features accumulated behind
# the visited Gaussian) + dL/dT_final * T_final, the one number of what lies behind that dL/dalpha needs
B_X, B_Y, B_TC, B_LK, B_Q0, B_Q1, B_Q2, B_Q3, B_R = (_U(j * NPIX) for j in range(9))
B_SIZE = 9 * NPIX
# the forward counts a tile's saturated pixels (to stop early) once per this many list entries; an
# entry after saturation changes nothing, so the period changes no result
SATURATION_CHECK = 8
# the compositing kernels walk a tile's list and prefetch the Gaussian this many entries ahead (a Gaussian's
# row of gp is a cache line read at random)
PREFETCH_AHEAD = 8
# one row per Gaussian, one 64-byte cache line: what the compositing reads of a Gaussian
G_MX, G_MY, G_A, G_B, G_C, G_O, G_F0, G_EX, G_EY, G_PMIN = 0, 1, 2, 3, 4, 5, 6, 10, 11, 12
G_SIZE = 16
ALIGN_F32 = 16  # float32s in 64 bytes: a cache line, and an AVX-512 register
KERNEL_OPTIONS: dict[str, Any] = dict(
    cache=True, fastmath=True, error_model="numpy"
)  # numpy's model: no zero-division branch


@intrinsic
def _bits_to_f32(typingctx, bits):  # pragma: no cover - compiled
    """The float32 whose bit pattern is the int32 ``bits`` (a bitcast, which LLVM vectorises)."""
    sig = types.float32(types.int32)

    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], llvm_ir.FloatType())

    return sig, codegen


@intrinsic
def _prefetch(typingctx, address):  # pragma: no cover - compiled
    """A hint that the cache line at the integer ``address`` is read soon (``llvm.prefetch``); no value,
    and no effect on any result."""
    sig = types.void(types.uintp)

    def codegen(context, builder, signature, args):
        i8p = llvm_ir.IntType(8).as_pointer()
        i32 = llvm_ir.IntType(32)
        fnty = llvm_ir.FunctionType(llvm_ir.VoidType(), [i8p, i32, i32, i32])
        fn = builder.module.globals.get("llvm.prefetch.p0") or llvm_ir.Function(
            builder.module, fnty, "llvm.prefetch.p0"
        )
        builder.call(fn, [builder.inttoptr(args[0], i8p), i32(0), i32(3), i32(1)])  # read, keep, data
        return context.get_dummy_value()

    return sig, codegen


@njit(inline="always", **KERNEL_OPTIONS)
def exp_f32(x):  # pragma: no cover - compiled
    """float32 exp(x) for x <= 0 as 2^n p(f) (Cephes' expf polynomial), relative error ~1e-7.

    np.exp compiles to a scalar libm call (pip's llvmlite has no vector maths library), which keeps
    every loop around it scalar; this is plain arithmetic, with 2^n put into the exponent bits."""
    x = min(max(x, F32(-87.0)), F32(0.0))
    n = np.floor(x * F32(1.44269504) + F32(0.5))
    f = x - n * F32(0.693359375) + n * F32(2.12194440e-4)
    p = F32(1.9875691500e-4)
    p = p * f + F32(1.3981999507e-3)
    p = p * f + F32(8.3334519073e-3)
    p = p * f + F32(4.1665795894e-2)
    p = p * f + F32(1.6666665459e-1)
    p = p * f + F32(5.0000001201e-1)
    p = p * f * f + f + F32(1.0)
    # an @intrinsic is called without its typingctx, which numba supplies; its stub takes it as an argument
    return p * _bits_to_f32(np.int32(n + F32(127.0)) << np.int32(23))  # type: ignore[call-arg]


@njit(parallel=True, **KERNEL_OPTIONS)
def pack(m2, conic, opac, feat, gp):  # pragma: no cover - compiled
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
        ex = ey = F32(-1.0)  # an empty box
        if o >= ALPHA_MIN and det > F32(0.0):
            r2 = F32(2.0) * (LN255 + np.log(o))  # d^T S^-1 d <= r2  <=>  o exp(power) >= 1/255
            ex = np.sqrt(r2 * c / det) + F32(1e-3)  # axis extents (S_xx = c / det, S_yy = a / det) + a margin
            ey = np.sqrt(r2 * a / det) + F32(1e-3)
        gp[g, G_EX], gp[g, G_EY] = ex, ey
        # below this exponent o exp(power) < 1/255 (with a margin, so the exact test decides at the edge)
        gp[g, G_PMIN] = -LN255 - np.log(o) - F32(1e-3) if o > F32(0.0) else F32(np.inf)
        for j in range(G_PMIN + 1, G_SIZE):
            gp[g, j] = F32(0.0)


@njit(inline="always", **KERNEL_OPTIONS)
def _aligned_state(size):  # pragma: no cover - compiled
    """A tile-state buffer that starts on a 64-byte boundary.

    LLVM's vectorised sums peel scalar iterations until their loads are aligned, so with a buffer at
    an arbitrary address the order of the additions, and their rounding, followed the heap's state:
    a process that had just compiled the kernels got other numbers than one that loaded them from
    numba's cache."""
    raw = np.empty(size + ALIGN_F32, np.float32)
    skip = (ALIGN_F32 - (raw.ctypes.data // 4) % ALIGN_F32) % ALIGN_F32
    return raw[skip : skip + size]


@njit(inline="always", **KERNEL_OPTIONS)
def pixel_box(mx, my, ex, ey, x0, x1, y0, y1):  # pragma: no cover - compiled
    """Pixels [bx0, bx1) x [by0, by1) of the tile within (ex, ey) of (mx, my) (empty if none, or ex < 0)."""
    if ex < F32(0.0):
        return 0, 0, 0, 0
    bx0 = max(x0, int(np.ceil(mx - ex)))
    bx1 = min(x1, int(np.floor(mx + ex)) + 1)
    by0 = max(y0, int(np.ceil(my - ey)))
    by1 = min(y1, int(np.floor(my + ey)) + 1)
    if bx0 >= bx1 or by0 >= by1:
        return 0, 0, 0, 0
    return bx0, bx1, by0, by1


@njit(inline="always", **KERNEL_OPTIONS)
def _rows(mx, my, a, b, c, p_min, cx0, cx1, by0, by1, y0):  # pragma: no cover - compiled
    """Rows [lo, hi) of [by0, by1) where the 1/255 ellipse meets columns [cx0, cx1): the tile's 16 rows
    tested at once (float64 vector code, no branch).

    Row y meets the ellipse a dx^2 + 2 b dx dy + c dy^2 <= q2 within dx in [dx0, dx1] if the
    quadratic's least value there, at its minimiser slope dy clamped, is within the threshold (it is
    convex in dx). The threshold and the columns are widened, so a row dropped here is one where
    every pixel fails the exact test (power < p_min) whatever float32's rounding; a row kept beyond
    those adds exact zeros."""
    q2 = -2.0 * float(p_min) * 1.001 + 0.01
    mxd, myd, ad, bd, cd = float(mx), float(my), float(a), float(b), float(c)
    slope = -bd / ad
    dx0, dx1 = float(cx0) - 0.01 - mxd, float(cx1) - 0.99 - mxd
    lo = by1
    hi = by0
    for y in range(y0, y0 + TILE):
        dy = float(y) - myd
        dx = min(max(slope * dy, dx0), dx1)
        meets = (ad * dx * dx + 2.0 * bd * dx * dy + cd * dy * dy <= q2) & (y >= by0) & (y < by1)
        lo = min(lo, y if meets else by1)
        hi = max(hi, y + 1 if meets else by0)
    return lo, max(lo, hi)


@njit(inline="always", **KERNEL_OPTIONS)
def _span(h, ry0, ry1, y0):  # pragma: no cover - compiled
    """Flat state indices [lo, hi) of rows [ry0, ry1) of column half h."""
    return _U(h) * _UHALF_PIX + _U(ry0 - y0) * _UH, _U(h) * _UHALF_PIX + _U(ry1 - y0) * _UH


@njit(inline="always", **KERNEL_OPTIONS)
def tile_pixels(t, tiles_x, width, height):  # pragma: no cover - compiled
    """Pixel range [x0, x1) x [y0, y1) of tile t, clipped at the image border."""
    x0 = (t % tiles_x) * TILE
    y0 = (t // tiles_x) * TILE
    return x0, min(x0 + TILE, width), y0, min(y0 + TILE, height)


@njit(cache=True)
def tile_schedule(tile_start, n_threads):  # pragma: no cover - compiled
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


@njit(inline="always", **KERNEL_OPTIONS)
def _forward_span(st, lo, hi, fx0, fx1, mx, my, a, b, c, o, p_min, f0, f1, f2, f3, kl):  # pragma: no cover
    """One Gaussian over state pixels [lo, hi), masked to its box columns [fx0, fx1): branch-free, so
    that it compiles to 8-lane vector code (a lane that takes no part adds zero and keeps its state)."""
    for i in range(lo, hi):
        xv = st[S_X + i]
        dx = xv - mx
        dy = st[S_Y + i] - my
        power = F32(-0.5) * (a * dx * dx + c * dy * dy) - b * dx * dy
        raw = o * exp_f32(power)
        alpha = min(raw, ALPHA_MAX)
        tp = st[S_T + i]
        test_t = tp * (F32(1.0) - alpha)
        ok = (xv >= fx0) & (xv < fx1) & (st[S_DONE + i] == F32(0.0)) & (power >= p_min) & (raw >= ALPHA_MIN)
        use = ok & (test_t >= T_MIN)
        w = alpha * tp if use else F32(0.0)
        st[S_A0 + i] += w * f0
        st[S_A1 + i] += w * f1
        st[S_A2 + i] += w * f2
        st[S_A3 + i] += w * f3
        st[S_T + i] = test_t if use else tp
        st[S_LAST + i] = kl if use else st[S_LAST + i]
        st[S_DONE + i] = F32(1.0) if ok & (test_t < T_MIN) else st[S_DONE + i]
        st[S_W + i] = w


@njit(inline="always", **KERNEL_OPTIONS)
def _coverage_span(st, lo, hi, fx0, fx1, mx, my, a, b, c, o):  # pragma: no cover - compiled
    """Sum of o exp(power) over state pixels [lo, hi) in columns [fx0, fx1): the pruning statistic's share."""
    cov = F32(0.0)
    for i in range(lo, hi):
        xv = st[S_X + i]
        dx = xv - mx
        dy = st[S_Y + i] - my
        power = F32(-0.5) * (a * dx * dx + c * dy * dy) - b * dx * dy
        cov += o * exp_f32(power) if (xv >= fx0) & (xv < fx1) else F32(0.0)
    return cov


@njit(parallel=True, **KERNEL_OPTIONS)
def composite_fwd(
    gid,
    tile_start,
    gp,
    width,
    height,
    tiles_x,
    stats,
    order,
    bounds,
    acc,
    t_final,
    last,
    pair_cov,
    pair_hits,
    pair_maxw,
):  # pragma: no cover - compiled
    """Front-to-back compositing per tile; fills acc [H*W, 4], t_final [H*W], last [H*W] (pair index).

    Each Gaussian of a tile's depth-sorted list updates the rows of its box, one 8-px vector per row
    and column half, so per pixel the order stays front to back. With ``stats`` it also fills, per
    pair, the coverage sum over the tile, the pixels contributed to and the largest blending weight.
    """
    gp_addr, gp_row = _U(gp.ctypes.data), _U(gp.strides[0])
    for th in prange(bounds.shape[0] - 1):
        st = _aligned_state(S_SIZE)
        for j in range(bounds[th], bounds[th + 1]):
            t = order[j]
            x0, x1, y0, y1 = tile_pixels(t, tiles_x, width, height)
            for i in range(NPIX):
                st[S_X + i] = F32(x0 + (i // (NPIX // 2)) * HALF + i % HALF)
                st[S_Y + i] = F32(y0 + (i // HALF) % TILE)
                st[S_T + i] = F32(1.0)
                st[S_A0 + i] = st[S_A1 + i] = st[S_A2 + i] = st[S_A3 + i] = F32(0.0)
                st[S_LAST + i] = F32(-1.0)
                st[S_DONE + i] = F32(0.0)
            s, e = tile_start[t], tile_start[t + 1]
            n_pix = (x1 - x0) * (y1 - y0)
            n_active = n_pix
            for k in range(s, e):
                if (k - s) % SATURATION_CHECK == 0 and n_active > 0:
                    n_done = F32(0.0)
                    for i in range(NPIX):
                        n_done += st[S_DONE + i]
                    n_active = n_pix - int(n_done)
                if n_active == 0 and not stats:
                    break
                g = gid[k]
                if k + PREFETCH_AHEAD < e:
                    _prefetch(gp_addr + _U(gid[k + PREFETCH_AHEAD]) * gp_row)  # type: ignore[call-arg]
                mx, my = gp[g, G_MX], gp[g, G_MY]
                a, b, c, o = gp[g, G_A], gp[g, G_B], gp[g, G_C], gp[g, G_O]
                hits = 0
                maxw = F32(0.0)
                bx0, bx1, by0, by1 = pixel_box(mx, my, gp[g, G_EX], gp[g, G_EY], x0, x1, y0, y1)
                if n_active > 0 and by1 > by0:
                    p_min = gp[g, G_PMIN]
                    for h in range((bx0 - x0) // HALF, (bx1 - x0 + HALF - 1) // HALF):
                        # the box's rows, untrimmed: a lane costs less here than ``_rows``' tests
                        lo, hi = _span(h, by0, by1, y0)
                        _forward_span(
                            st,
                            lo,
                            hi,
                            F32(bx0),
                            F32(bx1),
                            mx,
                            my,
                            a,
                            b,
                            c,
                            o,
                            p_min,
                            gp[g, G_F0],
                            gp[g, G_F0 + 1],
                            gp[g, G_F0 + 2],
                            gp[g, G_F0 + 3],
                            F32(k - s),
                        )
                        if stats:
                            for i in range(lo, hi):
                                w = st[S_W + i]
                                hits += 1 if w > F32(0.0) else 0
                                maxw = max(maxw, w)
                if stats:
                    pair_hits[k] = hits
                    pair_maxw[k] = maxw
                    cov = F32(0.0)
                    det = a * c - b * b
                    if o > F32(0.0) and det > F32(0.0):
                        r2 = F32(-2.0) * COVERAGE_POWER_MIN
                        cx0, cx1, cy0, cy1 = pixel_box(
                            mx, my, np.sqrt(r2 * c / det) + F32(1.0), np.sqrt(r2 * a / det) + F32(1.0), x0, x1, y0, y1
                        )
                        if cy1 > cy0:
                            for h in range((cx0 - x0) // HALF, (cx1 - x0 + HALF - 1) // HALF):
                                lo, hi = _span(h, cy0, cy1, y0)
                                cov += _coverage_span(st, lo, hi, F32(cx0), F32(cx1), mx, my, a, b, c, o)
                    pair_cov[k] = cov
            for y in range(y0, y1):
                for x in range(x0, x1):
                    p = y * width + x
                    ip = _U((x - x0) // HALF * (NPIX // 2) + (y - y0) * HALF + (x - x0) % HALF)
                    t_final[p] = st[S_T + ip]
                    k_loc = st[S_LAST + ip]
                    last[p] = s + int(k_loc) if k_loc >= F32(0.0) else -1
                    acc[p, 0] = st[S_A0 + ip]
                    acc[p, 1] = st[S_A1 + ip]
                    acc[p, 2] = st[S_A2 + ip]
                    acc[p, 3] = st[S_A3 + ip]


@njit(inline="always", **KERNEL_OPTIONS)
def _backward_span(st, lo, n, fx0, fx1, fy0, fy1, mx, my, a, b, c, o, p_min, f0, f1, f2, f3, kl):  # pragma: no cover
    """One Gaussian over backward state pixels [lo, lo + n), masked to its box [fx0, fx1) x [fy0, fy1),
    back to front: its 10 gradient sums there.

    One loop updates each pixel's state and adds its terms to the sums (the Gaussian's constants
    that find no register are read from the stack as operands). Per pixel,
    dL/dalpha = T_before q . f - (q . behind + dL/dT_final T_final) / (1 - alpha), with q = dL/d acc
    and behind the features accumulated behind the Gaussian: only the bracket's one number, r, is
    carried from Gaussian to Gaussian (r += w q . f), not the four features behind. The mean and
    conic gradients are linear in (a, b, c) and o, so only the moments u dx, u dy, u dx^2, u dy^2,
    u dx dy of u = dL/dalpha * exp(power) are summed."""
    s1 = s2 = sxx = syy = sxy = go = F32(0.0)
    gf0 = gf1 = gf2 = gf3 = F32(0.0)
    for j in range(n):
        i = lo + j
        xv = st[B_X + i]
        dx = xv - mx
        yv = st[B_Y + i]
        dy = yv - my
        power = F32(-0.5) * (a * dx * dx + c * dy * dy) - b * dx * dy
        gauss = exp_f32(power)
        raw = o * gauss
        alpha = min(raw, ALPHA_MAX)
        box = (xv >= fx0) & (xv < fx1) & (yv >= fy0) & (yv < fy1)
        ok = box & (st[B_LK + i] >= kl) & (power >= p_min) & (raw >= ALPHA_MIN)
        inv_one_m = F32(1.0) / (F32(1.0) - alpha)
        tcur = st[B_TC + i]
        t_before = tcur * inv_one_m
        w = alpha * t_before if ok else F32(0.0)
        q0, q1, q2, q3 = st[B_Q0 + i], st[B_Q1 + i], st[B_Q2 + i], st[B_Q3 + i]
        qf = q0 * f0 + q1 * f1 + q2 * f2 + q3 * f3
        r = st[B_R + i]
        # d acc / d alpha = f T_before - behind / (1 - alpha); d T_final / d alpha = -T_final / (1 - alpha)
        g_alpha = t_before * qf - inv_one_m * r
        st[B_R + i] = r + w * qf
        st[B_TC + i] = t_before if ok else tcur
        # the clamp at 0.99 passes no gradient
        u = g_alpha * gauss if ok & (raw < ALPHA_MAX) else F32(0.0)
        gf0 += w * q0
        gf1 += w * q1
        gf2 += w * q2
        gf3 += w * q3
        go += u
        s1 += u * dx
        s2 += u * dy
        sxx += u * (dx * dx)
        syy += u * (dy * dy)
        sxy += u * (dx * dy)
    # d power / d mean = (a dx + b dy, b dx + c dy); d power / d(a, b, c) = -(dx^2 / 2, dx dy, dy^2 / 2)
    return (
        o * (a * s1 + b * s2),
        o * (b * s1 + c * s2),
        F32(-0.5) * o * sxx,
        -o * sxy,
        F32(-0.5) * o * syy,
        go,
        gf0,
        gf1,
        gf2,
        gf3,
    )


@njit(parallel=True, **KERNEL_OPTIONS)
def composite_bwd(
    gid, tile_start, gp, width, height, tiles_x, order, bounds, t_final, last, g_acc, g_t, pair_grad
):  # pragma: no cover - compiled
    """Per tile, its list back to front from the last contributor (3DGS's backward pass), each
    Gaussian over the rows of its box that its ellipse meets, in each column half, widened to whole
    pairs of rows (the rows added are outside the box or fail the exact test: they add exact zeros).

    pair_grad [P, 10]: d/d(mean2d x, y), d/d(conic a, b, c), d/d opacity, d/d features (4) of the
    pair's Gaussian, summed over the tile's pixels in a fixed order.
    """
    gp_addr, gp_row = _U(gp.ctypes.data), _U(gp.strides[0])
    for th in prange(bounds.shape[0] - 1):
        st = _aligned_state(B_SIZE)
        for j in range(bounds[th], bounds[th + 1]):
            t = order[j]
            x0, x1, y0, y1 = tile_pixels(t, tiles_x, width, height)
            s, e = tile_start[t], tile_start[t + 1]
            for k in range(s, e):
                for m in range(10):
                    pair_grad[k, m] = F32(0.0)
            k_last = -1
            for i in range(NPIX):
                x = x0 + (i // (NPIX // 2)) * HALF + i % HALF
                y = y0 + (i // HALF) % TILE
                st[B_X + i] = F32(x)
                st[B_Y + i] = F32(y)
                inside = y < y1 and x < x1
                p = y * width + x if inside else 0
                # a pixel no gradient reaches (outside tracking's mask, say) adds exact zeros: none walked
                flows = inside and (
                    g_acc[p, 0] != 0 or g_acc[p, 1] != 0 or g_acc[p, 2] != 0 or g_acc[p, 3] != 0 or g_t[p] != 0
                )
                k_pix = last[p] if flows else -1
                k_last = max(k_last, k_pix)
                st[B_LK + i] = F32(k_pix - s) if k_pix >= 0 else F32(-1.0)
                st[B_TC + i] = t_final[p] if inside else F32(1.0)
                st[B_Q0 + i] = g_acc[p, 0] if inside else F32(0.0)
                st[B_Q1 + i] = g_acc[p, 1] if inside else F32(0.0)
                st[B_Q2 + i] = g_acc[p, 2] if inside else F32(0.0)
                st[B_Q3 + i] = g_acc[p, 3] if inside else F32(0.0)
                st[B_R + i] = g_t[p] * t_final[p] if inside else F32(0.0)
            for k in range(k_last, s - 1, -1):
                g = gid[k]
                if k - PREFETCH_AHEAD >= s:
                    _prefetch(gp_addr + _U(gid[k - PREFETCH_AHEAD]) * gp_row)  # type: ignore[call-arg]
                mx, my = gp[g, G_MX], gp[g, G_MY]
                bx0, bx1, by0, by1 = pixel_box(mx, my, gp[g, G_EX], gp[g, G_EY], x0, x1, y0, y1)
                if by1 <= by0:
                    continue
                a, b, c, o = gp[g, G_A], gp[g, G_B], gp[g, G_C], gp[g, G_O]
                p_min = gp[g, G_PMIN]
                for h in range((bx0 - x0) // HALF, (bx1 - x0 + HALF - 1) // HALF):
                    ry0, ry1 = _rows(
                        mx, my, a, b, c, p_min, max(bx0, x0 + h * HALF), min(bx1, x0 + (h + 1) * HALF), by0, by1, y0
                    )
                    if ry1 <= ry0:
                        continue
                    pair0, pair1 = (ry0 - y0) // 2, (ry1 - y0 + 1) // 2
                    lo, n = _U(h) * _UHALF_PIX + _U(pair0) * _UPAIR, _U(pair1 - pair0) << _UPAIR_SHIFT
                    f0, f1, f2, f3 = gp[g, G_F0], gp[g, G_F0 + 1], gp[g, G_F0 + 2], gp[g, G_F0 + 3]
                    kl = F32(k - s)
                    gr = _backward_span(
                        st, lo, n, F32(bx0), F32(bx1), F32(by0), F32(by1), mx, my, a, b, c, o, p_min, f0, f1, f2, f3, kl
                    )
                    for m in range(10):
                        pair_grad[k, m] += gr[m]


@njit(cache=True)
def reduce_sum(gid, pair_vals, out):  # pragma: no cover - compiled
    """out[gid[k]] += pair_vals[k] in list order: one fixed summation order, whatever the threads."""
    for k in range(gid.shape[0]):
        g = gid[k]
        for j in range(pair_vals.shape[1]):
            out[g, j] += pair_vals[k, j]


@njit(cache=True)
def reduce_stats(gid, pair_cov, pair_hits, pair_maxw, coverage, hit_count, max_weight):  # pragma: no cover
    for k in range(gid.shape[0]):
        g = gid[k]
        coverage[g] += pair_cov[k]
        hit_count[g] += pair_hits[k]
        if pair_maxw[k] > max_weight[g]:
            max_weight[g] = pair_maxw[k]
