"""What the literature criteria's render statistics cost on the fused backend, per scoring view.

A criterion with ``score_views=held_keyframes`` renders every keyframe held at each prune, with
``rasterize(..., extra=...)`` (``bench/slam/raster_fused/criteria_stats.py``), so over a long drive
this pass is most of a prune. Times one view's forward with ``stats=True`` alone and with each set of
statistics the criteria ask for, on ``raster_bench``'s scenes; ``extra ms`` is the difference, the
minimum over ``--repeats`` calls (the machine's load only ever adds time).

    python profiling/criteria_stats_bench.py [--repeats 5] [--points 20000x160x96,50000x320x192]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "profiling"))

from raster_bench import scene  # noqa: E402

from bench.slam.raster import rasterize  # noqa: E402

EXTRAS = {"weight_sum+top1": ("weight_sum", "top1"), "alpha_grad_sq": ("alpha_grad_sq",)}


def best_ms(fn, repeats: int) -> float:
    fn()  # compile, warm the caches
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times) * 1e3


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--points", default="20000x160x96,20000x320x192,50000x320x192")
    ap.add_argument("--scenes", default="iso,aniso")
    args = ap.parse_args()
    torch.set_num_threads(1)
    print("| scene | N | W x H | forward ms (stats) | extra | extra ms |")
    print("|---|---|---|---|---|---|")
    w2c = torch.eye(4)
    for kind in args.scenes.split(","):
        for point in args.points.split(","):
            n, w, h = (int(v) for v in point.split("x"))
            params, K = scene(n, w, h, torch.device("cpu"), kind=kind)
            params = [p.detach() for p in params]

            def render(extra: tuple[str, ...], params=params, K=K, w=w, h=h) -> None:
                rasterize(*params, w2c, K, w, h, stats=True, backend="fused", extra=extra)

            base = best_ms(lambda: render(()), args.repeats)
            for name, extra in EXTRAS.items():
                t = best_ms(lambda extra=extra: render(extra), args.repeats)
                print(f"| {kind} | {n} | {w} x {h} | {base:.1f} | {name} | {t - base:.1f} |")


if __name__ == "__main__":
    main()
