"""What a run is built from: its opened sequence, the SLAM system around it, the strategy, timers and probe.

``build`` makes them once per run (seeded by ``repeatable``); ``restore`` puts a checkpoint's state
back into freshly built ones.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch

from bench.datasets import FrameSequence, open_sequence
from bench.errors import ConfigError
from bench.measure.memory import MemoryProbe, set_malloc_policy
from bench.measure.timing import PhaseTimer
from bench.run import checkpoint as ckpt
from bench.run.config import RunConfig
from bench.run.figures.pruned_run import PruneViz
from bench.run.identity import dataset_name
from bench.run.validate import ValidatedRun
from bench.slam.keyframes import STORE_DIR
from bench.slam.strategy import CheckedStrategy, Strategy
from bench.slam.system import System


@dataclass
class RunSetup:
    """What ``build`` makes and the later steps use."""

    seq: FrameSequence
    n_frames: int  # frames to process (max_frames applied)
    strategy: Strategy
    system: System
    timer: PhaseTimer
    probe: MemoryProbe
    viz: PruneViz | None = None  # viz.pruning
    lpips: Any = None  # what validate loaded from eval.lpips_weights; None: loaded at evaluation if at all
    keys: dict[str, Any] = field(default_factory=dict)  # the run block of metrics.json (bench.run.identity)
    malloc: str = "system"  # the memory.malloc policy that holds (bench.measure.memory.set_malloc_policy)


def open_seq(cfg: RunConfig) -> FrameSequence:
    """The run's sequence; opened before the run starts, so its files enter the resume key."""
    dataset = cfg.dataset
    if cfg.seq is not None:
        is_plain = isinstance(dataset, dict)
        dataset = {**dataset, "seq": cfg.seq} if is_plain else dataclasses.replace(dataset, seq=cfg.seq)
    return open_sequence(dataset_name(dataset), dataset)


def build(
    cfg: RunConfig, device: torch.device, seq: FrameSequence, built: ValidatedRun, out: Path | None = None
) -> RunSetup:
    """Make the SLAM system (seeded by ``repeatable``) for the opened sequence, around what validate built;
    ``out``: the run dir, where ``slam.keyframes.residency=disk`` keeps its keyframe store."""
    strategy = built.strategy
    n_frames = min(len(seq), cfg.max_frames) if cfg.max_frames else len(seq)
    if n_frames < 2:
        raise ConfigError(f"a run needs at least 2 frames: expected >= 2, found {n_frames}")
    malloc = set_malloc_policy(cfg.memory.malloc)  # before the run allocates its state
    warm_kernels(cfg.slam.raster_backend, device, cfg.slam.gsplat_stats)  # before the memory probe: not the run's
    timer = PhaseTimer(device)
    probe = MemoryProbe(device, torch_live=cfg.memory.torch_live)  # before the SLAM state is allocated
    store = out / STORE_DIR if out is not None else None
    system = System(
        cfg.slam, seq.K, seq.height, seq.width, strategy, cfg.prune, device, timer=timer, keyframe_dir=store
    )
    return RunSetup(seq, n_frames, strategy, system, timer, probe, lpips=built.lpips, malloc=malloc)


_warm: set[str] = set()  # rasterizer backends whose kernels this process has loaded


def warm_kernels(backend: str, device: torch.device, gsplat_stats: str = "auto") -> None:
    """Load every compiled rasterizer kernel into this process before the timed frame loop.

    Why: numba loads a cached kernel at its first call, and a run calls some kernels first only
    after its warm-up frame (the pose gradient from the second frame, pruning statistics at the
    first prune). The first run of a process (a sweep's first job, a single run) then paid that
    loading inside ``slam_wall_s`` and FPS, and later jobs of the same process did not. Loaded here,
    once per process, every job's loop runs on loaded kernels; the time is in ``wall_s`` only.
    """
    from bench.slam.raster import resolve_backend

    name = resolve_backend(backend, device)
    if name == "fused" and name not in _warm:
        from bench.slam.raster_fused import compile_kernels

        compile_kernels()  # loads each kernel from numba's cache (compiling it there first if absent)
        _warm.add(name)
    if name == "gsplat" and "gsplat_stats" not in _warm:
        from bench.slam.raster_gsplat import stats_impl

        if stats_impl(gsplat_stats) == "triton":  # Triton compiles its kernel at the first call (seconds)
            from bench.slam.gsplat_stats import warm

            warm(device)
            _warm.add("gsplat_stats")


def restore(parts: RunSetup, start: dict[str, Any]) -> None:
    """Put a checkpoint's state into freshly built parts: the system, the strategy, the global generators."""
    parts.system.load_state_dict(start["system"], lambda i: parts.seq[i])
    vars(inner_strategy(parts.strategy)).update(start["strategy"])
    done = json.loads(start["drive"]["json"])
    parts.timer.restore(done["phase_s"], done["phase_n"])
    ckpt.set_global_rng_state(start["rng"])  # last: nothing after it draws before the next frame


def inner_strategy(strategy: Strategy) -> Strategy:
    return strategy.inner if isinstance(strategy, CheckedStrategy) else strategy


def describe(keys: dict[str, Any]) -> str:
    """A run in a figure title: strategy, keep ratio and preset, from its keys (``bench.run.identity.run_keys``)."""
    from bench.names import method_name

    ratio = "" if keys["keep_ratio"] is None else f", keep {keys['keep_ratio']:g}"
    return f"{method_name(keys['strategy'])} ({keys['strategy']}{ratio}, slam={keys['slam_preset']})"
