"""Time the image metrics of one frame: the harness's SSIM and MS-SSIM (separable window) against torchmetrics'
own functions (full 2D window) on the same pair, with the figures of both printed.

    python profiling/score_bench.py [--size 370x1226] [--repeats 3] [--threads 1]
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable

import torch
from torchmetrics.functional.image import (
    multiscale_structural_similarity_index_measure,
    structural_similarity_index_measure,
)

from bench.metrics.image import MS_SSIM_BETAS, WINDOW, ms_ssim, ssim


def timed(fn: Callable[[], float], repeats: int) -> tuple[float, float]:
    """(median seconds, the value) over ``repeats`` calls."""
    times, value = [], 0.0
    for _ in range(repeats):
        t0 = time.perf_counter()
        value = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), value


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="370x1226", help="HxW of the frame (default: KITTI's)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    h, w = (int(v) for v in args.size.split("x"))
    g = torch.Generator().manual_seed(0)
    target = torch.rand(h, w, 3, generator=g)  # [H, W, 3]
    pred = (target + 0.05 * torch.randn(h, w, 3, generator=g)).clamp(0, 1)
    p, t = (x.double().permute(2, 0, 1)[None] for x in (pred, target))  # [1, 3, H, W] as the harness scored before

    def tm_ms() -> float:
        return float(
            multiscale_structural_similarity_index_measure(p, t, **WINDOW, betas=MS_SSIM_BETAS, normalize="relu")
        )

    rows = [
        ("ssim", lambda: float(structural_similarity_index_measure(p, t, **WINDOW)), lambda: ssim(pred, target)),
        ("ms_ssim", tm_ms, lambda: ms_ssim(pred, target)),
    ]
    print(f"{h}x{w}, {args.threads} thread(s), median of {args.repeats}")
    print("metric   torchmetrics_s  harness_s  ratio  torchmetrics_value    harness_value")
    for name, old, new in rows:
        (t_old, v_old), (t_new, v_new) = timed(old, args.repeats), timed(new, args.repeats)
        print(f"{name:8s} {t_old:14.3f} {t_new:10.3f} {t_old / t_new:6.1f}x  {v_old:.15f}  {v_new:.15f}")


if __name__ == "__main__":
    main()
