"""Rasterizer forward+backward time and memory for a few (N Gaussians, resolution) points.

Speed lives here, not in timed tests. Gaussians are back-projected from random pixels at
3-23 m with a footprint of ~2 px, like the SLAM map's seeds.

    python benchmarks/raster_bench.py [--device cpu|cuda] [--repeats 5]
"""

from __future__ import annotations

import argparse
import time

import torch

from bench.measure import MemoryProbe
from bench.slam.raster import rasterize


def scene(n: int, width: int, height: int, device: torch.device, seed: int = 0):
    g = torch.Generator().manual_seed(seed)
    u, v = torch.rand(n, generator=g) * width, torch.rand(n, generator=g) * height
    z = torch.rand(n, generator=g) * 20 + 3
    fx = 0.6 * width
    means = torch.stack([(u - width / 2) / fx * z, (v - height / 2) / fx * z, z], 1)
    params = [
        means,
        torch.log(z / fx * 2)[:, None].repeat(1, 3),
        torch.tensor([1.0, 0, 0, 0]).repeat(n, 1),
        torch.full((n,), 0.8),
        torch.rand(n, 3, generator=g),
    ]
    K = torch.tensor([[fx, 0, width / 2], [0, fx, height / 2], [0, 0, 1]])
    return [p.to(device).requires_grad_(True) for p in params], K.to(device)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    device = torch.device(args.device)
    points = [(2_000, 96, 64), (5_000, 160, 96), (20_000, 160, 96), (20_000, 320, 192), (50_000, 320, 192)]
    print(f"device={device} threads={torch.get_num_threads()}")
    print(f"{'N':>7} {'W x H':>9} {'fwd_ms':>8} {'bwd_ms':>8} {'peak_mib':>9}")
    for n, w, h in points:
        params, K = scene(n, w, h, device)
        probe = MemoryProbe(device)
        fwd, bwd = [], []
        probe.start_window()
        for i in range(args.repeats + 1):
            t0 = time.perf_counter()
            out = rasterize(*params, torch.eye(4, device=device), K, w, h)
            if device.type == "cuda":
                torch.cuda.synchronize()
            t1 = time.perf_counter()
            (out.color.sum() + out.depth.sum()).backward()
            if device.type == "cuda":
                torch.cuda.synchronize()
            t2 = time.perf_counter()
            if i:  # the first call is warm-up
                fwd.append(t1 - t0)
                bwd.append(t2 - t1)
        mem = probe.end_window()
        probe.close()
        peak = mem["cuda_alloc_peak_mib"] if device.type == "cuda" else mem["torch_live_peak_mib"]
        fwd.sort()
        bwd.sort()
        print(f"{n:>7} {f'{w}x{h}':>9} {1e3 * fwd[len(fwd) // 2]:>8.1f} {1e3 * bwd[len(bwd) // 2]:>8.1f} "
              f"{peak if peak is not None else float('nan'):>9.1f}")


if __name__ == "__main__":
    main()
