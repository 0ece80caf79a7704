"""Mapping's D-SSIM term, forward and backward: torch's reference against the compiled kernels, call by call.

Both run on the same pair of images (a random target and a noisy copy as the render, the size of a
mapping keyframe), alternating call by call in one process, timed in CPU time of the thread: each
pair of calls sees the same load, so the median of the per-pair ratios (torch / fused; above 1: the
kernels are faster) holds on a machine shared with other jobs, where absolute times do not. It also
says how far the kernels' value and gradient are from the reference's.

    python profiling/ssim_ab.py [--size 613x185] [--calls 21] [--threads 1]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # the checkout this file sits in, not whichever one is pip-installed

from bench.slam.losses import dssim  # noqa: E402


def step(pred: torch.Tensor, target: torch.Tensor, fused: bool) -> tuple[torch.Tensor, torch.Tensor]:
    """(D-SSIM, its gradient [H, W, 3]) of ``pred`` against ``target``."""
    p = pred.clone().requires_grad_(True)
    loss = dssim(p, target, fused)
    loss.backward()
    assert p.grad is not None
    return loss.detach(), p.grad


def cpu_ms(fn, *args) -> float:
    t0 = time.thread_time()
    fn(*args)
    return 1e3 * (time.thread_time() - t0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="613x185", help="WxH of the images (default: KITTI at 1/2)")
    ap.add_argument("--calls", type=int, default=21, help="timed calls of each")
    ap.add_argument("--threads", type=int, default=1, help="torch's (and so the kernels') thread count")
    args = ap.parse_args()
    w, h = (int(v) for v in args.size.split("x"))
    torch.set_num_threads(args.threads)
    torch.set_flush_denormal(True)  # as the SLAM system runs
    g = torch.Generator().manual_seed(0)
    target = torch.rand(h, w, 3, generator=g)
    pred = (target + 0.1 * torch.randn(h, w, 3, generator=g)).clamp(0, 1)
    (ref_loss, ref_grad), (loss, grad) = step(pred, target, False), step(pred, target, True)
    again = step(pred, target, True)
    scale = float(ref_grad.abs().max())
    rel = (grad - ref_grad).abs() / ref_grad.abs().clamp_min(1e-30)
    print(
        f"{w}x{h}, threads={args.threads}: D-SSIM torch {float(ref_loss):.9g}, fused {float(loss):.9g}; gradient "
        f"max |fused - torch| / max |torch| = {float((grad - ref_grad).abs().max()) / scale:.1e}, median relative "
        f"{float(rel.median()):.1e}; fused run to run bit for bit: "
        f"{torch.equal(again[0], loss) and torch.equal(again[1], grad)}"
    )
    ratios, ref_ms, fused_ms = [], [], []
    for _ in range(args.calls):
        a = cpu_ms(step, pred, target, False)
        b = cpu_ms(step, pred, target, True)
        ratios.append(a / b)
        ref_ms.append(a)
        fused_ms.append(b)
    print(
        f"forward + backward, CPU ms (median of {args.calls}): torch {statistics.median(ref_ms):.2f}, fused "
        f"{statistics.median(fused_ms):.2f}; ratio torch / fused x{statistics.median(ratios):.2f} "
        f"(pairs from x{min(ratios):.2f} to x{max(ratios):.2f})"
    )


if __name__ == "__main__":
    main()
