"""PSNR/SSIM: cross-checks against closed forms and scikit-image, and the batch helper."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from skimage.metrics import structural_similarity as sk_ssim
from torchmetrics.functional.image import structural_similarity_index_measure as tm_ssim

from bench.errors import MetricError
from bench.metrics.image import image_metrics, psnr_db, ssim


def _image(h: int, w: int, seed: int) -> torch.Tensor:
    """Smooth structure plus noise, so SSIM is neither ~0 nor ~1."""
    g = torch.Generator().manual_seed(seed)
    yy, xx = torch.meshgrid(torch.linspace(0, 1, h), torch.linspace(0, 1, w), indexing="ij")
    base = torch.stack([torch.sin(6 * xx + c) * torch.cos(4 * yy - c) * 0.4 + 0.5 for c in range(3)], -1)
    return (base + 0.05 * torch.randn(h, w, 3, generator=g)).clamp(0, 1)  # [H, W, 3]


def _noisy(img: torch.Tensor, sigma: float, seed: int) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return (img + sigma * torch.randn(img.shape, generator=g)).clamp(0, 1)


def _skimage(pred: torch.Tensor, target: torch.Tensor, full: bool = False):
    return sk_ssim(
        pred.double().numpy(),
        target.double().numpy(),
        gaussian_weights=True,
        sigma=1.5,
        use_sample_covariance=False,
        data_range=1.0,
        channel_axis=-1,
        full=full,
    )


def test_psnr_closed_form() -> None:
    target = torch.full((16, 20, 3), 0.5)
    pred = target + 0.1  # MSE = 0.01 -> 20 dB
    assert psnr_db(pred, target) == pytest.approx(20.0, abs=1e-5)
    assert psnr_db(target, target) == math.inf


@pytest.mark.parametrize(("h", "w"), [(120, 160), (240, 320)])
@pytest.mark.parametrize("noise", [0.02, 0.1, 0.3])
def test_ssim_matches_skimage_whole_image(h: int, w: int, noise: float) -> None:
    """Means differ only by border handling (reflect-pad vs 5 px crop): measured <= 6e-4 here."""
    target = _image(h, w, seed=1)
    pred = _noisy(target, noise, seed=2)
    assert ssim(pred, target) == pytest.approx(_skimage(pred, target), abs=1.5e-3)


def test_ssim_maps_identical_on_interior() -> None:
    """With the 5 px border cropped, torchmetrics' map equals scikit-image's to float64 precision."""
    target = _image(64, 80, seed=3).double()
    pred = _noisy(target, 0.1, seed=4).double()
    _, full = tm_ssim(
        pred.permute(2, 0, 1)[None],
        target.permute(2, 0, 1)[None],
        gaussian_kernel=True,
        sigma=1.5,
        kernel_size=11,
        data_range=1.0,
        return_full_image=True,
    )
    _, sk_map = _skimage(pred, target, full=True)
    ours = full[0].permute(1, 2, 0).numpy()[5:-5, 5:-5]
    np.testing.assert_allclose(ours, sk_map[5:-5, 5:-5], atol=1e-10)
    assert abs(ssim(pred, target) - _skimage(pred, target)) < 5e-3  # small image: larger border share


def test_ssim_bounds_and_dtype_independence() -> None:
    target = _image(48, 48, seed=5)
    assert ssim(target, target) == pytest.approx(1.0, abs=1e-12)
    pred = _noisy(target, 0.1, seed=6)
    assert ssim(pred, target) == pytest.approx(ssim(pred.double(), target.double()), abs=1e-12)
    assert ssim(pred, target) == pytest.approx(ssim(target, pred), abs=1e-12)


def test_image_metrics_averages_per_frame() -> None:
    targets = torch.stack([_image(40, 50, seed=s) for s in range(3)])  # [3, H, W, 3]
    preds = torch.stack([_noisy(t, 0.05 * (i + 1), seed=10 + i) for i, t in enumerate(targets)])
    res = image_metrics(preds, targets)
    assert res["num_frames"] == 3 and res["lpips"] is None
    pairs = list(zip(preds, targets, strict=True))
    assert res["psnr_db"] == pytest.approx(np.mean([psnr_db(p, t) for p, t in pairs]))
    assert res["ssim"] == pytest.approx(np.mean([ssim(p, t) for p, t in pairs]))
    res_list = image_metrics(list(preds), list(targets))
    assert res_list["psnr_db"] == pytest.approx(res["psnr_db"])


def test_image_metrics_passes_lpips_through() -> None:
    t = _image(32, 32, seed=0)
    res = image_metrics([t], [t], lpips=lambda p, q: 0.25)  # any callable with LPIPS' signature
    assert res["lpips"] == 0.25


@pytest.mark.parametrize(
    ("pred", "target", "pattern"),
    [
        (torch.zeros(8, 8, 3), torch.zeros(8, 9, 3), "one size"),
        (torch.zeros(8, 8), torch.zeros(8, 8), r"\[h, w, 3\]"),
        (torch.zeros(8, 8, 3, dtype=torch.uint8), torch.zeros(8, 8, 3, dtype=torch.uint8), "must be float"),
        (torch.full((8, 8, 3), float("nan")), torch.zeros(8, 8, 3), "must be finite"),
    ],
)
def test_bad_inputs(pred: torch.Tensor, target: torch.Tensor, pattern: str) -> None:
    with pytest.raises(MetricError, match=pattern):
        psnr_db(pred, target)


def test_ssim_too_small_and_frame_count() -> None:
    with pytest.raises(MetricError, match="at least 11x11"):
        ssim(torch.zeros(8, 8, 3), torch.zeros(8, 8, 3))
    with pytest.raises(MetricError, match="frame counts differ"):
        image_metrics([torch.zeros(16, 16, 3)], [])


def test_region_psnr_is_over_the_selected_pixels_only():
    from bench.metrics.image import region_psnr_db

    sq = torch.full((4, 6), 0.01)  # an error of 0.1 everywhere ...
    sq[:, :3] = 0.0001  # ... and 0.01 on the left half
    left = torch.zeros(4, 6, dtype=torch.bool)
    left[:, :3] = True
    assert region_psnr_db(sq, left) == pytest.approx(40.0)
    assert region_psnr_db(sq, ~left) == pytest.approx(20.0)
    assert region_psnr_db(sq) == pytest.approx(-10 * math.log10(0.00505))
    assert region_psnr_db(sq, torch.zeros_like(left)) is None
    assert region_psnr_db(torch.zeros(2, 2)) == math.inf


@pytest.mark.parametrize(("h", "w", "noise"), [(176, 176, 0.02), (185, 243, 0.3), (370, 613, 0.02), (181, 181, 0.6)])
def test_separable_window_gives_torchmetrics_figures(h: int, w: int, noise: float) -> None:
    """SSIM and MS-SSIM through the separable window equal torchmetrics' own functions (full 2D window) to
    float64 rounding, odd sides (halved with a dropped row or column) and a dissimilar pair included."""
    from torchmetrics.functional.image import multiscale_structural_similarity_index_measure as tm_ms_ssim

    from bench.metrics.image import MS_SSIM_BETAS, WINDOW, ms_ssim

    target = _image(h, w, seed=3)
    pred = _noisy(target, noise, seed=4)
    p, t = (x.double().permute(2, 0, 1)[None] for x in (pred, target))  # [1, 3, H, W]
    assert ssim(pred, target) == pytest.approx(float(tm_ssim(p, t, **WINDOW)), abs=1e-12)
    expected = float(tm_ms_ssim(p, t, **WINDOW, betas=MS_SSIM_BETAS, normalize="relu"))
    assert ms_ssim(pred, target) == pytest.approx(expected, abs=1e-12)
