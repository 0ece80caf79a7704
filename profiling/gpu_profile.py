"""Where a run's time goes on a GPU (or the CPU): phase by phase, kernels against host, and the host syncs by call site.

Runs one ordinary ``bench.run.lifecycle.run`` of a config (nothing it computes changes) and writes, under ``--out``:

- ``profile_phases.csv``: per phase (frame loading with stereo depth, tracking, mapping, pruning, residency,
  refinement, evaluation, and what is outside them), the wall seconds it held exclusively, the device's busy
  seconds (kernels, copies and memsets that started inside it), the kernels launched, and the host syncs seen
  (``cudaStreamSynchronize``, ``cudaDeviceSynchronize``, ``cudaEventSynchronize``, device-to-host copies,
  ``aten::item``/``aten::_local_scalar_dense``, ``aten::nonzero``);
- ``profile_ops.txt``: torch.profiler's operator table (CPU and CUDA totals), the raw figures behind the above;
- ``profile_syncs.csv`` (``--syncs``): a second run under ``torch.cuda.set_sync_debug_mode("warn")``, each
  synchronising call counted at its innermost frame in ``bench/`` or ``strategies/``;
- ``profile_summary.json``: the run's own metrics (fps, fps_slam, phase_s, eval_s, wall_s) and the tables' totals.

The phases are the run's own (``bench.measure.timing.PhaseTimer``: it synchronises CUDA at both ends of each
phase, so a phase's kernels run inside its wall time); the profile adds a ``record_function`` range around each.
The device is busy for ``gpu_busy_s`` of a phase's ``wall_s``; the rest is the host: Python, launches and waits.

    python profiling/gpu_profile.py --out DIR -- dataset=kitti dataset.root=kitti seq=06 dataset.downscale=1 \\
        slam.raster_backend=gsplat threads=8 dataset.last=11 eval.every=5
    python profiling/gpu_profile.py --out DIR --syncs --sync-frames 4 -- <the same overrides>

Keep the profiled run short (a dozen frames): the profiler records every operator and kernel.
"""

from __future__ import annotations

import argparse
import bisect
import contextlib
import csv
import json
import sys
import tempfile
import time
import traceback
import warnings
from collections import Counter, defaultdict
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import torch
from torch.autograd import DeviceType
from torch.profiler import ProfilerActivity, profile, record_function

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # profile the checkout this file sits in, not whichever one is pip-installed

SYNC_OPS = {
    "cudaStreamSynchronize",
    "cudaDeviceSynchronize",
    "cudaEventSynchronize",
    "aten::_local_scalar_dense",
    "aten::nonzero",
}
PHASE_PREFIX = "phase:"
OUTSIDE = "outside phases"


@contextlib.contextmanager
def phase_ranges() -> Iterator[None]:
    """Each PhaseTimer phase, the frame loading and the evaluation also as a profiler range ``phase:NAME``."""
    from bench.measure import timing
    from bench.run import evaluation, loop

    orig_phase, orig_frames, orig_eval = timing.PhaseTimer.phase, loop.run_frames, evaluation.evaluate

    @contextlib.contextmanager
    def phase(self: Any, name: str) -> Iterator[None]:
        with record_function(PHASE_PREFIX + name), orig_phase(self, name):
            yield

    class Loading:
        """The sequence, with each frame's loading (images, stereo depth) as the range ``phase:load``."""

        def __init__(self, seq: Any) -> None:
            self._seq = seq

        def __getitem__(self, i: int) -> Any:
            with record_function(PHASE_PREFIX + "load"):
                return self._seq[i]

        def __len__(self) -> int:
            return len(self._seq)

        def __getattr__(self, name: str) -> Any:
            return getattr(self._seq, name)

    def run_frames(cfg: Any, parts: Any, *a: Any, **k: Any) -> Any:
        parts.seq = Loading(parts.seq)
        try:
            return orig_frames(cfg, parts, *a, **k)
        finally:
            parts.seq = parts.seq._seq

    def evaluate(*a: Any, **k: Any) -> Any:
        with record_function(PHASE_PREFIX + "evaluation"):
            return orig_eval(*a, **k)

    timing.PhaseTimer.phase = phase  # type: ignore[method-assign]
    loop.run_frames, evaluation.evaluate = run_frames, evaluate
    try:
        yield
    finally:
        timing.PhaseTimer.phase = orig_phase  # type: ignore[method-assign]
        loop.run_frames, evaluation.evaluate = orig_frames, orig_eval


def one_run(overrides: list[str]) -> tuple[dict[str, Any], float]:
    """One ordinary run of ``overrides`` in a scratch dir: its metrics and its wall seconds."""
    from bench.cli.entry import compose
    from bench.run.lifecycle import run

    cfg = compose([*overrides, "progress=false"])
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        res = run(cfg, Path(tmp) / "run")
        wall = time.perf_counter() - t0
    return {"status": res.status, **res.metrics}, wall


class Intervals:
    """The phase ranges as nested intervals: the innermost one holding a time, and each one's exclusive time."""

    def __init__(self, ranges: list[tuple[str, float, float]]) -> None:
        self.ranges = sorted(ranges, key=lambda r: (r[1], -r[2]))  # outer before inner at one start
        self.starts = [r[1] for r in self.ranges]
        self.parent: list[int | None] = []
        stack: list[int] = []
        for i, (_, s, _e) in enumerate(self.ranges):
            while stack and self.ranges[stack[-1]][2] < s:
                stack.pop()
            self.parent.append(stack[-1] if stack else None)
            stack.append(i)

    def phase_of(self, t_us: float) -> str:
        i: int | None = bisect.bisect_right(self.starts, t_us) - 1
        while i is not None and i >= 0:
            name, s, e = self.ranges[i]
            if s <= t_us <= e:
                return name
            i = self.parent[i]
        return OUTSIDE

    def exclusive_s(self) -> dict[str, float]:
        out: dict[str, float] = defaultdict(float)
        for i, (name, s, e) in enumerate(self.ranges):
            out[name] += (e - s) / 1e6
            p = self.parent[i]
            if p is not None:
                out[self.ranges[p][0]] -= (e - s) / 1e6
        return dict(out)


def phase_table(prof: Any, wall_s: float) -> tuple[list[dict[str, Any]], str]:
    """Per phase: exclusive wall, device-busy seconds, kernels and host syncs; and the operator table.

    Reads the profiler's raw events (``kineto_results``), not ``prof.events()``: building those objects for a
    run's million events takes minutes of the device's time."""
    events = prof.profiler.kineto_results.events()
    cpu, cuda = DeviceType.CPU, DeviceType.CUDA
    ranges = [
        (e.name()[len(PHASE_PREFIX) :], e.start_ns() / 1e3, e.end_ns() / 1e3)
        for e in events
        if e.device_type() == cpu and e.name().startswith(PHASE_PREFIX)
    ]
    iv = Intervals(ranges)
    busy: dict[str, float] = defaultdict(float)
    kernels: Counter[str] = Counter()
    syncs: Counter[str] = Counter()
    totals: dict[tuple[str, str], list[float]] = defaultdict(lambda: [0, 0.0])  # (device, name) -> [count, s]
    for e in events:
        name, dev = e.name(), e.device_type()
        if dev == cuda and e.is_user_annotation():  # the device-side mirror of a record_function range, not work
            continue
        dur_s = e.duration_ns() / 1e9
        tot = totals[("cuda" if dev == cuda else "cpu", name)]
        tot[0] += 1
        tot[1] += dur_s
        if dev == cuda:  # a kernel, copy or memset on the device
            ph = iv.phase_of(e.start_ns() / 1e3)
            busy[ph] += dur_s
            kernels[ph] += 1
            if "DtoH" in name or "Device -> Pageable" in name or "Device -> Pinned" in name:
                syncs[ph] += 1
        elif name in SYNC_OPS or name == "aten::item":
            syncs[iv.phase_of(e.start_ns() / 1e3)] += 1
    excl = iv.exclusive_s()
    excl[OUTSIDE] = max(0.0, wall_s - sum(excl.values()))
    rows = []
    for name in sorted(excl, key=lambda n: -excl[n]):
        w = excl[name]
        rows.append(
            {
                "phase": name,
                "wall_s": round(w, 3),
                "share_of_wall": round(w / wall_s, 4) if wall_s > 0 else None,
                "gpu_busy_s": round(busy.get(name, 0.0), 3),
                "gpu_busy_share": round(busy.get(name, 0.0) / w, 4) if w > 0 else None,
                "kernels": kernels.get(name, 0),
                "host_syncs": syncs.get(name, 0),
            }
        )
    lines = []
    for dev in ("cuda", "cpu"):
        top = sorted(((k[1], v) for k, v in totals.items() if k[0] == dev), key=lambda kv: -kv[1][1])[:40]
        if not top:
            continue
        lines.append(f"== {dev}: total seconds (CPU ranges include what they enclose), calls, name")
        lines += [f"{v[1]:10.3f} {int(v[0]):9d}  {n[:110]}" for n, v in top]
    return rows, "\n".join(lines) + "\n"


def sync_sites(overrides: list[str], frames: int) -> list[dict[str, Any]]:
    """A short run under ``set_sync_debug_mode("warn")``: each synchronising call counted at its innermost
    frame in the harness's code (bench/, strategies/), with the phase-free stack top as context."""
    counts: Counter[tuple[str, str]] = Counter()
    ours = (str(ROOT / "bench"), str(ROOT / "strategies"))

    def show(message: Any, category: Any, filename: str, lineno: int, file: Any = None, line: Any = None) -> None:
        stack = traceback.extract_stack()[:-1]
        mine = [f for f in stack if f.filename.startswith(ours)]
        site = f"{Path(mine[-1].filename).relative_to(ROOT)}:{mine[-1].lineno}" if mine else f"{filename}:{lineno}"
        what = str(message).split("\n", 1)[0][:80]
        counts[(site, what)] += 1

    torch.cuda.set_sync_debug_mode("warn")
    old = warnings.showwarning
    warnings.showwarning = show
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("always")
            warnings.showwarning = show
            one_run([*overrides, f"dataset.last={frames - 1}", "eval.every=1000000"])
    finally:
        torch.cuda.set_sync_debug_mode(0)
        warnings.showwarning = old
    return [{"site": s, "what": w, "count": n} for (s, w), n in counts.most_common()]


def write_csv(path: Path, rows: list[dict[str, Any]]) -> None:
    if not rows:
        path.write_text("")
        return
    with path.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, required=True, help="folder for the tables")
    ap.add_argument("--syncs", action="store_true", help="also count the host syncs by call site (CUDA only)")
    ap.add_argument("--sync-frames", type=int, default=4, help="frames of the sync-counting run")
    ap.add_argument("overrides", nargs="*", help="the run's config, as on the python -m bench command line")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    cuda = torch.cuda.is_available()
    acts = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if cuda else [])
    with phase_ranges(), profile(activities=acts) as prof:
        metrics, wall = one_run(args.overrides)
    t = time.perf_counter()
    rows, ops = phase_table(prof, wall)
    parse_s = time.perf_counter() - t
    write_csv(args.out / "profile_phases.csv", rows)
    (args.out / "profile_ops.txt").write_text(ops)
    keep = ("status", "num_frames", "num_keyframes", "fps", "fps_slam", "phase_s", "slam_wall_s", "refine_s", "eval_s")
    summary = {
        "overrides": args.overrides,
        "device": torch.cuda.get_device_name() if cuda else "cpu",
        "torch": torch.__version__,
        "profiled_wall_s": round(wall, 3),
        "profile_parse_s": round(parse_s, 3),
        "metrics": {k: metrics.get(k) for k in keep},
        "phases": rows,
    }
    if args.syncs and cuda:
        sites = sync_sites(args.overrides, args.sync_frames)
        write_csv(args.out / "profile_syncs.csv", sites)
        summary["sync_sites_top"] = sites[:25]
        summary["syncs_total"] = sum(s["count"] for s in sites)
    (args.out / "profile_summary.json").write_text(json.dumps(summary, indent=1))
    print(f"profiled run: {wall:.1f} s wall, status {metrics.get('status')}, fps {metrics.get('fps')}")
    print(f"{'phase':<16} {'wall_s':>8} {'share':>6} {'gpu_s':>8} {'busy':>6} {'kernels':>8} {'syncs':>7}")
    for r in rows:
        share = "" if r["share_of_wall"] is None else f"{r['share_of_wall']:.3f}"
        busy = "" if r["gpu_busy_share"] is None else f"{r['gpu_busy_share']:.3f}"
        print(
            f"{r['phase']:<16} {r['wall_s']:>8.2f} {share:>6} {r['gpu_busy_s']:>8.2f} {busy:>6} "
            f"{r['kernels']:>8} {r['host_syncs']:>7}"
        )
    if "sync_sites_top" in summary:
        print(f"host syncs in a {args.sync_frames}-frame run: {summary['syncs_total']}; top sites:")
        for s in summary["sync_sites_top"][:15]:
            print(f"  {s['count']:>6}  {s['site']}  {s['what']}")


if __name__ == "__main__":
    main()
