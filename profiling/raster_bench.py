"""Rasterizer forward+backward time and memory per backend, for a few (N Gaussians, resolution) points.

Speed and memory live here, not in timed tests. Two scenes, both in one process on the same
inputs: ``iso``, Gaussians back-projected from random pixels at 3-23 m with a round footprint of
~2 px, like the SLAM map's seeds; ``aniso``, the same centres with random rotations and per-axis
scales from 0.37x to 2.7x of that footprint. Times are the minimum over ``--repeats`` calls (the
machine's load only ever adds time). ``pairs`` counts contributing (pixel, Gaussian) pairs, the
work the compositing does, and ``ns_pair`` divides forward+backward time by it. The peak is the
live-tensor peak of ``bench.measure.memory.MemoryProbe`` over one forward+backward (CUDA: the allocator
peak), and bytes per Gaussian divide it by N.

``--old REV`` adds a row ``fused@REV``: the fused kernels of git revision REV (loaded from
``git show`` into a cache folder, compiled once), timed back to back with today's in the same
process; ``vs_old`` is the old kernels' time over today's (above 1: today's are faster), a ratio
that holds on a loaded machine where absolute times do not; ``vs_torch`` likewise is torch's time
over the row's.

    python profiling/raster_bench.py [--device cpu|cuda] [--repeats 5] [--backends torch,fused]
                                      [--scenes iso,aniso] [--points 20000x320x192,50000x640x384]
                                      [--old 641f0f0]
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import importlib.util
import os
import subprocess
import sys
import time
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # the checkout this file sits in, not whichever one is pip-installed

import bench.slam  # noqa: E402
from bench.measure.memory import MemoryProbe  # noqa: E402
from bench.slam.raster import rasterize  # noqa: E402

DEFAULT_POINTS = "2000x96x64,5000x160x96,20000x160x96,20000x320x192,50000x320x192,50000x640x384"


def scene(n: int, width: int, height: int, device: torch.device, seed: int = 0, kind: str = "iso"):
    g = torch.Generator().manual_seed(seed)
    u, v = torch.rand(n, generator=g) * width, torch.rand(n, generator=g) * height
    z = torch.rand(n, generator=g) * 20 + 3
    fx = 0.6 * width
    means = torch.stack([(u - width / 2) / fx * z, (v - height / 2) / fx * z, z], 1)
    log_scales = torch.log(z / fx * 2)[:, None].repeat(1, 3)
    quats = torch.tensor([1.0, 0, 0, 0]).repeat(n, 1)
    if kind == "aniso":
        log_scales = log_scales + torch.rand(n, 3, generator=g) * 2 - 1
        quats = torch.randn(n, 4, generator=g)
    params = [means, log_scales, quats, torch.full((n,), 0.8), torch.rand(n, 3, generator=g)]
    K = torch.tensor([[fx, 0, width / 2], [0, fx, height / 2], [0, 0, 1]])
    return [p.to(device).requires_grad_(True) for p in params], K.to(device)


def old_kernels(rev: str):
    """bench/slam/raster_fused.py as of ``rev``, as a module of its own (numba caches it beside the copy)."""
    shown = subprocess.run(
        ["git", "-C", str(ROOT), "show", f"{rev}:bench/slam/raster_fused.py"], capture_output=True, text=True
    )
    if shown.returncode != 0:
        sys.exit(
            f"--old {rev}: expected the kernels as one file, bench/slam/raster_fused.py, found none at {rev} "
            "(the package bench/slam/raster_fused/ cannot be loaded beside today's)"
        )
    src = shown.stdout
    folder = Path.home() / ".cache" / "pocketbench" / "old_kernels"
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"raster_fused_{hashlib.sha256(src.encode()).hexdigest()[:12]}.py"
    if not path.exists():
        path.write_text(src)
    spec = importlib.util.spec_from_file_location(path.stem, path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[path.stem] = mod
    layer = os.environ.get("NUMBA_THREADING_LAYER")
    spec.loader.exec_module(mod)
    if layer is None:  # revisions before d99440b pinned numba's layer at import: both are timed under today's
        import numba

        os.environ.pop("NUMBA_THREADING_LAYER", None)
        numba.config.THREADING_LAYER = "default"
    if not hasattr(mod, "in_view"):  # today's raster.py asks the kernels which Gaussians are in view
        from bench.slam.raster_fused import in_view

        mod.in_view = in_view
    return mod


@contextlib.contextmanager
def kernels(module):
    """Route ``rasterize(backend="fused")`` through ``module`` (None: today's kernels)."""
    today = bench.slam.raster_fused if hasattr(bench.slam, "raster_fused") else None
    if module is not None:
        bench.slam.raster_fused = module
    try:
        yield
    finally:
        if today is not None:
            bench.slam.raster_fused = today


def pairs(params, K, w: int, h: int) -> int:
    """Contributing (pixel, Gaussian) pairs of the view (the fused backend's hit counts)."""
    with torch.no_grad():
        out = rasterize(
            *params,
            torch.eye(4, device=K.device),
            K,
            w,
            h,
            stats=True,
            backend="fused" if K.device.type == "cpu" else "torch",
        )
    return int(out.hit_count.sum())


def measure(backend: str, params, K, w: int, h: int, device: torch.device, repeats: int):
    """(min forward ms, min backward ms, peak MiB of one forward+backward)."""
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
    return 1e3 * min(fwd), 1e3 * min(bwd), float("nan") if peak is None else peak


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--backends", default=None, help="comma list; default torch,fused on cpu, torch on cuda")
    ap.add_argument("--scenes", default="iso,aniso", help="comma list of iso, aniso")
    ap.add_argument("--points", default=DEFAULT_POINTS, help="comma list of NxWxH")
    ap.add_argument(
        "--torch-max-n",
        type=int,
        default=20_000,
        help="skip the torch backend above this N (it needs GiBs at 50k Gaussians)",
    )
    ap.add_argument("--old", default=None, metavar="REV", help="also time the fused kernels of git revision REV")
    args = ap.parse_args()
    device = torch.device(args.device)
    backends = (args.backends or ("torch,fused" if device.type == "cpu" else "torch")).split(",")
    points = [tuple(int(v) for v in p.split("x")) for p in args.points.split(",")]
    old = old_kernels(args.old) if args.old else None
    if old is not None and "fused" in backends:
        backends.append(f"fused@{args.old}")
    print(f"device={device} threads={torch.get_num_threads()} repeats={args.repeats} (times: min over repeats)")
    head = (
        f"{'scene':>5} {'N':>6} {'W x H':>8} {'backend':>14} {'fwd_ms':>7} {'bwd_ms':>7} {'pairs':>8} "
        f"{'ns_pair':>7} {'peak_mib':>8} {'B_per_g':>7} {'vs_torch':>8} {'vs_old':>6}"
    )
    print(head)
    for kind in args.scenes.split(","):
        for n, w, h in points:
            params, K = scene(n, w, h, device, kind=kind)
            n_pairs = pairs(params, K, w, h)
            res = {}
            for be in backends:
                if be == "torch" and n > args.torch_max_n:
                    continue
                with kernels(old if be.startswith("fused@") else None):
                    res[be] = measure(be.split("@")[0], params, K, w, h, device, args.repeats)
                f, b, peak = res[be]
                line = (
                    f"{kind:>5} {n:>6} {f'{w}x{h}':>8} {be:>14} {f:>7.1f} {b:>7.1f} {n_pairs:>8} "
                    f"{1e6 * (f + b) / max(n_pairs, 1):>7.1f} {peak:>8.1f} {peak * 2**20 / n:>7.0f}"
                )
                if be != "torch" and "torch" in res:
                    tf, tb, _ = res["torch"]
                    line += f" {(tf + tb) / (f + b):>8.2f}"
                elif be != "torch":
                    line += f" {'':>8}"
                if be.startswith("fused@") and "fused" in res:
                    line += f" {(f + b) / sum(res['fused'][:2]):>6.2f}"
                print(line, flush=True)
    if "fused" in backends:
        import numba

        print(f"numba threading layer: {numba.threading_layer()}")


if __name__ == "__main__":
    main()
