"""Today's compositing kernels against those of a git revision, call by call in one process, on the same inputs.

``raster_bench.py`` times the whole rasterizer, wall clock, in one process per revision; on a
machine shared with other jobs its times move by 2x from run to run, more than a kernel change.
Here the forward and backward compositing kernels of both revisions run on the very inputs one
render of ``raster_bench``'s scene gives (the Gaussians packed, the pair list, the tile schedule),
on one thread, alternating call by call, timed in CPU time of the thread: each pair of calls sees
the same load, and the median of the per-pair ratios (old / today; above 1: today's are faster)
holds where absolute times do not. It also says whether the two revisions' outputs are bit for bit
the same (images, transmittance, last contributors; per-pair gradients) and, where not, the
largest difference relative to the largest value.

The old kernels are ``bench/slam/raster_fused/compositing.py`` as of REV, loaded as a module of its
own beside today's (its imports, the threads and constants modules, are today's), so REV must
have that file and the same kernel signatures. Kernels compiled in the process that runs them round
otherwise than the same kernels loaded from numba's cache (``raster_fused/kernel_cache.py``), so a
child process first compiles both into the cache, and this one loads them from it.

    python profiling/compositing_ab.py --old c26b028 [--points 20000x320x192,5000x160x96]
                                       [--scenes aniso,iso] [--calls 21]
"""

from __future__ import annotations

import argparse
import hashlib
import importlib.util
import re
import statistics
import subprocess
import sys
import time
from pathlib import Path
from types import ModuleType

import numba
import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # the checkout this file sits in, not whichever one is pip-installed
sys.path.insert(0, str(ROOT / "profiling"))

from raster_bench import scene  # noqa: E402

from bench.slam.raster import rasterize  # noqa: E402
from bench.slam.raster_fused import autograd as fused_autograd  # noqa: E402
from bench.slam.raster_fused import compositing as today  # noqa: E402

KERNELS = "bench/slam/raster_fused/compositing.py"
# names the kernels had before they were made public (issue 61): an older revision's file is read with today's
RENAMED = {
    "_forward": "composite_fwd",
    "_backward": "composite_bwd",
    "_pack": "pack",
    "_schedule": "tile_schedule",
    "_reduce_sum": "reduce_sum",
    "_reduce_stats": "reduce_stats",
    "_KERNEL": "KERNEL_OPTIONS",
    "_box": "pixel_box",
    "_exp": "exp_f32",
    "_tile_pixels": "tile_pixels",
    "_F": "F32",
}


def old_compositing(rev: str) -> ModuleType:
    """``KERNELS`` as of ``rev``, as a module of its own (numba caches it beside the copy)."""
    shown = subprocess.run(["git", "-C", str(ROOT), "show", f"{rev}:{KERNELS}"], capture_output=True, text=True)
    if shown.returncode != 0:
        sys.exit(f"--old {rev}: expected {KERNELS} at {rev}, found none ({shown.stderr.strip()})")
    source = re.sub(r"\b(" + "|".join(RENAMED) + r")\b", lambda m: RENAMED[m.group(1)], shown.stdout)
    folder = Path.home() / ".cache" / "pocketbench" / "old_kernels"
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"compositing_{hashlib.sha256(source.encode()).hexdigest()[:12]}.py"
    if not path.exists():
        path.write_text(source)
    spec = importlib.util.spec_from_file_location(path.stem, path)
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    sys.modules[path.stem] = mod
    spec.loader.exec_module(mod)
    return mod


def kernel_inputs(n: int, w: int, h: int, kind: str) -> tuple[list, list]:
    """The arguments one forward+backward of ``raster_bench``'s scene passes the two kernels, for one thread."""
    params, K = scene(n, w, h, torch.device("cpu"), kind=kind)
    seen: dict[str, tuple] = {}
    fwd, bwd = fused_autograd.composite_fwd, fused_autograd.composite_bwd

    def keep(name, kernel):
        def call(*a):
            seen[name] = a
            return kernel(*a)

        return call

    fused_autograd.composite_fwd, fused_autograd.composite_bwd = keep("f", fwd), keep("b", bwd)  # type: ignore[assignment]
    try:
        out = rasterize(*params, torch.eye(4), K, w, h, backend="fused")
        (out.color.sum() + out.depth.sum()).backward()
    finally:
        fused_autograd.composite_fwd, fused_autograd.composite_bwd = fwd, bwd
    f_args, b_args = list(seen["f"]), list(seen["b"])
    order, bounds = today.tile_schedule(f_args[1], 1)  # one thread: every tile in one list
    f_args[7:9] = [order, bounds]
    b_args[6:8] = [order, bounds]
    return f_args, b_args


def run_forward(mod: ModuleType, f_args: list) -> list[np.ndarray]:
    outs = [np.empty_like(x) for x in f_args[9:]]  # acc, t_final, last, and the per-pair statistics
    mod.composite_fwd(*f_args[:9], *outs)
    return outs


def run_backward(mod: ModuleType, b_args: list) -> np.ndarray:
    pair_grad = np.empty_like(b_args[12])  # [P, 10]
    mod.composite_bwd(*b_args[:12], pair_grad)
    return pair_grad


def difference(old: np.ndarray, new: np.ndarray) -> str:
    if np.array_equal(old, new):
        return "bit-identical"
    scale = max(float(np.abs(old).max()), 1e-30)
    return f"max |new - old| / max |old| = {float(np.abs(new.astype(np.float64) - old).max()) / scale:.1e}"


def cpu_s(fn, *args) -> float:
    t0 = time.thread_time()
    fn(*args)
    return time.thread_time() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--old", required=True, metavar="REV", help="the git revision whose kernels are compared")
    ap.add_argument("--points", default="20000x320x192,5000x160x96", help="comma list of NxWxH")
    ap.add_argument("--scenes", default="aniso,iso", help="comma list of iso, aniso")
    ap.add_argument("--calls", type=int, default=21, help="timed calls of each kernel of each revision")
    ap.add_argument("--compile-only", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if not args.compile_only:  # compile both revisions' kernels into numba's cache, in a child
        child = [sys.executable, __file__, "--old", args.old, "--points", "500x32x32", "--scenes", "aniso"]
        subprocess.run([*child, "--calls", "0", "--compile-only"], capture_output=True, check=True)
    old = old_compositing(args.old)
    torch.set_num_threads(1)
    numba.set_num_threads(1)
    print(f"old = {args.old}, today = the checkout; one thread, CPU time; ratio = old / today (above 1: today faster)")
    for kind in args.scenes.split(","):
        for point in args.points.split(","):
            n, w, h = (int(v) for v in point.split("x"))
            f_args, b_args = kernel_inputs(n, w, h, kind)
            if args.compile_only:
                run_forward(old, f_args)
                run_backward(old, b_args)
                continue
            names = ("acc", "t_final", "last")
            outs = run_forward(old, f_args), run_forward(today, f_args)
            same_f = ", ".join(f"{nm} {difference(a, b)}" for nm, a, b in zip(names, outs[0], outs[1], strict=False))
            same_b = difference(run_backward(old, b_args), run_backward(today, b_args))
            ratios: dict[str, list[float]] = {"forward": [], "backward": []}
            ms: dict[str, list[float]] = {"old_f": [], "new_f": [], "old_b": [], "new_b": []}
            for _ in range(args.calls):
                a = cpu_s(run_forward, old, f_args)
                b = cpu_s(run_forward, today, f_args)
                c = cpu_s(run_backward, old, b_args)
                d = cpu_s(run_backward, today, b_args)
                ratios["forward"].append(a / b)
                ratios["backward"].append(c / d)
                for key, v in zip(ms, (a, b, c, d), strict=True):
                    ms[key].append(1e3 * v)
            med = {k: statistics.median(v) for k, v in ms.items()}
            print(
                f"{kind} {n} {w}x{h}: forward x{statistics.median(ratios['forward']):.3f} "
                f"({med['old_f']:.2f} -> {med['new_f']:.2f} ms), backward x{statistics.median(ratios['backward']):.3f} "
                f"({med['old_b']:.2f} -> {med['new_b']:.2f} ms), both "
                f"x{(med['old_f'] + med['old_b']) / (med['new_f'] + med['new_b']):.3f}\n"
                f"  forward outputs: {same_f}\n  backward per-pair gradients: {same_b}",
                flush=True,
            )


if __name__ == "__main__":
    main()
