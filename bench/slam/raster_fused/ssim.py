"""Mapping's SSIM term as two compiled CPU kernels: the per-pixel SSIM and its hand-written gradient.

``bench.slam.losses.ssim_map`` (torch) is the reference: the same 11 px, sigma 1.5 Gaussian window applied
as two separable 1-D passes with zero padding, the same constants, float32. There autograd keeps the
15 blurred channels (mean, square and cross term of both images) and runs two convolutions' backward
and some forty elementwise backward operations per call. Here the forward blurs the five statistics
row by row and column by column and keeps, per pixel, the three partial derivatives of SSIM that
the gradient needs; the backward blurs the upstream gradient times them (three channels: the
transpose of a zero-padded blur with a symmetric window is the same blur) and adds them up:

    dL/dx = B(g dS/dmu_x) + 2 x B(g dS/ds_xx) + y B(g dS/ds_xy)

with B the blur, g the upstream gradient of the SSIM map, and s_xx, s_xy the blurred x^2 and x y.
The target needs no gradient. The results agree with the reference up to float32 rounding (the
taps are summed in another order; tests/slam/test_ssim_fused.py).

Determinism: every output element is one thread's fixed sequence of operations (the rows of a pass
are split between threads, no sum crosses them), so the result does not depend on the thread count.
"""

from __future__ import annotations

import numpy as np
import torch
from numba import njit, prange

from bench.slam.raster_fused.compositing import KERNEL_OPTIONS
from bench.slam.raster_fused.constants import F32
from bench.slam.raster_fused.threads import set_threads

SSIM_WINDOW_PX = 11  # as bench.slam.losses
_HALF = SSIM_WINDOW_PX // 2
# the compositing kernels' options (fastmath, numpy's error model); the blur's loops are elementwise over a
# row (no sum across vector lanes), so fastmath's reordering cannot make the rounding depend on a buffer's alignment
_OPTIONS = KERNEL_OPTIONS


_U = np.uint64  # unsigned indices: numba wraps negative signed ones, a select per load that keeps loops scalar


@njit(inline="always", **_OPTIONS)
def _blur_row(src, s0, pad, dst, d0, w, g):  # pragma: no cover - compiled
    """dst[d0 + j] = sum_k g[k] src[s0 + j + k - HALF] for j < w, zero outside the row; ``pad`` [w + 10] is scratch."""
    for j in range(_U(w)):
        pad[_U(_HALF) + j] = src[s0 + j]
    for j in range(_U(w)):
        dst[d0 + j] = g[0] * pad[j]
    for k in range(_U(1), _U(SSIM_WINDOW_PX)):
        gk = g[k]
        for j in range(_U(w)):
            dst[d0 + j] += gk * pad[j + k]


@njit(inline="always", **_OPTIONS)
def _row_scratch(w):  # pragma: no cover - compiled
    """A row of w pixels with the window's zero padding either side."""
    return np.zeros(w + 2 * _HALF, np.float32)


@njit(inline="always", **_OPTIONS)
def _blur_column(src, n, n_q, cr, h, w, g):  # pragma: no cover - compiled
    """The column pass at flat row ``cr`` (channel cr // h, row cr % h) of each of the ``n_q`` planes of
    ``src`` (n values each): [n_q * w], zero padding above and below the image."""
    r = cr % h
    out = np.zeros(n_q * w, np.float32)
    for k in range(max(0, _HALF - r), min(SSIM_WINDOW_PX, h + _HALF - r)):
        gk = g[k]
        row = _U((cr + k - _HALF) * w)
        for q in range(_U(n_q)):
            for j in range(_U(w)):
                out[q * _U(w) + j] += gk * src[q * _U(n) + row + j]
    return out


@njit(parallel=True, **_OPTIONS)
def ssim_fwd(x, y, g, c1, c2, hb, s, d_mx, d_sxx, d_sxy):  # pragma: no cover - compiled
    """x, y [C, H, W] float32 (prediction, target); g [11] the window; hb [5 C H W] scratch (the row pass of
    x, y, x^2, y^2 and x y).

    Fills s [C, H, W], the SSIM of each pixel and channel, and its partial derivatives by the blurred
    mean of x (d_mx), of x^2 (d_sxx) and of x y (d_sxy), each [C, H, W]."""
    n_ch, h, w = x.shape
    n = n_ch * h * w
    xf, yf = x.reshape(n), y.reshape(n)
    sf, dmf, dxf, dyf = s.reshape(n), d_mx.reshape(n), d_sxx.reshape(n), d_sxy.reshape(n)
    for cr in prange(n_ch * h):
        o = _U(cr * w)
        pad = _row_scratch(w)
        row = np.empty(w, np.float32)
        _blur_row(xf, o, pad, hb, o, w, g)
        _blur_row(yf, o, pad, hb, _U(n) + o, w, g)
        for j in range(_U(w)):
            row[j] = xf[o + j] * xf[o + j]
        _blur_row(row, _U(0), pad, hb, _U(2 * n) + o, w, g)
        for j in range(_U(w)):
            row[j] = yf[o + j] * yf[o + j]
        _blur_row(row, _U(0), pad, hb, _U(3 * n) + o, w, g)
        for j in range(_U(w)):
            row[j] = xf[o + j] * yf[o + j]
        _blur_row(row, _U(0), pad, hb, _U(4 * n) + o, w, g)
    for cr in prange(n_ch * h):
        o = _U(cr * w)
        st = _blur_column(hb, n, 5, cr, h, w, g)  # mx, my, sxx, syy, sxy at this row
        for j in range(_U(w)):
            mx, my = st[j], st[_U(w) + j]
            sxx, syy, sxy = st[_U(2 * w) + j], st[_U(3 * w) + j], st[_U(4 * w) + j]
            a1 = F32(2.0) * mx * my + c1
            a2 = F32(2.0) * (sxy - mx * my) + c2
            b1 = mx * mx + my * my + c1
            b2 = (sxx - mx * mx) + (syy - my * my) + c2
            inv = F32(1.0) / (b1 * b2)
            ss = a1 * a2 * inv
            sf[o + j] = ss
            # dS/dmx = 2 (my (a2 - a1) - S mx (b2 - b1)) / (b1 b2); dS/dsxx = -S / b2; dS/dsxy = 2 a1 / (b1 b2)
            dmf[o + j] = F32(2.0) * (my * (a2 - a1) - ss * mx * (b2 - b1)) * inv
            dxf[o + j] = -ss / b2
            dyf[o + j] = F32(2.0) * a1 * inv


@njit(parallel=True, **_OPTIONS)
def ssim_bwd(x, y, g, g_s, d_mx, d_sxx, d_sxy, tb, g_x):  # pragma: no cover - compiled
    """g_x [C, H, W] = dL/dx from the upstream gradient g_s [C, H, W] of the SSIM map and the partial
    derivatives ``ssim_fwd`` kept: the three products (into the scratch tb [3 C H W]) blurred, columns then
    rows, and combined."""
    n_ch, h, w = x.shape
    n = n_ch * h * w
    xf, yf, gsf, gxf = x.reshape(n), y.reshape(n), g_s.reshape(n), g_x.reshape(n)
    dmf, dxf, dyf = d_mx.reshape(n), d_sxx.reshape(n), d_sxy.reshape(n)
    for cr in prange(n_ch * h):
        o = _U(cr * w)
        for j in range(_U(w)):
            gs = gsf[o + j]
            tb[o + j] = gs * dmf[o + j]
            tb[_U(n) + o + j] = gs * dxf[o + j]
            tb[_U(2 * n) + o + j] = gs * dyf[o + j]
    for cr in prange(n_ch * h):
        o = _U(cr * w)
        vb = _blur_column(tb, n, 3, cr, h, w, g)
        pad = _row_scratch(w)
        b0 = np.empty(w, np.float32)
        b1 = np.empty(w, np.float32)
        b2 = np.empty(w, np.float32)
        _blur_row(vb, _U(0), pad, b0, _U(0), w, g)
        _blur_row(vb, _U(w), pad, b1, _U(0), w, g)
        _blur_row(vb, _U(2 * w), pad, b2, _U(0), w, g)
        for j in range(_U(w)):
            gxf[o + j] = b0[j] + F32(2.0) * xf[o + j] * b1[j] + yf[o + j] * b2[j]


class _SsimMap(torch.autograd.Function):
    """SSIM per pixel and channel [C, H, W] of x [C, H, W] against y [C, H, W]; differentiable in x."""

    @staticmethod
    def forward(ctx, x, y, g, c1, c2):
        xc = x.detach().float().contiguous()
        yc = y.detach().float().contiguous()
        gc = g.detach().float().contiguous()
        set_threads(int(xc.numel()))
        s, d_mx, d_sxx, d_sxy = (torch.empty_like(xc) for _ in range(4))
        hb = torch.empty(5 * xc.numel())  # a torch tensor, like every buffer of the kernels: the memory probe counts it
        ssim_fwd(
            xc.numpy(),
            yc.numpy(),
            gc.numpy(),
            F32(c1),
            F32(c2),
            hb.numpy(),
            s.numpy(),
            d_mx.numpy(),
            d_sxx.numpy(),
            d_sxy.numpy(),
        )
        del hb
        ctx.save_for_backward(xc, yc, gc, d_mx, d_sxx, d_sxy)
        return s

    @staticmethod
    def backward(ctx, g_s):
        xc, yc, gc, d_mx, d_sxx, d_sxy = ctx.saved_tensors
        set_threads(int(xc.numel()))
        g_x = torch.empty_like(xc)
        ssim_bwd(
            xc.numpy(),
            yc.numpy(),
            gc.numpy(),
            g_s.float().contiguous().numpy(),
            d_mx.numpy(),
            d_sxx.numpy(),
            d_sxy.numpy(),
            torch.empty(3 * xc.numel()).numpy(),
            g_x.numpy(),
        )
        return g_x, None, None, None, None


def ssim_map_fused(x: torch.Tensor, y: torch.Tensor, g: torch.Tensor, c1: float, c2: float) -> torch.Tensor:
    """[C, H, W] SSIM of x against y ([C, H, W] float32 CPU tensors, x differentiable) under the 1-D window g [11].
    Callers load the kernels first (``kernel_cache.load_from_cache``, as ``losses.dssim`` does; that module
    imports this one)."""
    return _SsimMap.apply(x, y, g, c1, c2)
