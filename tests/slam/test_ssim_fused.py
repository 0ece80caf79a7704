"""Mapping's D-SSIM term through the compiled kernels against torch's reference: value, gradient, edges, determinism."""

from __future__ import annotations

import pytest
import torch

from bench.slam.losses import dssim, ssim_map


def _pair(h: int, w: int, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    target = torch.rand(h, w, 3, generator=g)
    pred = (target + 0.1 * torch.randn(h, w, 3, generator=g)).clamp(0, 1)
    return pred, target


def _loss_and_grad(pred, target, fused, weight=None):
    p = pred.clone().requires_grad_(True)
    if weight is None:
        loss = dssim(p, target, fused)
    else:  # an upstream gradient that is not uniform over the map, through the fused map itself
        from bench.slam.losses import C1, C2, _window
        from bench.slam.raster_fused.ssim import ssim_map_fused

        x, y = p.permute(2, 0, 1), target.permute(2, 0, 1)
        s = ssim_map_fused(x, y, _window(p.device), C1, C2).mean(0) if fused else ssim_map(p, target)
        loss = (s * weight).sum()
    loss.backward()
    assert p.grad is not None
    return loss.detach(), p.grad


@pytest.mark.parametrize("h,w", [(40, 56), (7, 5), (11, 30), (96, 13)])  # smaller than the window, too
def test_value_and_gradient_match_torch(h, w):
    pred, target = _pair(h, w)
    ref_loss, ref_grad = _loss_and_grad(pred, target, fused=False)
    loss, grad = _loss_and_grad(pred, target, fused=True)
    torch.testing.assert_close(loss, ref_loss, atol=1e-6, rtol=1e-5)
    # the taps are summed in another order: float32 rounding of the gradient, nothing more
    torch.testing.assert_close(grad, ref_grad, atol=1e-5 * float(ref_grad.abs().max()), rtol=1e-4)


def test_map_and_weighted_gradient_match_torch():
    pred, target = _pair(33, 47, seed=3)
    from bench.slam.losses import C1, C2, _window
    from bench.slam.raster_fused.ssim import ssim_map_fused

    s = ssim_map_fused(pred.permute(2, 0, 1), target.permute(2, 0, 1), _window(pred.device), C1, C2).mean(0)
    torch.testing.assert_close(s, ssim_map(pred, target), atol=2e-6, rtol=1e-5)
    weight = torch.rand(33, 47, generator=torch.Generator().manual_seed(4))
    _, ref_grad = _loss_and_grad(pred, target, False, weight)
    _, grad = _loss_and_grad(pred, target, True, weight)
    torch.testing.assert_close(grad, ref_grad, atol=1e-5 * float(ref_grad.abs().max()), rtol=1e-4)


def test_identical_images_give_zero_and_only_the_prediction_gets_a_gradient():
    pred, target = _pair(20, 24)
    assert float(dssim(target, target, True)) == pytest.approx(0.0, abs=1e-6)
    t = target.clone().requires_grad_(True)
    p = pred.clone().requires_grad_(True)
    dssim(p, t.detach(), True).backward()
    assert t.grad is None and p.grad is not None and p.grad.abs().sum() > 0


def test_bit_identical_run_to_run_and_across_threads():
    pred, target = _pair(120, 100, seed=5)  # 36,000 values: above the kernels' one-thread threshold
    first = _loss_and_grad(pred, target, True)
    threads = torch.get_num_threads()
    try:
        for n_threads in (1, 2):
            torch.set_num_threads(n_threads)
            again = _loss_and_grad(pred, target, True)
            assert torch.equal(first[0], again[0]) and torch.equal(first[1], again[1])
    finally:
        torch.set_num_threads(threads)
