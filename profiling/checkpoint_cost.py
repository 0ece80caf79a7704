"""Size and write time of one checkpoint (``bench/run/checkpoint.py``) for a map of N Gaussians.

What a checkpoint costs grows with the map (parameters, Adam moments, per-Gaussian state: the
keyframe store is saved by index, poses are 64 B a frame), so this builds a SLAM system in the state
a long drive reaches, N Gaussians with Adam moments, K keyframes, F tracked frames and F / K rows
of keyframes.csv, and times ``bench.run.loop.write_checkpoint`` on it, the same call the frame loop makes.
The figure to compare with is a keyframe's own time (``map_s`` in keyframes.csv, seconds).

    python profiling/checkpoint_cost.py                        # N = 10k, 30k, 100k, 300k; 400 frames
    python profiling/checkpoint_cost.py --gaussians 50000 --frames 1100 --keyframes 370
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bench import schema  # noqa: E402
from bench.measure.memory import MemoryProbe
from bench.measure.timing import PhaseTimer  # noqa: E402
from bench.run.config import RunConfig  # noqa: E402
from bench.run.loop import write_checkpoint  # noqa: E402
from bench.run.outcome import LoopOutcome  # noqa: E402
from bench.run.setup import RunSetup  # noqa: E402
from bench.slam.config import SlamConfig  # noqa: E402
from bench.slam.strategy import CheckedStrategy, load_strategy  # noqa: E402
from bench.slam.system import System  # noqa: E402


def long_drive_system(n: int, keyframes: int, frames: int, hw: tuple[int, int] = (192, 320)) -> System:
    """A system holding what a drive of ``frames`` frames leaves: its map, moments, keyframes and poses."""
    h, w = hw
    K = torch.tensor([[w / 2, 0, w / 2], [0, w / 2, h / 2], [0, 0, 1.0]])
    strategy = CheckedStrategy(load_strategy("none"), "none")
    system = System(SlamConfig(), K, h, w, strategy, 0.5, torch.device("cpu"))
    g = torch.Generator().manual_seed(0)
    system.map.add(
        {
            "means": torch.randn(n, 3, generator=g) * 20,
            "log_scales": torch.randn(n, 3, generator=g) - 3,
            "quats": torch.randn(n, 4, generator=g),
            "opacity_logits": torch.randn(n, generator=g),
            "colors": torch.rand(n, 3, generator=g),
        },
        keyframe=0,
    )
    loss = sum(p.square().sum() for p in system.map.params.values())
    loss.backward()
    system.map.optimizer.step()  # the Adam moments a mapping step leaves
    system.map.optimizer.zero_grad(set_to_none=True)
    rgb, depth = torch.zeros(h, w, 3), torch.zeros(h, w)
    for i in range(keyframes):
        system.keyframes.add(i * frames // keyframes, rgb, depth, torch.eye(4))
    system.poses = [torch.eye(4) for _ in range(frames)]
    return system


def cost(n: int, keyframes: int, frames: int, repeats: int) -> tuple[float, float]:
    """(MiB, median seconds) of one checkpoint."""
    system = long_drive_system(n, keyframes, frames)
    parts = RunSetup(None, frames, system.strategy, system, PhaseTimer(), MemoryProbe(torch.device("cpu")))
    row = dict.fromkeys(schema.KEYFRAME_COLUMNS, 0.0)
    drive = LoopOutcome(
        timestamps_s=[0.1 * i for i in range(frames)],
        gt_c2w=[torch.eye(4, dtype=torch.float64)] * frames,
        windows=[{**row, "kf": i} for i in range(keyframes)],
    )
    code = {"git_commit": "0" * 40, "git_dirty": False}
    record = {
        "run": {"config_hash": "0" * 16, "code_version": code, "inputs": {}},
        "checkpoint": {"every": 1, "written": 0, "mib_last": None, "write_s_total": 0.0, "resumed_from_frames": []},
    }
    times = []
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(repeats):
            t0 = time.perf_counter()
            write_checkpoint(RunConfig(dataset={}), parts, drive, Path(tmp), record, {})
            times.append(time.perf_counter() - t0)
    parts.probe.close()
    return record["checkpoint"]["mib_last"], statistics.median(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--gaussians", type=int, nargs="+", default=[10_000, 30_000, 100_000, 300_000])
    ap.add_argument("--frames", type=int, default=400)
    ap.add_argument("--keyframes", type=int, default=134)  # kf_every=3 over 400 frames
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    torch.set_num_threads(1)
    print(f"{args.frames} frames, {args.keyframes} keyframes; median of {args.repeats} writes")
    print(f"{'gaussians':>10} {'MiB':>8} {'write ms':>9} {'B/Gaussian':>11}")
    for n in args.gaussians:
        mib, s = cost(n, args.keyframes, args.frames, args.repeats)
        print(f"{n:>10} {mib:>8.2f} {s * 1e3:>9.1f} {mib * 2**20 / n:>11.0f}")


if __name__ == "__main__":
    main()
