"""Differentiable image losses: the depth L1 that tracking and mapping share, and mapping's D-SSIM.

The D-SSIM term is the one 3DGS (``utils/loss_utils.py``: ``(1 - lambda) * L1 + lambda * (1 - ssim)``,
lambda = 0.2) and SplaTAM's mapping (``scripts/splatam.py`` ``get_loss``: ``0.8 * l1 + 0.2 * (1 - calc_ssim)``)
add to the colour L1. The evaluation metric (``bench.metrics.image``) is torchmetrics' SSIM in float64;
this one is the training loss: float32, the same 11 px / sigma 1.5 Gaussian window applied as two
separable 1-D passes (11 + 11 taps instead of 121), zero padding as in 3DGS's ``_ssim``.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from bench.slam.raster import RasterOutput

SSIM_WINDOW_PX = 11
SSIM_SIGMA_PX = 1.5
C1 = 0.01**2
C2 = 0.03**2


def _window(device: torch.device) -> torch.Tensor:
    x = torch.arange(SSIM_WINDOW_PX, dtype=torch.float32, device=device) - SSIM_WINDOW_PX // 2
    g = torch.exp(-(x**2) / (2 * SSIM_SIGMA_PX**2))
    return g / g.sum()  # [11]


def _blur(x: torch.Tensor, g: torch.Tensor) -> torch.Tensor:
    """Separable Gaussian blur of ``x`` [C, H, W] (same size, zero padding)."""
    c = x.shape[0]
    pad = SSIM_WINDOW_PX // 2
    x = F.conv2d(x[None], g.view(1, 1, 1, -1).expand(c, 1, 1, -1), padding=(0, pad), groups=c)
    return F.conv2d(x, g.view(1, 1, -1, 1).expand(c, 1, -1, 1), padding=(pad, 0), groups=c)[0]


def ssim_map(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Per-pixel SSIM [H, W] of two [H, W, 3] images in [0, 1], averaged over channels."""
    g = _window(pred.device)
    x, y = pred.permute(2, 0, 1), target.permute(2, 0, 1)  # [3, H, W]
    stats = _blur(torch.cat([x, y, x * x, y * y, x * y]), g)  # [15, H, W]
    mx, my, sxx, syy, sxy = stats.split(3)
    vx, vy, cxy = sxx - mx * mx, syy - my * my, sxy - mx * my
    s = ((2 * mx * my + C1) * (2 * cxy + C2)) / ((mx * mx + my * my + C1) * (vx + vy + C2))
    return s.mean(0)


def dssim(pred: torch.Tensor, target: torch.Tensor, fused: bool = False) -> torch.Tensor:
    """1 - mean SSIM of two [H, W, 3] images: the structural term of the 3DGS mapping loss.

    ``fused``: through the compiled CPU kernels of ``bench/slam/raster_fused/ssim.py`` (CPU tensors;
    mapping uses them where the rasterizer is the ``fused`` backend), which give ``ssim_map``'s value
    and gradient up to float32 rounding at a fraction of autograd's cost; otherwise ``ssim_map``."""
    if fused:
        # numba: only where the fused backend runs; the kernels loaded from numba's cache, as the rasterizer's
        from bench.slam.raster_fused.kernel_cache import load_from_cache
        from bench.slam.raster_fused.ssim import ssim_map_fused

        load_from_cache()
        s = ssim_map_fused(pred.permute(2, 0, 1), target.permute(2, 0, 1), _window(pred.device), C1, C2)  # [3, H, W]
        return 1.0 - s.mean(0).mean()
    return 1.0 - ssim_map(pred, target).mean()


def rendered_depth(out: RasterOutput, normalized: bool) -> torch.Tensor:
    """The render's depth [H, W] (m); ``normalized``: divided by its alpha (``slam.depth_normalized``)."""
    if normalized:
        return out.depth / out.alpha.clamp_min(1e-3)
    return out.depth


def depth_l1(
    out: RasterOutput, depth: torch.Tensor, max_m: float, normalized: bool, mask: torch.Tensor | None = None
) -> torch.Tensor:
    """Mean L1 depth error of the render ``out`` against ``depth`` [H, W] over valid pixels nearer than
    ``max_m`` (``slam.depth_loss_max_m``), within ``mask`` [H, W] where given (tracking and mapping both)."""
    dmask = (depth > 0) & (depth < max_m)
    if mask is not None:
        dmask &= mask
    return ((rendered_depth(out, normalized) - depth).abs() * dmask).sum() / dmask.sum().clamp_min(1)
