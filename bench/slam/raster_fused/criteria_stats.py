"""The pruning criteria's per-Gaussian render statistics (``rasterize(..., extra=...)``), fused backend.

One compiled pass per pixel over its tile's depth-sorted list, with the forward's rules (alpha =
min(0.99, o exp(power)), pairs under 1/255 skipped, the pixel done where T would fall under 1e-4 and
that Gaussian not counted). It runs only when a strategy reads one of these statistics, apart from
the vectorised compositing (``compositing._forward``), which it leaves as it is: a scalar loop per
pixel is slower but these statistics are taken once per prune, not per mapping iteration.

Per pair it writes (then ``_reduce_sum`` sums over pairs in list order, so the result does not
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

from bench.slam.raster_fused import threads as _threading_layer  # noqa: F401 - set before a parallel kernel runs
from bench.slam.raster_fused.compositing import _exp, _reduce_sum, _tile_pixels
from bench.slam.raster_fused.constants import _F, ALPHA_MAX, ALPHA_MIN, T_MIN

# per-pair columns of ``pair``: weight_sum, opacity_t_sum, top1_count, top1_after_count, alpha_grad_sq
P_W, P_OT, P_TOP, P_TOPA, P_G2 = 0, 1, 2, 3, 4
N_PAIR = 5


@njit(inline="always", cache=True, error_model="numpy")
def _alpha(px, py, m2, conic, opac, g):  # pragma: no cover - compiled
    dx = px - m2[g, 0]
    dy = py - m2[g, 1]
    power = _F(-0.5) * (conic[g, 0] * dx * dx + conic[g, 2] * dy * dy) - conic[g, 1] * dx * dy
    raw = opac[g] * _exp(power)
    return raw, min(raw, ALPHA_MAX)


@njit(parallel=True, cache=True, error_model="numpy")
def _extra(gid, tile_start, m2, conic, opac, csum, width, height, tiles_x, bg_sum, grad, pair):  # pragma: no cover
    n_tiles = tile_start.shape[0] - 1
    for t in prange(n_tiles):
        x0, x1, y0, y1 = _tile_pixels(t, tiles_x, width, height)
        s, e = tile_start[t], tile_start[t + 1]
        ks = np.empty(e - s, np.int64)  # a pixel's contributors (pair index), their alpha and T in front
        al = np.empty(e - s, np.float32)
        tb = np.empty(e - s, np.float32)
        for y in range(y0, y1):
            for x in range(x0, x1):
                px, py = _F(x), _F(y)
                T = _F(1.0)
                col = _F(0.0)
                n = 0
                best_w, best_k = _F(0.0), -1
                best_a, best_ka = _F(0.0), -1
                for k in range(s, e):
                    g = gid[k]
                    raw, alpha = _alpha(px, py, m2, conic, opac, g)
                    if raw < ALPHA_MIN:
                        continue
                    test_t = T * (_F(1.0) - alpha)
                    if test_t < T_MIN:
                        break
                    w = alpha * T
                    pair[k, P_W] += w
                    pair[k, P_OT] += opac[g] * T
                    if w > best_w:
                        best_w, best_k = w, k
                    wa = alpha * test_t
                    if wa > best_a:
                        best_a, best_ka = wa, k
                    col += w * csum[g]
                    ks[n], al[n], tb[n] = k, alpha, T
                    n += 1
                    T = test_t
                if best_k >= 0:
                    pair[best_k, P_TOP] += _F(1.0)
                if best_ka >= 0:
                    pair[best_ka, P_TOPA] += _F(1.0)
                if grad:
                    front = _F(0.0)
                    for m in range(n):
                        k = ks[m]
                        g = gid[k]
                        front += al[m] * tb[m] * csum[g]
                        inv = _F(1.0) / (_F(1.0) - al[m])
                        v = opac[g] * (tb[m] * csum[g] - (col - front) * inv - T * bg_sum * inv)
                        pair[k, P_G2] += v * v


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
    pair = torch.zeros(gid.shape[0], N_PAIR, dtype=torch.float32)
    out = torch.zeros(m2.shape[0], N_PAIR, dtype=torch.float32)
    _extra(
        gid.numpy(), tile_start.numpy(), m2, co, op, cs, width, height, tiles_x, np.float32(bg_sum), grad, pair.numpy()
    )
    _reduce_sum(gid.numpy(), pair.numpy(), out.numpy())
    return out
