"""Rasterizer forward+backward time and memory per backend, for a few (N Gaussians, resolution) points.

Speed and memory live here, not in timed tests. Gaussians are back-projected from random pixels at
3-23 m with a footprint of ~2 px, like the SLAM map's seeds. Both backends run in one process on
the same scenes; the peak is the live-tensor peak of ``bench.measure.MemoryProbe`` over one
forward+backward (CUDA: the allocator peak), and bytes per Gaussian divide it by N.

    python benchmarks/raster_bench.py [--device cpu|cuda] [--repeats 5] [--backends torch,fused]
                                      [--points 20000x320x192,50000x640x384]
"""

from __future__ import annotations

import argparse
import time

import torch

from bench.measure import MemoryProbe
from bench.slam.raster import rasterize

DEFAULT_POINTS = "2000x96x64,5000x160x96,20000x160x96,20000x320x192,50000x320x192,50000x640x384"


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


def measure(backend: str, n: int, w: int, h: int, device: torch.device, repeats: int) -> tuple[float, float, float]:
    """(median forward ms, median backward ms, peak MiB of one forward+backward)."""
    params, K = scene(n, w, h, device)
    eye = torch.eye(4, device=device)

    def step() -> tuple[float, float]:
        t0 = time.perf_counter()
        out = rasterize(*params, eye, K, w, h, backend=backend)
        if device.type == "cuda":
            torch.cuda.synchronize()
        t1 = time.perf_counter()
        (out.color.sum() + out.depth.sum()).backward()
        if device.type == "cuda":
            torch.cuda.synchronize()
        for p in params:
            p.grad = None
        return t1 - t0, time.perf_counter() - t1

    step()  # warm-up (and, for fused, the numba compile or cache load)
    fwd, bwd = [], []
    for _ in range(repeats):
        f, b = step()
        fwd.append(f)
        bwd.append(b)
    probe = MemoryProbe(device)
    probe.start_window()
    step()
    mem = probe.end_window()
    probe.close()
    peak = mem["cuda_alloc_peak_mib"] if device.type == "cuda" else mem["torch_live_peak_mib"]
    fwd.sort()
    bwd.sort()
    return 1e3 * fwd[len(fwd) // 2], 1e3 * bwd[len(bwd) // 2], float("nan") if peak is None else peak


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--backends", default=None, help="comma list; default torch,fused on cpu, torch on cuda")
    ap.add_argument("--points", default=DEFAULT_POINTS, help="comma list of NxWxH")
    ap.add_argument("--torch-max-n", type=int, default=20_000,
                    help="skip the torch backend above this N (it needs GiBs at 50k Gaussians)")
    args = ap.parse_args()
    device = torch.device(args.device)
    backends = (args.backends or ("torch,fused" if device.type == "cpu" else "torch")).split(",")
    points = [tuple(int(v) for v in p.split("x")) for p in args.points.split(",")]
    print(f"device={device} threads={torch.get_num_threads()} repeats={args.repeats}")
    head = f"{'N':>7} {'W x H':>9} {'backend':>7} {'fwd_ms':>8} {'bwd_ms':>8} {'peak_mib':>9} {'B_per_gauss':>11}"
    print(head + f" {'speedup':>8} {'mem_ratio':>9}")
    for n, w, h in points:
        res = {}
        for be in backends:
            if be == "torch" and n > args.torch_max_n:
                continue
            res[be] = measure(be, n, w, h, device, args.repeats)
            f, b, peak = res[be]
            line = f"{n:>7} {f'{w}x{h}':>9} {be:>7} {f:>8.1f} {b:>8.1f} {peak:>9.1f} {peak * 2**20 / n:>11.0f}"
            if be != "torch" and "torch" in res:
                tf, tb, tp = res["torch"]
                line += f" {(tf + tb) / (f + b):>8.2f} {peak / tp:>9.3f}"
            print(line, flush=True)


if __name__ == "__main__":
    main()
