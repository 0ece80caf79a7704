"""Where the SLAM loop's time goes: per phase, and per part of one optimisation iteration.

Runs one ordinary ``bench.run.lifecycle.run`` of a config with timers wrapped around the loop's parts (no
change to what the run computes) and prints two tables per config:

- per phase (tracking, mapping, densification, pruning, evaluation, refinement): seconds, share of
  the total, and ms per optimisation iteration where the phase iterates;
- within one iteration of tracking, of mapping and of the final refinement: projection, binning and sorting, raster
  forward, raster backward, loss, projection backward, autograd glue (the backward of everything
  torch differentiates itself: loss, conic inversion, concatenations), Adam step, and the rest.

Each part is timed exclusively (a part nested in another is billed to the inner one only), so the
parts sum to the phase. Timers add a few microseconds per call.

    python profiling/loop_profile.py                 # both defaults below
    python profiling/loop_profile.py --only kitti    # or: --only synthetic
    python profiling/loop_profile.py --overrides "dataset=synthetic +experiment=tiny"

Defaults: the shared KITTI 06 frames at 1/2 resolution, first 20 frames
(``dataset=kitti dataset.root=<shared>/data/kitti seq=06 max_frames=20``), and the synthetic
default (``python -m bench``), both at ``threads=2``.
"""

from __future__ import annotations

import argparse
import shlex
import sys
import tempfile
import time
from collections import defaultdict
from collections.abc import Callable
from contextlib import contextmanager
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # profile the checkout this file sits in, not whichever one is pip-installed
SHARED_KITTI = ROOT.parent / "shared" / "data" / "kitti"  # ../shared beside the checkout
DEFAULTS = {
    "kitti": f"dataset=kitti dataset.root={SHARED_KITTI} seq=06 max_frames=20 threads=2",
    "synthetic": "threads=2",
}
PARTS = ("projection", "binning", "raster_fwd", "raster_bwd", "loss", "proj_bwd", "autograd_glue", "adam", "rest")
PHASES = ("tracking", "mapping", "densification", "pruning", "evaluation", "refine")


class Clock:
    """Exclusive wall time per label: entering a label pauses the one that was running."""

    def __init__(self) -> None:
        self.ms: dict[str, float] = defaultdict(float)
        self.stack: list[list] = []  # [label, start]

    @contextmanager
    def part(self, label: str):
        now = time.perf_counter()
        if self.stack:
            top = self.stack[-1]
            self.ms[top[0]] += 1e3 * (now - top[1])
        self.stack.append([label, now])
        try:
            yield
        finally:
            now = time.perf_counter()
            lab, t0 = self.stack.pop()
            self.ms[lab] += 1e3 * (now - t0)
            if self.stack:
                self.stack[-1][1] = now


def wrap_timed(owner, name: str, clock: Clock, label: Callable[[], str] | str, static: bool = False):
    """Replace ``owner.name`` by itself timed under ``label`` on ``clock``; returns the original."""
    orig = getattr(owner, name)

    def wrapped(*a, **k):
        with clock.part(label() if callable(label) else label):
            return orig(*a, **k)

    setattr(owner, name, staticmethod(wrapped) if static else wrapped)
    return orig


class Profile:
    """Patches the loop's functions with timers; ``phase`` is the phase the loop is in."""

    def __init__(self) -> None:
        from bench.run import evaluation as run_mod
        from bench.slam import mapping, raster, raster_fused, renderer, system, tracking
        from bench.slam.raster_fused import autograd as fused_autograd

        self.clock = Clock()
        self.phase = "other"
        self.iters: dict[str, int] = defaultdict(int)
        self.parts: dict[str, dict[str, float]] = {}
        pc = self

        def phased(owner, name, phase):
            orig = getattr(owner, name)

            def wrapped(self_, *a, **k):
                prev, pc.phase = pc.phase, phase
                try:
                    with pc.clock.part(f"phase:{phase}"):
                        return orig(self_, *a, **k)
                finally:
                    pc.phase = prev

            setattr(owner, name, wrapped)

        for owner, name, phase in (
            (tracking.Tracking, "track", "tracking"),
            (mapping.Mapping, "map_keyframe", "mapping"),
            (mapping.Mapping, "densify", "densification"),
            (system.System, "_prune", "pruning"),
            (mapping.Mapping, "refine", "refine"),
        ):
            phased(owner, name, phase)
        orig_eval = run_mod.evaluate

        def evaluate(*a, **k):
            prev, pc.phase = pc.phase, "evaluation"
            try:
                with pc.clock.part("phase:evaluation"):
                    return orig_eval(*a, **k)
            finally:
                pc.phase = prev

        run_mod.evaluate = evaluate

        def lab(part):
            return lambda: f"{pc.phase}:{part}"

        orig_render = renderer.Renderer.render  # every render of the system goes through it

        def render(self_, *a, **k):
            if k.get("training") or pc.phase == "tracking" and torch.is_grad_enabled():
                pc.iters[pc.phase] += 1
            return orig_render(self_, *a, **k)

        renderer.Renderer.render = render
        wrap_timed(raster, "_front", self.clock, lab("projection"))
        wrap_timed(raster, "_front_fused", self.clock, lab("projection"))
        wrap_timed(raster_fused, "bin_pairs", self.clock, lab("binning"))
        wrap_timed(fused_autograd._Composite, "forward", self.clock, lab("raster_fwd"), static=True)
        wrap_timed(fused_autograd._Composite, "backward", self.clock, lab("raster_bwd"), static=True)
        wrap_timed(fused_autograd._Project, "backward", self.clock, lab("proj_bwd"), static=True)
        wrap_timed(raster, "_render_torch", self.clock, lab("raster_fwd"))
        wrap_timed(tracking.Tracking, "_tracking_loss", self.clock, lab("loss"))
        wrap_timed(mapping, "depth_l1", self.clock, lab("loss"))  # mapping's depth term, as mapping calls it
        wrap_timed(torch.Tensor, "backward", self.clock, lab("autograd_glue"))
        wrap_timed(torch.optim.Adam, "step", self.clock, lab("adam"))

    def reset(self) -> None:
        self.clock.ms.clear()
        self.clock.stack.clear()
        self.iters.clear()

    def tables(self) -> str:
        ms = self.clock.ms
        phase_ms = {p: sum(v for k, v in ms.items() if k.startswith(p + ":")) for p in PHASES}
        total = sum(phase_ms.values())
        lines = [f"{'phase':<14} {'s':>8} {'share':>6} {'iters':>6} {'ms/iter':>8}"]
        for p in PHASES:
            n = self.iters.get(p, 0)
            per = f"{phase_ms[p] / n:8.1f}" if n else f"{'':>8}"
            lines.append(f"{p:<14} {phase_ms[p] / 1e3:8.2f} {phase_ms[p] / max(total, 1e-9):6.1%} {n:6d} {per}")
        lines.append(f"{'total':<14} {total / 1e3:8.2f}")
        for p in ("tracking", "mapping", "refine"):
            n = self.iters.get(p, 0)
            if not n:
                continue
            lines.append("")
            lines.append(f"one {p} iteration ({n} iterations; ms per iteration, share of the phase)")
            own = {part: ms.get(f"{p}:{part}", 0.0) for part in PARTS}
            own["rest"] += ms.get(f"phase:{p}", 0.0)
            for part in PARTS:
                lines.append(f"  {part:<14} {own[part] / n:8.2f} {own[part] / max(phase_ms[p], 1e-9):6.1%}")
            lines.append(f"  {'total':<14} {phase_ms[p] / n:8.2f}")
        return "\n".join(lines)


def warm_up() -> None:
    """Load (or compile) the fused kernels before timing, so no phase is billed for numba."""
    from bench.slam.raster import rasterize

    n = 64
    g = torch.Generator().manual_seed(0)
    means = torch.cat([torch.rand(n, 2, generator=g) - 0.5, torch.full((n, 1), 3.0)], 1)
    params = [
        means,
        torch.full((n, 3), -3.0),
        torch.tensor([1.0, 0, 0, 0]).repeat(n, 1),
        torch.full((n,), 0.8),
        torch.rand(n, 3, generator=g),
    ]
    params = [p.requires_grad_(True) for p in params]
    K = torch.tensor([[40.0, 0, 32], [0, 40.0, 32], [0, 0, 1]])
    for stats in (False, True):
        out = rasterize(*params, torch.eye(4), K, 64, 64, stats=stats, backend="fused")
        (out.color.sum() + out.depth.sum()).backward()


def profile(prof: Profile, overrides: list[str]) -> str:
    from bench.cli.entry import compose
    from bench.run.lifecycle import run

    prof.reset()
    cfg = compose([*overrides, "progress=false"])
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        res = run(cfg, Path(tmp) / "run")
        wall = time.perf_counter() - t0
    m = res.metrics
    head = (
        f"status={res.status} frames={m.get('num_frames')} fps={m.get('fps')} wall_s={wall:.1f} "
        f"ate_rmse_m={m.get('ate_rmse_m')} psnr_db={m.get('psnr_db')} "
        f"gaussians_final={m.get('gaussians_final')}"
    )
    import numba

    try:
        head += f" numba_layer={numba.threading_layer()}"
    except ValueError:  # no parallel kernel ran (the torch backend)
        pass
    return head + "\n" + prof.tables()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", choices=sorted(DEFAULTS), help="one of the two default configs")
    ap.add_argument("--overrides", help="a config of your own, as on the python -m bench command line")
    args = ap.parse_args()
    if args.overrides is not None:
        configs = {"custom": args.overrides}
    else:
        configs = {args.only: DEFAULTS[args.only]} if args.only else DEFAULTS
    warm_up()
    prof = Profile()
    for name, ov in configs.items():
        print(f"== {name}: python -m bench {ov}", flush=True)
        print(profile(prof, shlex.split(ov)), flush=True)


if __name__ == "__main__":
    main()
