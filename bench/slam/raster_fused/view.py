"""The Gaussians in view: gathered from the map's [N] tensors, their conic and antialiasing factor, and the
backward that chains the compositing's per-Gaussian gradients through both and scatters them back to [N].

What torch did here before (index selects, the conic's and the factor's element-wise ops, and their autograd:
zero-filled [N] gradients plus index additions, and the intermediates it kept) cost more time and memory than
these two passes (reports/speed/2026-11-29-view-kernels.md).

The forward computes each quantity with the operations of ``bench.slam.conic.conic`` and
``raster.antialias_compensation``, in the same order and without fastmath: the same values as torch's, but for
the antialiasing factor, whose square root torch's vectorised float32 code does not round correctly on every host
(it may differ in the last place). The backward gives torch's gradients up to float32 rounding (another order of
the same sums).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from bench.slam.raster_fused.constants import F32, LOWPASS_PX2

_EPS = F32(1e-12)  # antialias_compensation's clamps


@njit(parallel=True, cache=True)
def gather_view(vis, m2, cov, opac, colors, z, antialiased, far, m2_v, inv_v, op_v, feat_v, fac_v):  # pragma: no cover
    """Per Gaussian in view i (``vis[i]`` in the map): its mean m2_v [V, 2], conic inv_v [V, 3], opacity op_v
    [V] (times the antialiasing factor fac_v [V] where ``antialiased``; fac_v is 1 otherwise) and features
    feat_v [V, 4] (colour, and the depth it paints: z, or 0 from ``far`` on)."""
    for i in prange(vis.shape[0]):
        g = vis[i]
        a, b, c = cov[g, 0], cov[g, 1], cov[g, 2]
        det = a * c - b * b
        det_safe = det if det > F32(0.0) else F32(1.0)
        inv_v[i, 0] = c / det_safe
        inv_v[i, 1] = -b / det_safe
        inv_v[i, 2] = a / det_safe
        fac = F32(1.0)
        if antialiased:
            det_raw = (a - LOWPASS_PX2) * (c - LOWPASS_PX2) - b * b
            fac = np.sqrt(max(det_raw / max(det, _EPS), _EPS)) if det > F32(0.0) else F32(0.0)
            op_v[i] = opac[g] * fac
        else:
            op_v[i] = opac[g]
        fac_v[i] = fac
        m2_v[i, 0], m2_v[i, 1] = m2[g, 0], m2[g, 1]
        feat_v[i, 0], feat_v[i, 1], feat_v[i, 2] = colors[g, 0], colors[g, 1], colors[g, 2]
        feat_v[i, 3] = z[g] if z[g] < far else F32(0.0)


@njit(parallel=True, cache=True)
def scatter_view(vis, grad_v, cov, opac, z, far, antialiased, fac_v, g_m2, g_cov, g_op, g_col, g_z):  # pragma: no cover
    """The gradients of ``gather_view``'s inputs from those of its outputs, grad_v [V, 10] (mean 2, conic 3,
    opacity 1, features 4, as the compositing's backward sums them): written at the rows ``vis`` of g_m2 [N, 2],
    g_cov [N, 3], g_z [N] and, where they have N rows (the colours and opacities take a gradient), g_op [N]
    and g_col [N, 3]; the other rows keep what they hold (zeros)."""
    want_op = g_op.shape[0] > 0
    want_col = g_col.shape[0] > 0
    for i in prange(vis.shape[0]):
        g = vis[i]
        g_m2[g, 0], g_m2[g, 1] = grad_v[i, 0], grad_v[i, 1]
        a, b, c = cov[g, 0], cov[g, 1], cov[g, 2]
        ga, gb, gc = grad_v[i, 2], grad_v[i, 3], grad_v[i, 4]  # of the conic (c/d, -b/d, a/d)
        det = a * c - b * b
        if det > F32(0.0):
            g_det = -(ga * c - gb * b + gc * a) / (det * det)
            da = gc / det + g_det * c
            db = -gb / det - F32(2.0) * b * g_det
            dc = ga / det + g_det * a
        else:  # divided by 1: the numerators alone carry the gradient
            da, db, dc = gc, -gb, ga
        g_o = grad_v[i, 5]
        if antialiased:
            fac = fac_v[i]
            if want_op:
                g_op[g] = g_o * fac
            if det > F32(0.0):
                det_c = max(det, _EPS)
                det_raw = (a - LOWPASS_PX2) * (c - LOWPASS_PX2) - b * b
                if det_raw / det_c >= _EPS:  # the clamps pass the gradient at and above their bound
                    g_ratio = g_o * opac[g] / (F32(2.0) * fac)
                    g_raw = g_ratio / det_c
                    da += g_raw * (c - LOWPASS_PX2)
                    dc += g_raw * (a - LOWPASS_PX2)
                    db -= F32(2.0) * b * g_raw
                    if det >= _EPS:
                        g_dc = -g_ratio * det_raw / (det_c * det_c)
                        da += g_dc * c
                        dc += g_dc * a
                        db -= F32(2.0) * b * g_dc
        elif want_op:
            g_op[g] = g_o
        g_cov[g, 0], g_cov[g, 1], g_cov[g, 2] = da, db, dc
        if want_col:
            g_col[g, 0], g_col[g, 1], g_col[g, 2] = grad_v[i, 6], grad_v[i, 7], grad_v[i, 8]
        g_z[g] = grad_v[i, 9] if z[g] < far else F32(0.0)
