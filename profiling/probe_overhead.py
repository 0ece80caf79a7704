"""Wall-time overhead of ``bench.measure.memory.MemoryProbe`` on a workload, with and without the probe.

A workload is any function ``workload(window) -> None`` that wraps each keyframe window in
``with window(): ...``; the script passes a no-op window for the baseline and one that calls
``start_window``/``end_window`` for the probed run, so the per-window cost is included. Runs are
interleaved (base, probe, base, probe, ...) and medians compared, to cancel slow drift on a shared
machine; the ratio of the fastest runs is printed too (interference only ever adds time). A fresh
probe is made for each probed run, outside the timed part, so the baseline runs without one.

    python profiling/probe_overhead.py                       # toy Gaussian optimisation, CPU
    python profiling/probe_overhead.py --method dispatch-mode
    python profiling/probe_overhead.py --workload mypkg.mod:func --device cuda
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import importlib
import statistics
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bench.measure.memory import MemoryProbe  # noqa: E402

Window = Callable[[], AbstractContextManager[None]]
Workload = Callable[[Window], None]


def gaussian_toy(window: Window, windows: int = 4, steps_per_window: int = 5, n: int = 100_000) -> None:
    """Adam on 100k toy Gaussians: ~170 aten ops of [n, 3]-sized tensors per step, with backward."""
    g = torch.Generator().manual_seed(0)
    params = {
        name: torch.randn(n, dim, generator=g).requires_grad_()
        for name, dim in (("means", 3), ("log_scales", 3), ("quats", 4), ("colors", 3), ("opacity", 1))
    }
    opt = torch.optim.Adam(params.values(), lr=1e-3)
    rot = torch.randn(3, 3, generator=g)  # [3, 3]
    trans = torch.randn(3, generator=g)  # [3]
    target = torch.rand(n, 3, generator=g)  # [n, 3]
    for _ in range(windows):
        with window():
            for _ in range(steps_per_window):
                opt.zero_grad(set_to_none=True)
                q = torch.nn.functional.normalize(params["quats"], dim=-1)  # [n, 4]
                s = params["log_scales"].exp()  # [n, 3]
                cam = params["means"] @ rot.T + trans  # [n, 3]
                z = cam[:, 2:3].abs() + 1.0  # [n, 1]
                uv = cam[:, :2] / z  # [n, 2]
                radius = (s * q[:, :3]).norm(dim=-1, keepdim=True) / z  # [n, 1]
                alpha = torch.sigmoid(params["opacity"]) * torch.exp(-0.5 * (uv**2).sum(-1, keepdim=True))
                rgb = torch.sigmoid(params["colors"]) * alpha + 0.01 * radius  # [n, 3]
                loss = (rgb - target).abs().mean() + 0.1 * ((1 - alpha) ** 2).mean()
                loss.backward()
                opt.step()


@contextlib.contextmanager
def _no_window() -> Iterator[None]:
    yield


def measure_overhead(
    workload: Workload, device: torch.device, reps: int = 7, torch_live: bool = True, method: str = "auto"
) -> dict[str, float | str]:
    """Median seconds of ``workload`` without and with a probe, and the overhead in percent."""
    peaks: list[dict] = []
    probe: MemoryProbe | None = None

    @contextlib.contextmanager
    def probed_window() -> Iterator[None]:
        assert probe is not None
        probe.start_window()
        try:
            yield
        finally:
            peaks.append(probe.end_window())

    def timed(window: Window) -> float:
        if device.type == "cuda":
            torch.cuda.synchronize(device)
        t0 = time.perf_counter()
        workload(window)
        if device.type == "cuda":
            torch.cuda.synchronize(device)
        return time.perf_counter() - t0

    workload(_no_window)  # warm-up: allocator, thread pools, lazy init
    base_s, probed_s = [], []
    methods = ("", "")
    for _ in range(reps):
        base_s.append(timed(_no_window))  # no probe exists during the baseline
        probe = MemoryProbe(device, torch_live=torch_live, live_method=method)
        try:
            probed_s.append(timed(probed_window))
        finally:
            probe.close()
        methods = (probe.rss_method, probe.torch_live_method)
    base, probed = statistics.median(base_s), statistics.median(probed_s)
    last = peaks[-1] if peaks else {}
    return {
        "base_s": base,
        "probed_s": probed,
        "overhead_pct": 100.0 * (probed / base - 1.0),
        "overhead_min_pct": 100.0 * (min(probed_s) / min(base_s) - 1.0),  # least disturbed runs
        "base_spread_pct": 100.0 * (max(base_s) - min(base_s)) / base,
        "rss_method": methods[0],
        "torch_live_method": methods[1],
        "last_window": str(last),
    }


def _load(spec: str) -> Workload:
    module, _, func = spec.partition(":")
    return getattr(importlib.import_module(module), func or "workload")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workload", default=None, help="module:function taking a window factory")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--reps", type=int, default=7)
    ap.add_argument("--threads", type=int, default=1, help="torch intra-op threads (CPU)")
    ap.add_argument("--method", default="auto", choices=["auto", "profiler-memory", "dispatch-mode", "off"])
    ap.add_argument("--windows", type=int, default=4, help="toy workload: keyframe windows per run")
    ap.add_argument("--steps-per-window", type=int, default=5, help="toy workload: optimiser steps per window")
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    if args.workload:
        workload = _load(args.workload)
    else:
        workload = functools.partial(gaussian_toy, windows=args.windows, steps_per_window=args.steps_per_window)
    res = measure_overhead(
        workload,
        torch.device(args.device),
        reps=args.reps,
        torch_live=args.method != "off",
        method="auto" if args.method == "off" else args.method,
    )
    print(
        f"base {res['base_s'] * 1e3:.1f} ms (spread {res['base_spread_pct']:.1f} %), "
        f"probed {res['probed_s'] * 1e3:.1f} ms -> overhead {res['overhead_pct']:+.1f} % "
        f"(of the fastest runs {res['overhead_min_pct']:+.1f} %) "
        f"[rss: {res['rss_method']}, torch live: {res['torch_live_method']}]"
    )
    print(f"last window: {res['last_window']}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
