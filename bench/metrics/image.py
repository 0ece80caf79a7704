"""Rendering quality (PSNR, SSIM) through torchmetrics' functional API, one convention everywhere.

Images are ``[H, W, 3]`` float tensors in [0, 1]; the data range is 1.

SSIM convention (Wang et al. 2004 as used by 3DGS papers): Gaussian window 11x11, sigma 1.5,
data range 1, K1 = 0.01, K2 = 0.03, population (not sample) covariance, per-channel maps averaged
over channels and pixels. Computed in float64 so the figure does not depend on the input dtype.

Border handling: torchmetrics reflect-pads by 5 px and averages the SSIM map over *all* H x W
pixels, while scikit-image (``structural_similarity(gaussian_weights=True, sigma=1.5,
use_sample_covariance=False)``) crops 5 px per side before averaging. On the interior the two
maps agree to 1e-14 (float64); the whole-image means differ by the border share, measured on
smooth-plus-noise images at noise 0.02-0.3 as up to 2.6e-3 at 64x80, 6e-4 at 120x160, 5e-4 at
240x320 and 2e-5 at KITTI's 370x1226 (tests/metrics/test_image.py checks 1.5e-3 from 120x160).
The original 3DGS code's SSIM (zero padding, border kept) differs from both in the same way.

PSNR of identical images is ``inf``; it is reported as such rather than clipped.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING

import torch
from torchmetrics.functional.image import peak_signal_noise_ratio, structural_similarity_index_measure

from bench.errors import MetricError

if TYPE_CHECKING:
    from bench.metrics.lpips import LPIPS

SSIM_KERNEL_PX = 11
SSIM_SIGMA_PX = 1.5
SSIM_K1 = 0.01
SSIM_K2 = 0.03
DATA_RANGE = 1.0


def _to_bchw(pred: torch.Tensor, target: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Validate two ``[H, W, 3]`` images and return ``[1, 3, H, W]`` float64 copies."""
    if not isinstance(pred, torch.Tensor) or not isinstance(target, torch.Tensor):
        raise MetricError(f"images must be torch tensors: found {type(pred).__name__} and {type(target).__name__}")
    if pred.ndim != 3 or pred.shape[-1] != 3 or pred.shape != target.shape:
        raise MetricError(
            f"images must both be [h, w, 3] of one size: found {list(pred.shape)} and {list(target.shape)}"
        )
    if not (pred.is_floating_point() and target.is_floating_point()):
        raise MetricError(f"images must be float in [0, 1]: found {pred.dtype} and {target.dtype}")
    p = pred.detach().to(torch.float64).permute(2, 0, 1)[None]  # [1, 3, H, W]
    t = target.detach().to(torch.float64).permute(2, 0, 1)[None]  # [1, 3, H, W]
    if not (torch.isfinite(p).all() and torch.isfinite(t).all()):
        raise MetricError("images must be finite: found nan or inf")
    return p, t


def psnr_db(pred: torch.Tensor, target: torch.Tensor) -> float:
    """Peak signal-to-noise ratio in dB with data range 1 (``inf`` for identical images)."""
    p, t = _to_bchw(pred, target)
    if torch.equal(p, t):
        return math.inf
    return float(peak_signal_noise_ratio(p, t, data_range=DATA_RANGE))


def ssim(pred: torch.Tensor, target: torch.Tensor) -> float:
    """Mean SSIM with the module's convention (Gaussian 11 / 1.5, K1 0.01, K2 0.03, range 1)."""
    p, t = _to_bchw(pred, target)
    if min(p.shape[-2:]) < SSIM_KERNEL_PX:
        raise MetricError(
            f"ssim needs images of at least {SSIM_KERNEL_PX}x{SSIM_KERNEL_PX} px: found {list(pred.shape[:2])}"
        )
    value = structural_similarity_index_measure(
        p,
        t,
        gaussian_kernel=True,
        sigma=SSIM_SIGMA_PX,
        kernel_size=SSIM_KERNEL_PX,
        data_range=DATA_RANGE,
        k1=SSIM_K1,
        k2=SSIM_K2,
    )
    return float(value)


def image_metrics(
    preds: torch.Tensor | Sequence[torch.Tensor],
    targets: torch.Tensor | Sequence[torch.Tensor],
    lpips: LPIPS | None = None,
) -> dict[str, float | int | None]:
    """Per-frame PSNR/SSIM (and LPIPS when a loaded ``LPIPS`` is given), averaged over frames.

    ``preds``/``targets``: ``[B, H, W, 3]`` tensors or sequences of ``[H, W, 3]`` (sizes may differ
    between frames). PSNR is averaged per frame in dB (the 3DGS convention), not pooled over MSE;
    an ``inf`` frame makes the mean ``inf``. ``lpips`` is ``None`` in the result when not given.
    """
    if len(preds) != len(targets):
        raise MetricError(f"frame counts differ: expected equal, found {len(preds)} preds and {len(targets)} targets")
    if len(preds) == 0:
        raise MetricError("no frames to evaluate: expected at least 1, found 0")
    psnrs, ssims, lpipss = [], [], []
    for pred, target in zip(preds, targets, strict=True):
        psnrs.append(psnr_db(pred, target))
        ssims.append(ssim(pred, target))
        if lpips is not None:
            lpipss.append(lpips(pred, target))
    n = len(psnrs)
    return {
        "psnr_db": sum(psnrs) / n,
        "ssim": sum(ssims) / n,
        "lpips": sum(lpipss) / n if lpipss else None,
        "num_frames": n,
    }
