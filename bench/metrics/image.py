"""Rendering quality (PSNR, SSIM, MS-SSIM) through torchmetrics' functional API, one convention everywhere.

Images are ``[H, W, 3]`` float tensors in [0, 1]; the data range is 1.

SSIM convention (Wang et al. 2004 as used by 3DGS papers): Gaussian window 11x11, sigma 1.5,
data range 1, K1 = 0.01, K2 = 0.03, population (not sample) covariance, per-channel maps averaged
over channels and pixels. Computed in float64 so the figure does not depend on the input dtype.

Speed: torchmetrics convolves with the full 11x11 window; the Gaussian window is separable, so the same
window is applied here as an 11x1 and a 1x11 pass (``_ssim_terms``), in float64, with torchmetrics'
padding, clamps, border crop and down-sampling. It gives torchmetrics' figures to float64 rounding
(``tests/metrics/test_image.py`` holds both metrics to torchmetrics' own functions) at a fraction of the
cost of a full 2D convolution in float64.

Border handling: torchmetrics reflect-pads by 5 px and averages the SSIM map over *all* H x W
pixels, while scikit-image (``structural_similarity(gaussian_weights=True, sigma=1.5,
use_sample_covariance=False)``) crops 5 px per side before averaging. On the interior the two
maps agree to float64 rounding; the whole-image means differ by the border's share of the image,
which shrinks as images grow (tests/metrics/test_image.py holds the bound).
The original 3DGS code's SSIM (zero padding, border kept) differs from both in the same way.

PSNR of identical images is ``inf``; it is reported as such rather than clipped.

MS-SSIM is the SSIM the paper's base system reports (SplaTAM ``utils/eval_helpers.py``, ``eval``:
``ms_ssim(weighted_im, weighted_gt_im, data_range=1.0, size_average=True)`` from pytorch_msssim):
five scales with Wang et al.'s weights, the same 11 px / sigma 1.5 window and K1, K2 as SSIM,
negative per-scale terms clipped to 0 (both libraries' ``relu``). It is computed here with
torchmetrics, which differs from pytorch_msssim in three details: torchmetrics averages each
scale over channels before the product across scales (pytorch_msssim takes the product per
channel, then the mean), scores the coarsest scale's SSIM term over its reflect-padded border
too, and drops an odd last row or column when it halves (pytorch_msssim zero-pads it). The two
agree closely for similar images and drift apart for dissimilar ones
(``tests/metrics/test_protocol.py`` pins a known answer of pytorch_msssim 1.0.0).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import torch
import torch.nn.functional as F
from torchmetrics.functional.image import peak_signal_noise_ratio

from bench.errors import MetricError

if TYPE_CHECKING:
    from bench.metrics.lpips import LPIPS

SSIM_KERNEL_PX = 11
SSIM_SIGMA_PX = 1.5
SSIM_K1 = 0.01
SSIM_K2 = 0.03
DATA_RANGE = 1.0
MS_SSIM_BETAS = (0.0448, 0.2856, 0.3001, 0.2363, 0.1333)  # Wang et al. 2003; pytorch_msssim's and torchmetrics' default
# the coarsest of the 5 scales (1/16 of the image) must still hold the 11 px window: torchmetrics refuses
# a side s with s // 16 <= 10 (pytorch_msssim, SplaTAM's library, asserts s > 160)
MS_SSIM_MIN_PX = SSIM_KERNEL_PX * 2 ** (len(MS_SSIM_BETAS) - 1)


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


# the SSIM window and constants, shared by SSIM and every scale of MS-SSIM (torchmetrics' keyword names)
WINDOW: dict[str, Any] = dict(
    gaussian_kernel=True, sigma=SSIM_SIGMA_PX, kernel_size=SSIM_KERNEL_PX, data_range=DATA_RANGE, k1=SSIM_K1, k2=SSIM_K2
)


def _gaussian_1d(dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    """[K] the normalised 1D Gaussian whose outer product is torchmetrics' 2D window (``_gaussian``)."""
    half = (SSIM_KERNEL_PX - 1) / 2
    dist = torch.arange(-half, half + 1, 1, dtype=dtype, device=device)  # [K]
    g = torch.exp(-torch.pow(dist / SSIM_SIGMA_PX, 2) / 2)
    return g / g.sum()


def _blur(x: torch.Tensor, g: torch.Tensor) -> torch.Tensor:
    """[B, C, H, W] reflect-padded by K // 2 and filtered by the separable window ``g`` [K]: a valid [B, C, H, W]."""
    pad, c = g.numel() // 2, x.shape[1]
    x = F.pad(x, (pad, pad, pad, pad), mode="reflect")
    x = F.conv2d(x, g.view(1, 1, 1, -1).expand(c, 1, 1, g.numel()), groups=c)  # along W
    return F.conv2d(x, g.view(1, 1, -1, 1).expand(c, 1, g.numel(), 1), groups=c)  # along H


def _ssim_terms(p: torch.Tensor, t: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """SSIM over every pixel, and the contrast-structure term over the pixels the window does not reach past the
    border (torchmetrics' ``_ssim_update`` with ``return_contrast_sensitivity``), for [1, C, H, W] float64 images."""
    g = _gaussian_1d(p.dtype, p.device)
    c = p.shape[1]
    mu_p, mu_t, pp, tt, pt = _blur(torch.cat((p, t, p * p, t * t, p * t), 1), g).split(c, 1)  # each [1, C, H, W]
    mu_pp, mu_tt, mu_pt = mu_p.pow(2), mu_t.pow(2), mu_p * mu_t
    var_p, var_t = torch.clamp(pp - mu_pp, min=0.0), torch.clamp(tt - mu_tt, min=0.0)
    c1, c2 = (SSIM_K1 * DATA_RANGE) ** 2, (SSIM_K2 * DATA_RANGE) ** 2
    upper, lower = 2 * (pt - mu_pt) + c2, var_p + var_t + c2
    ssim_map = ((2 * mu_pt + c1) * upper) / ((mu_pp + mu_tt + c1) * lower)
    pad = g.numel() // 2
    return ssim_map.mean(), (upper / lower)[..., pad:-pad, pad:-pad].mean()


def _sized_bchw(
    pred: torch.Tensor, target: torch.Tensor, metric: str, min_px: int, why: str = ""
) -> tuple[torch.Tensor, torch.Tensor]:
    """``_to_bchw``, and one ``MetricError`` line when the shorter side is under ``min_px``."""
    p, t = _to_bchw(pred, target)
    if min(p.shape[-2:]) < min_px:
        raise MetricError(f"{metric} needs images of at least {min_px}x{min_px} px{why}: found {list(pred.shape[:2])}")
    return p, t


def region_psnr_db(sq_err: torch.Tensor, sel: torch.Tensor | None = None) -> float | None:
    """PSNR (data range 1) of the pooled squared errors ``sq_err`` [H, W] over the pixels ``sel`` [H, W] (all if None).

    For diagnostics that split an image into regions (pixels with and without depth); a run's own image
    metrics are ``psnr_db`` and ``bench.metrics.protocol``. None for an empty region, ``inf`` for no error.
    """
    vals = sq_err if sel is None else sq_err[sel]
    if vals.numel() == 0:
        return None
    mse = float(vals.double().mean())
    return math.inf if mse == 0 else -10.0 * math.log10(mse)


def ssim(pred: torch.Tensor, target: torch.Tensor) -> float:
    """Mean SSIM with the module's convention (Gaussian 11 / 1.5, K1 0.01, K2 0.03, range 1)."""
    p, t = _sized_bchw(pred, target, "ssim", SSIM_KERNEL_PX)
    return float(_ssim_terms(p, t)[0])


def psnr_channel_mean_db(pred: torch.Tensor, target: torch.Tensor) -> float:
    """PSNR per colour channel, then the mean over channels: SplaTAM's ``calc_psnr(im, gt).mean()``.

    ``utils/slam_external.py:calc_psnr`` views the ``[C, H, W]`` image as ``C`` rows and takes one
    MSE per row, so its figure is the mean of three channel PSNRs, not the PSNR of the pooled MSE
    (``psnr_db``); on a gray image replicated to three channels the two are equal. A channel
    rendered exactly gives ``inf``, and so does the mean.
    """
    p, t = _to_bchw(pred, target)
    mse = ((p - t) ** 2).flatten(2).mean(-1)[0]  # [3]
    if bool((mse == 0).any()):
        return math.inf
    return float((-10.0 * torch.log10(mse / DATA_RANGE**2)).mean())


def ms_ssim(pred: torch.Tensor, target: torch.Tensor) -> float:
    """Multi-scale SSIM (5 scales, data range 1, the SSIM window above), in float64.

    The metric the paper's base system reports as "SSIM"; see the module docstring for its source
    and how torchmetrics' figure relates to SplaTAM's pytorch_msssim. Images whose shorter side is
    below ``MS_SSIM_MIN_PX`` have no fifth scale to score: a ``MetricError`` says so.
    """
    why = f" ({len(MS_SSIM_BETAS)} scales of an {SSIM_KERNEL_PX} px window)"
    p, t = _sized_bchw(pred, target, "ms_ssim", MS_SSIM_MIN_PX, why)
    terms = []  # per scale: the contrast-structure term, and SSIM itself at the coarsest
    for scale in range(len(MS_SSIM_BETAS)):
        sim, cs = _ssim_terms(p, t)
        terms.append(torch.relu(sim if scale == len(MS_SSIM_BETAS) - 1 else cs))  # normalize="relu"
        p, t = F.avg_pool2d(p, (2, 2)), F.avg_pool2d(t, (2, 2))  # an odd last row or column is dropped
    # torchmetrics builds the exponents in the default dtype (float32): the same rounded exponents keep its figures
    betas = torch.tensor(MS_SSIM_BETAS, dtype=torch.float32, device=p.device)
    return float(torch.prod(torch.stack(terms) ** betas))


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
