"""Evaluation protocols by hand: the masks, masked pixels counting as perfect, MS-SSIM, per-channel PSNR."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from torchmetrics.functional.image import multiscale_structural_similarity_index_measure

from bench.errors import MetricError
from bench.metrics import frame_metrics, image_metrics, mean_metrics, ms_ssim, path_length_ratio, protocol_mask
from bench.metrics.image import MS_SSIM_MIN_PX, psnr_channel_mean_db, psnr_db, ssim
from bench.metrics.trajectory import Trajectory


def pair(h: int = 180, w: int = 200) -> tuple[torch.Tensor, torch.Tensor]:
    """A smooth colour image [h, w, 3] and a render of it with a fine, deterministic error pattern."""
    y = torch.arange(h, dtype=torch.float64)[:, None, None]
    x = torch.arange(w, dtype=torch.float64)[None, :, None]
    c = torch.arange(3, dtype=torch.float64)[None, None, :]
    target = 0.5 + 0.4 * torch.sin(x / 7 + c) * torch.cos(y / 11)
    pred = (target + 0.05 * torch.sin(1.3 * x + 0.7 * y + c)).clamp(0, 1)
    return pred, target


def lower_rows(h: int, w: int, first: int) -> torch.Tensor:
    """[h, w] bool: rows from ``first`` on."""
    return (torch.arange(h)[:, None] >= first).expand(h, w)


# ------------------------------------------------------------------------------------------- MS-SSIM


def test_ms_ssim_is_torchmetrics_with_splatams_arguments() -> None:
    pred, target = pair()
    direct = multiscale_structural_similarity_index_measure(
        pred.permute(2, 0, 1)[None], target.permute(2, 0, 1)[None], data_range=1.0
    )  # defaults: 11 px, 1.5, relu
    assert ms_ssim(pred, target) == pytest.approx(float(direct), abs=1e-12)  # the separable window: rounding apart
    assert ms_ssim(target, target) == 1.0
    assert ms_ssim(pred.float(), target.float()) == pytest.approx(ms_ssim(pred, target), abs=1e-6)  # float64 inside


@pytest.mark.parametrize(("masked", "splatam_value"), [(False, 0.97627898718696), (True, 0.9847886413676751)])
def test_ms_ssim_agrees_with_splatams_library(masked: bool, splatam_value: float) -> None:
    """Known answers of pytorch_msssim 1.0.0 as SplaTAM's eval calls it (``ms_ssim(X, Y, data_range=1.0,
    size_average=True)``, float64) on these images; torchmetrics pools channels and borders differently."""
    pred, target = pair()
    if masked:
        keep = lower_rows(180, 200, 60)[..., None].double()
        pred, target = pred * keep, target * keep
    assert ms_ssim(pred, target) == pytest.approx(splatam_value, abs=1e-5)


def test_ms_ssim_says_the_smallest_image_it_scores() -> None:
    pred, target = pair(MS_SSIM_MIN_PX, 300)
    assert 0 < ms_ssim(pred, target) < 1  # 176 px: the coarsest scale still holds the window
    with pytest.raises(MetricError, match=r"ms_ssim needs images of at least 176x176 px .* found \[175, 300\]"):
        ms_ssim(*pair(MS_SSIM_MIN_PX - 1, 300))


# ------------------------------------------------------------------------------------------- masks


def test_full_scores_every_pixel() -> None:
    assert protocol_mask("full", torch.zeros(4, 5), torch.zeros(4, 5), 0.1, 30.0) is None


def test_splatam_mask_is_the_depth_range_both_ends_excluded() -> None:
    depth = torch.tensor([[0.0, 0.1, 0.1001, 5.0], [29.99, 30.0, 45.0, math.nan]])  # [2, 4] metres
    expected = torch.tensor([[False, False, True, True], [True, False, False, False]])
    assert torch.equal(protocol_mask("splatam", depth, None, 0.1, 30.0), expected)
    # no range (the base default): every pixel with depth; 0 is the loader's "no depth" whatever the range
    anywhere = torch.tensor([[False, True, True, True], [True, True, True, False]])
    assert torch.equal(protocol_mask("splatam", depth, None, 0.0, None), anywhere)


def test_released_mask_is_the_silhouette_above_one_half() -> None:
    sil = torch.tensor([[0.0, 0.5, 0.5001, 1.0]])
    assert protocol_mask("released", torch.zeros(1, 4), sil).tolist() == [[False, False, True, True]]
    assert protocol_mask("released", None, sil) is not None  # no depth needed


@pytest.mark.parametrize(
    ("args", "says"),
    [
        (("bogus", torch.ones(2, 2), None), "eval.protocol: expected one of full, splatam, released, found 'bogus'"),
        (("splatam", None, torch.ones(2, 2)), "protocol splatam: expected depth [h, w], found None"),
        (("splatam", torch.ones(2, 2), None, 5.0, 1.0), "expected depth_near_m < depth_far_m, found 5.0 and 1.0"),
        (("released", torch.ones(2, 2), torch.ones(2, 2, 1)), "protocol released: expected a silhouette [h, w]"),
    ],
)
def test_mask_refuses_bad_input_in_one_line(args: tuple, says: str) -> None:
    with pytest.raises(MetricError) as err:
        protocol_mask(*args)
    assert says in str(err.value) and "\n" not in str(err.value)


# ------------------------------------------------------------------------------------------- metrics


@pytest.mark.parametrize("protocol", ["splatam", "released"])
def test_masked_pixels_count_as_perfect(protocol: str) -> None:
    """Garbage where the mask is off changes nothing: both images are zero there."""
    pred, target = pair()
    keep = lower_rows(180, 200, 60)
    wild = torch.where(keep[..., None], target, 1.0 - target)  # wrong everywhere the mask drops
    res = frame_metrics(protocol, wild, target, keep)
    assert res["psnr_db"] == math.inf and res["ssim"] == 1.0 and res["ms_ssim"] == 1.0
    assert res["mask_frac"] == pytest.approx(120 / 180)
    unmasked = frame_metrics("full", wild, target, None)
    assert unmasked["psnr_db"] < 15 and unmasked["mask_frac"] is None


def test_masked_psnr_divides_by_the_whole_image() -> None:
    """An error of 0.1 on the kept half: MSE 0.01 x 1/2 per channel, so 10 log10(1 / 0.005) dB."""
    target = torch.full((16, 20, 3), 0.5, dtype=torch.float64)
    pred = target + 0.1
    keep = lower_rows(16, 20, 8)
    res = frame_metrics("splatam", pred, target, keep)
    assert res["psnr_db"] == pytest.approx(10 * math.log10(1 / 0.005), abs=1e-9)  # 23.01 dB; 20 dB unmasked
    assert res["ms_ssim"] is None and res["ssim"] is not None  # 16x20 px has no fifth scale; the rest still come


def test_splatam_psnr_is_the_mean_of_channel_psnrs() -> None:
    """calc_psnr(...).mean(): per-channel PSNR, then the mean; the pooled MSE gives a different figure."""
    target = torch.full((6, 6, 3), 0.5, dtype=torch.float64)
    pred = target + torch.tensor([0.1, 0.01, 0.001], dtype=torch.float64)  # channel PSNRs 20, 40, 60 dB
    assert psnr_channel_mean_db(pred, target) == pytest.approx(40.0, abs=1e-6)
    assert psnr_db(pred, target) == pytest.approx(-10 * math.log10((0.01 + 1e-4 + 1e-6) / 3), abs=1e-4)  # 24.7 dB
    gray = target + 0.1
    assert psnr_channel_mean_db(gray, target) == pytest.approx(psnr_db(gray, target), abs=1e-5)


def test_lpips_sees_the_masked_images() -> None:
    seen = []
    pred, target = pair()
    keep = lower_rows(180, 200, 90)

    def lpips(p: torch.Tensor, t: torch.Tensor) -> float:
        seen.append((p, t))
        return 0.25

    assert frame_metrics("released", pred, target, keep, lpips)["lpips"] == 0.25
    p, t = seen[0]
    assert torch.equal(p[:90], torch.zeros(90, 200, 3)) and torch.equal(t[:90], torch.zeros(90, 200, 3))
    assert torch.equal(p[90:], pred[90:])


def test_full_protocol_is_todays_image_metrics_to_the_bit() -> None:
    frames = [pair(180 + 4 * k, 200) for k in range(3)]
    lpips = lambda p, t: float((p - t).abs().mean())  # noqa: E731 - any callable with LPIPS' signature
    ours = mean_metrics([frame_metrics("full", p, t, None, lpips) for p, t in frames])
    before = image_metrics([p for p, _ in frames], [t for _, t in frames], lpips=lpips)
    for key in ("psnr_db", "ssim", "lpips", "num_frames"):
        assert ours[key] == before[key], key
    assert ours["ms_ssim"] == sum(ms_ssim(p, t) for p, t in frames) / 3 and ours["mask_frac"] is None
    assert frame_metrics("full", *frames[0], None)["ssim"] == ssim(*frames[0])


@pytest.mark.parametrize(
    ("protocol", "mask", "says"),
    [
        ("full", torch.ones(180, 200, dtype=torch.bool), "protocol full: expected no mask"),
        ("splatam", None, "protocol splatam: expected a bool mask of [180, 200], found None"),
        (
            "released",
            torch.ones(180, 200),
            "protocol released: expected a bool mask of [180, 200], found torch.float32",
        ),
        ("bogus", None, "eval.protocol: expected one of full, splatam, released"),
    ],
)
def test_frame_metrics_refuses_a_mask_that_does_not_fit(protocol: str, mask: torch.Tensor | None, says: str) -> None:
    with pytest.raises(MetricError, match=None) as err:
        frame_metrics(protocol, *pair(), mask)
    assert says in str(err.value)


def test_mean_metrics_skips_frames_without_a_value() -> None:
    res = mean_metrics(
        [
            {"psnr_db": 20.0, "ssim": 0.5, "ms_ssim": None, "lpips": None, "mask_frac": 0.5},
            {"psnr_db": 30.0, "ssim": 0.7, "ms_ssim": None, "lpips": None, "mask_frac": 0.7},
        ]
    )
    assert res == {
        "psnr_db": 25.0,
        "ssim": pytest.approx(0.6),
        "ms_ssim": None,
        "lpips": None,
        "mask_frac": pytest.approx(0.6),
        "num_frames": 2,
    }
    with pytest.raises(MetricError, match="no frames to evaluate"):
        mean_metrics([])


# ------------------------------------------------------------------------------------------- path length


def _line(scale: float, n: int = 20) -> Trajectory:
    ts = np.arange(n) * 0.1
    pos = np.column_stack([np.zeros(n), np.zeros(n), scale * np.arange(n) * 1.2])  # a straight drive, 1.2 m/frame
    return Trajectory(ts, pos, np.tile([1.0, 0.0, 0.0, 0.0], (n, 1)))


def test_path_length_ratio_is_estimated_over_true_length() -> None:
    assert path_length_ratio(_line(0.88), _line(1.0)) == pytest.approx(0.88)  # 12% short: scale lost
    assert path_length_ratio(_line(1.0), _line(1.0)) == 1.0
    assert path_length_ratio(_line(1.0), _line(0.0)) is None  # a camera that stood still has no ratio


def test_window_path_ratios_show_where_a_drift_starts() -> None:
    from bench.errors import MetricError
    from bench.metrics.trajectory import window_path_ratios

    gt = np.column_stack([np.zeros(7), np.zeros(7), np.arange(7) * 1.0])  # [7, 3] 1 m a frame
    est = gt.copy()
    est[4:, 2] = 3.0 + (np.arange(4, 7) - 3) * 0.5  # on scale to frame 3, then half the speed
    assert window_path_ratios(est, gt, 0)["path_length_ratio"] == pytest.approx(4.5 / 6)
    late = window_path_ratios(est, gt, 3)  # the window frames 3-6: where the drift is
    assert late["path_length_m"] == pytest.approx(3.0) and late["path_length_ratio"] == pytest.approx(0.5)
    assert late["path_length_ratio_prefix"] == pytest.approx(4.5 / 6)
    assert window_path_ratios(est[:4], gt[:4], 0)["path_length_ratio_prefix"] == pytest.approx(1.0)
    assert window_path_ratios(est[:1], gt[:1], 0) == {
        "path_length_m": 0.0, "path_length_ratio": None, "path_length_ratio_prefix": None
    }  # fmt: skip
    with pytest.raises(MetricError, match="expected a start"):
        window_path_ratios(est, gt, 7)
    with pytest.raises(MetricError, match=r"\[N, 3\]"):
        window_path_ratios(est[:, :2], gt[:, :2], 0)
