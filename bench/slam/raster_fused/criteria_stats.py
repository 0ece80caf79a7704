"""The pruning criteria's per-Gaussian render statistics (``rasterize(..., extra=...)``), fused backend.

One compiled pass per tile over its depth-sorted list, with the forward's rules (alpha =
min(0.99, o exp(power)), pairs under 1/255 skipped, the pixel done where T would fall under 1e-4 and
that Gaussian not counted). It runs only when a strategy reads one of these statistics, apart from
the vectorised compositing (``compositing.composite_fwd``), which it leaves as it is.

Each Gaussian of the list, front to back, updates the pixels of its 1/255 box (the half-extents
``compositing.pack`` computes), whose transmittance, best contributor and colour sum the tile keeps
per pixel, as the forward does. A loop per pixel over the tile's whole list, the first version, cost
a criterion that scores every keyframe held most of a long drive's time, mispredicting a branch for
each pair that misses the pixel. Per pair and per pixel the additions come in the same order as
there (pixels row by row, Gaussians front to back), so the sums are the same bit for bit.

Per pair it writes (then ``reduce_sum`` sums over pairs in list order, so the result does not
depend on the threads): sum of alpha T and of o T over the tile's pixels (T before the Gaussian),
the pixels where the Gaussian has the largest alpha T (front-most on ties) and the largest
alpha T_after = alpha T (1 - alpha) (EfficientGS's code), and sum of (o dI/dalpha)^2 with I the
image summed over channels (Speedy-Splat), in closed form:
dI/dalpha_j = T_j c_j - (C - C_<=j) / (1 - alpha_j) - T_final sum(bg) / (1 - alpha_j),
c_j the channel sum of j's colour, C the pixel's composited colour sum without background and
C_<=j its part from j and the Gaussians in front.
"""

from __future__ import annotations

import numpy as np
import torch
from numba import njit, prange

from bench.slam.raster_fused.compositing import KERNEL_OPTIONS, LN255, exp_f32, pixel_box, reduce_sum, tile_pixels
from bench.slam.raster_fused.constants import ALPHA_MAX, ALPHA_MIN, F32, T_MIN

# per-pair columns of ``pair``: weight_sum, opacity_t_sum, top1_count, top1_after_count, alpha_grad_sq
P_W, P_OT, P_TOP, P_TOPA, P_G2 = 0, 1, 2, 3, 4
N_PAIR = 5


@njit(inline="always", cache=True, error_model="numpy")
def _alpha(px, py, m2, conic, opac, g):  # pragma: no cover - compiled
    dx = px - m2[g, 0]
    dy = py - m2[g, 1]
    power = F32(-0.5) * (conic[g, 0] * dx * dx + conic[g, 2] * dy * dy) - conic[g, 1] * dx * dy
    raw = opac[g] * exp_f32(power)
    return raw, min(raw, ALPHA_MAX)


@njit(parallel=True, **KERNEL_OPTIONS)
def _half_extents(conic, opac, ext):  # pragma: no cover - compiled
    """ext [V, 2]: the half-extents of each Gaussian's 1/255 box, computed as ``compositing.pack`` does
    (-1: an empty box, for a Gaussian that reaches 1/255 nowhere)."""
    for g in prange(conic.shape[0]):
        a, b, c = conic[g, 0], conic[g, 1], conic[g, 2]
        o = opac[g]
        det = a * c - b * b
        ex = ey = F32(-1.0)
        if o >= ALPHA_MIN and det > F32(0.0):
            r2 = F32(2.0) * (LN255 + np.log(o))  # d^T S^-1 d <= r2  <=>  o exp(power) >= 1/255
            ex = np.sqrt(r2 * c / det) + F32(1e-3)
            ey = np.sqrt(r2 * a / det) + F32(1e-3)
        ext[g, 0], ext[g, 1] = ex, ey


@njit(parallel=True, cache=True, error_model="numpy")
def criteria_extra(
    gid, tile_start, m2, conic, opac, ext, csum, width, height, tiles_x, bg_sum, grad, pair
):  # pragma: no cover
    n_tiles = tile_start.shape[0] - 1
    for t in prange(n_tiles):
        x0, x1, y0, y1 = tile_pixels(t, tiles_x, width, height)
        s, e = tile_start[t], tile_start[t + 1]
        tw = x1 - x0
        n_px = tw * (y1 - y0)
        trans = np.ones(n_px, np.float32)  # per pixel: T in front of the next contributor
        done = np.zeros(n_px, np.bool_)  # T would fall under T_MIN: nothing behind counts
        best_w = np.zeros(n_px, np.float32)
        best_k = np.full(n_px, -1, np.int64)
        best_a = np.zeros(n_px, np.float32)
        best_ka = np.full(n_px, -1, np.int64)
        col = np.zeros(n_px, np.float32)  # the composited colour sum, without the background
        t2 = np.ones(n_px, np.float32)  # stage 1: T again, front to back
        front = np.zeros(n_px, np.float32)  # stage 1: the colour sum from the Gaussians up to this one
        # stage 0: the sums, the best contributors and each pixel's colour and final T; stage 1 (alpha_grad_sq),
        # the same walk again, now that the colour and final T that dI/dalpha needs are known
        for stage in range(2 if grad else 1):
            tr = trans if stage == 0 else t2
            done[:] = False
            for k in range(s, e):
                g = gid[k]
                bx0, bx1, by0, by1 = pixel_box(m2[g, 0], m2[g, 1], ext[g, 0], ext[g, 1], x0, x1, y0, y1)
                for y in range(by0, by1):
                    for x in range(bx0, bx1):
                        p = (y - y0) * tw + (x - x0)
                        if done[p]:
                            continue
                        raw, alpha = _alpha(F32(x), F32(y), m2, conic, opac, g)
                        if raw < ALPHA_MIN:
                            continue
                        T = tr[p]
                        test_t = T * (F32(1.0) - alpha)
                        if test_t < T_MIN:
                            done[p] = True
                            continue
                        tr[p] = test_t
                        if stage == 0:
                            w = alpha * T
                            pair[k, P_W] += w
                            pair[k, P_OT] += opac[g] * T
                            if w > best_w[p]:
                                best_w[p], best_k[p] = w, k
                            wa = alpha * test_t
                            if wa > best_a[p]:
                                best_a[p], best_ka[p] = wa, k
                            col[p] += w * csum[g]
                        else:
                            front[p] += alpha * T * csum[g]
                            inv = F32(1.0) / (F32(1.0) - alpha)
                            v = opac[g] * (T * csum[g] - (col[p] - front[p]) * inv - trans[p] * bg_sum * inv)
                            pair[k, P_G2] += v * v
        for p in range(n_px):
            if best_k[p] >= 0:
                pair[best_k[p], P_TOP] += F32(1.0)
            if best_ka[p] >= 0:
                pair[best_ka[p], P_TOPA] += F32(1.0)


def extra_stats(
    means2d: torch.Tensor,
    conic: torch.Tensor,
    opac: torch.Tensor,
    colors: torch.Tensor,
    gid: torch.Tensor,
    tile_start: torch.Tensor,
    width: int,
    height: int,
    tiles_x: int,
    bg_sum: float,
    grad: bool,
) -> torch.Tensor:
    """[V, 5] float32 per Gaussian in view: sum alpha T, sum o T, top-1 pixels by alpha T, top-1 pixels
    by alpha T_after, and (``grad``; else 0) sum (o dI/dalpha)^2."""
    m2 = means2d.detach().float().contiguous().numpy()
    co = conic.detach().float().contiguous().numpy()
    op = opac.detach().float().contiguous().numpy()
    cs = colors.detach().float().sum(-1).contiguous().numpy()  # [V] channel sum, the colours as rendered
    ext = np.empty((m2.shape[0], 2), np.float32)  # [V, 2]
    _half_extents(co, op, ext)
    pair = torch.zeros(gid.shape[0], N_PAIR, dtype=torch.float32)
    out = torch.zeros(m2.shape[0], N_PAIR, dtype=torch.float32)
    args = (tiles_x, np.float32(bg_sum), grad, pair.numpy())
    criteria_extra(gid.numpy(), tile_start.numpy(), m2, co, op, ext, cs, width, height, *args)
    reduce_sum(gid.numpy(), pair.numpy(), out.numpy())
    return out
