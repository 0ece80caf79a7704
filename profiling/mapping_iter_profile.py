"""Where one mapping iteration at the faithful preset spends its time, part by part, on a real map.

Builds a map with a short real run (the shared KITTI 06 frames at 1/2 resolution,
``slam=faithful_fit``, the first ``--frames`` frames, no final refinement), keeps the system as its
last keyframe's mapping left it, and then runs ``--blocks`` x ``--iters`` more mapping iterations
over the same keyframe window (``Mapping._optimize``, the code the run itself calls) with a timer
around each part:

- ``projection``: the projection kernel and the in-view index (``raster._front_fused``);
- ``binning``: the depth sort and the (tile, Gaussian) pair list (``raster_fused.bin_pairs``);
- ``fwd_kernel`` / ``fwd_glue``: the compositing forward kernel, and the rest of the compositing
  function (gathering the Gaussians in view with their conic, antialiasing factor and features,
  buffers, packing them, the tile schedule, the statistics' reductions);
- ``render_glue``: what the fused render does around them in torch (the output images);
- ``bwd_kernel`` / ``bwd_glue``: the compositing backward kernel, and the rest of its function
  (buffers, schedule, the per-pair gradients summed per Gaussian, chained through the conic and
  the antialiasing factor and scattered back to the map's rows);
- ``proj_bwd``: the projection's hand-written backward;
- ``loss_ssim``, ``loss_depth``: the D-SSIM term and the depth L1 (the colour L1 is a line of
  ``_optimize``, billed to ``python``);
- ``autograd_glue``: the backward of everything torch differentiates itself (losses, selection,
  concatenations), i.e. ``loss.backward()`` less the parts above;
- ``adam``: the optimizer step; ``kf_images``: reading the keyframe's images;
- ``python``: the rest of the iteration (the loop, the learning-rate decay, the colour L1,
  ``zero_grad``, the strategy's hooks).

Each part is timed exclusively (a part nested in another is billed to the inner one only), so the
parts sum to the iteration. The shares are the median over the blocks of each part's share of its
block; with other jobs on the machine the absolute times move, the shares much less. Pairs: the
contributing (pixel, Gaussian) pairs per pixel, the work of the compositing, and the (tile,
Gaussian) entries of the list per tile (stats renders of a few picks of the window, outside the
timing).

    python profiling/mapping_iter_profile.py [--frames 3] [--iters 10] [--blocks 3] [--threads 2]
                                             [--overrides "slam.mapping_window=4"]
"""

from __future__ import annotations

import argparse
import shlex
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # profile the checkout this file sits in, not whichever one is pip-installed
sys.path.insert(0, str(ROOT / "profiling"))

from loop_profile import Clock, warm_up, wrap_timed  # noqa: E402

from bench.slam.raster_fused.constants import TILE  # noqa: E402

SHARED_KITTI = ROOT.parent / "shared" / "data" / "kitti"  # ../shared beside the checkout
PARTS = (
    "projection",
    "binning",
    "render_glue",
    "fwd_glue",
    "fwd_kernel",
    "loss_ssim",
    "loss_depth",
    "bwd_glue",
    "bwd_kernel",
    "proj_bwd",
    "autograd_glue",
    "adam",
    "kf_images",
    "python",
)


def build_map(frames: int, threads: int, extra: list[str]) -> tuple[Any, tuple, str]:
    """A short run at the faithful preset; its mapping part, its last ``_optimize`` call's arguments, and a summary."""
    from bench.cli.entry import compose
    from bench.run.lifecycle import run
    from bench.slam import mapping

    captured: dict[str, Any] = {}
    orig = mapping.Mapping._optimize

    def optimize(self_, kf_idx, iters, pick, *a, **k):
        captured["call"] = (self_, kf_idx, pick)
        return orig(self_, kf_idx, iters, pick, *a, **k)

    mapping.Mapping._optimize = optimize  # type: ignore[method-assign]
    overrides = [
        "dataset=kitti",
        f"dataset.root={SHARED_KITTI}",
        "seq=06",
        f"max_frames={frames}",
        "slam=faithful_fit",
        "dataset.downscale=2",
        "slam.refine_iters=0",
        f"threads={threads}",
        "eval.lpips=false",
        "progress=false",
        *extra,
    ]
    cfg = compose(overrides)
    try:
        with tempfile.TemporaryDirectory() as tmp:
            t0 = time.perf_counter()
            res = run(cfg, Path(tmp) / "run")
            wall_s = time.perf_counter() - t0
    finally:
        mapping.Mapping._optimize = orig  # type: ignore[method-assign]
    if "call" not in captured:
        sys.exit(f"expected the run to map at least one keyframe, found none (python -m bench {' '.join(overrides)})")
    m = res.metrics
    head = (
        f"map: python -m bench {' '.join(overrides)}\n"
        f"  status={res.status} wall_s={wall_s:.1f} psnr_db={m.get('psnr_db')} "
        f"gaussians_final={m.get('gaussians_final')}"
    )
    return captured["call"], head


def pair_counts(mapper: Any, pick: Any, n_views: int) -> tuple[float, float, int, int]:
    """(list entries per tile, contributing pairs per pixel, Gaussians in view, Gaussians), averaged
    over ``n_views`` picks of the window (stats renders, no gradient)."""
    from bench.slam import raster_fused

    listed: list[int] = []
    orig = raster_fused.bin_pairs

    def bin_pairs(*a, **k):
        tile_start, gid = orig(*a, **k)
        listed.append(int(gid.numel()))
        return tile_start, gid

    raster_fused.bin_pairs = bin_pairs
    hits, in_view = [], []
    try:
        with torch.no_grad():
            for it in range(n_views):
                out = mapper.renderer.render(mapper.map, pick(it).w2c, stats=True)
                hits.append(int(out.hit_count.sum()))
                in_view.append(int((out.radius_px > 0).sum()))
    finally:
        raster_fused.bin_pairs = orig
    W, H = mapper.renderer.W, mapper.renderer.H
    tiles = -(-W // TILE) * -(-H // TILE)
    per_px = statistics.mean(hits) / (W * H)
    return statistics.mean(listed) / tiles, per_px, int(statistics.mean(in_view)), len(mapper.map)


class Timers:
    """The parts of an iteration patched with exclusive timers; ``undo`` restores every function."""

    def __init__(self, clock: Clock) -> None:
        from bench.slam import mapping, raster, raster_fused
        from bench.slam.raster_fused import autograd as fa

        self.undo: list[tuple[Any, str, Any]] = []

        def timed(owner: Any, name: str, label: str, static: bool = False) -> None:
            # the attribute as the owner holds it (a staticmethod stays one), or None where it is inherited
            self.undo.append((owner, name, vars(owner).get(name)))
            wrap_timed(owner, name, clock, label, static)

        timed(raster, "_front_fused", "projection")
        timed(raster_fused, "bin_pairs", "binning")
        timed(raster, "_render_fused", "render_glue")
        timed(fa._Composite, "forward", "fwd_glue", static=True)
        timed(fa, "composite_fwd", "fwd_kernel")
        timed(fa._Composite, "backward", "bwd_glue", static=True)
        timed(fa, "composite_bwd", "bwd_kernel")
        timed(fa._Project, "backward", "proj_bwd", static=True)
        timed(mapping, "dssim", "loss_ssim")
        timed(mapping, "depth_l1", "loss_depth")  # mapping's depth term, as mapping calls it
        timed(torch.Tensor, "backward", "autograd_glue")
        timed(torch.optim.Adam, "step", "adam")
        from bench.slam import keyframes

        timed(keyframes.Keyframe, "images", "kf_images")

    def restore(self) -> None:
        for owner, name, orig in reversed(self.undo):
            if orig is None:
                delattr(owner, name)
            else:
                setattr(owner, name, orig)


def profile(call: tuple, iters: int, blocks: int, threads: int) -> str:
    """The iterations timed as the run ran them: on its thread count, with denormals flushed as the
    SLAM system sets them (the run's end restores both, and Adam's moments and small gradients are
    slow as denormals)."""
    mapper, kf_idx, pick = call
    torch.set_num_threads(threads)
    torch.set_flush_denormal(True)
    clock = Clock()
    timers = Timers(clock)
    shares: dict[str, list[float]] = {p: [] for p in PARTS}
    per_iter_ms: dict[str, list[float]] = {p: [] for p in PARTS}
    totals_ms = []
    try:
        for _ in range(blocks):
            clock.ms.clear()
            clock.stack.clear()
            with clock.part("python"):
                mapper._optimize(kf_idx, iters, pick)
            total = sum(clock.ms.values())
            totals_ms.append(total / iters)
            for p in PARTS:
                shares[p].append(clock.ms.get(p, 0.0) / total)
                per_iter_ms[p].append(clock.ms.get(p, 0.0) / iters)
    finally:
        timers.restore()
        torch.set_flush_denormal(False)
    lines = [f"one mapping iteration ({blocks} blocks of {iters}; medians over the blocks)"]
    lines.append(f"  {'part':<14} {'ms/iter':>8} {'share':>6}")
    for p in PARTS:
        lines.append(f"  {p:<14} {statistics.median(per_iter_ms[p]):8.2f} {statistics.median(shares[p]):6.1%}")
    lines.append(f"  {'total':<14} {statistics.median(totals_ms):8.2f}")
    groups = {
        "compositing kernels (fwd + bwd)": ("fwd_kernel", "bwd_kernel"),
        "projection + binning + proj_bwd": ("projection", "binning", "proj_bwd"),
        "torch around the kernels (render, fwd, bwd glue; autograd)": (
            "render_glue",
            "fwd_glue",
            "bwd_glue",
            "autograd_glue",
        ),
        "losses": ("loss_ssim", "loss_depth"),
        "adam": ("adam",),
        "python and the rest": ("python", "kf_images"),
    }
    lines.append("  grouped:")
    for name, parts in groups.items():
        share = statistics.median([sum(shares[p][b] for p in parts) for b in range(blocks)])
        lines.append(f"    {name:<58} {share:6.1%}")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=3, help="frames of the run that builds the map")
    ap.add_argument("--iters", type=int, default=10, help="mapping iterations per timed block")
    ap.add_argument("--blocks", type=int, default=3, help="timed blocks")
    ap.add_argument("--threads", type=int, default=2, help="threads= of the run")
    ap.add_argument("--overrides", default="", help="more overrides, as on the python -m bench command line")
    args = ap.parse_args()
    if not SHARED_KITTI.is_dir():
        sys.exit(f"expected the shared KITTI frames at {SHARED_KITTI}, found no such folder")
    warm_up()
    call, head = build_map(args.frames, args.threads, shlex.split(args.overrides))
    print(head, flush=True)
    mapper, _, pick = call
    torch.set_num_threads(args.threads)  # the run's end restored the count it found
    per_tile, per_px, n_view, n = pair_counts(mapper, pick, 4)
    print(
        f"  {n} Gaussians, {n_view} in view on average; {per_px:.1f} contributing (pixel, Gaussian) pairs per "
        f"pixel, {per_tile:.0f} list entries per {TILE}x{TILE} tile; {mapper.renderer.W}x{mapper.renderer.H} px, "
        f"threads={torch.get_num_threads()}",
        flush=True,
    )
    print(profile(call, args.iters, args.blocks, args.threads), flush=True)


if __name__ == "__main__":
    main()
