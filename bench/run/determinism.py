"""One place that makes a run repeatable: thread count, every random source, order-stable kernels.

Why each piece is needed:
- Threads: a threaded reduction splits its input by the number of threads, and float addition is
  not associative, so the same sum at 1 and at 2 threads can differ in the last bit. SLAM feeds
  those bits back (tracking, then mapping from the tracked pose), so they grow into different
  trajectories. The count is therefore a setting (``threads``, part of the config hash), never
  "whatever the machine has".
- ``torch.use_deterministic_algorithms``: on CPU, ``index_put_(accumulate=True)`` (the backward of
  the gathers in the torch rasterizer) adds with atomics across threads unless it is set, so the
  summation order follows the scheduler and two identical runs differ.
- Seeds: Python's ``random``, numpy's legacy global generator, torch's and OpenCV's (``cv2.setRNGSeed``)
  global generators. The SLAM system also draws from its own generators seeded by the run seed
  (keyframe sampling, densification offsets, RANSAC order; see ``bench.slam.system.System``), so that
  a change in one consumer does not shift the draws of another.

``determinism=fast`` is the opt-in escape hatch: the same seeds and thread count, but torch may
pick non-deterministic kernels. A run records which mode it ran in and whether the result is
expected to repeat bit for bit (``metrics.json`` → ``determinism``).
"""

from __future__ import annotations

import os
import random
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import cv2
import numpy as np
import torch

from bench.errors import ConfigError

MODES: tuple[str, ...] = ("strict", "fast")
# What a repeat may change even when deterministic: wall-clock times and process memory peaks.
# Everything else in metrics.json's "metrics" block and keyframes.csv must repeat exactly.
VOLATILE_METRICS: frozenset[str] = frozenset({
    "slam_wall_s", "warmup_s", "refine_s", "eval_s", "wall_s", "fps", "fps_slam", "phase_s", "cpu_rss_peak_mib",
    "torch_live_peak_mib", "cuda_alloc_peak_mib", "cuda_reserved_peak_mib", "peak_mem_mib",
    "gaussian_share_of_peak",  # from the peak and its work buffers
})  # fmt: skip
VOLATILE_KEYFRAME_COLUMNS: frozenset[str] = frozenset({
    "track_s", "map_s", "prune_s", "diag_s", "cpu_rss_peak_mib", "torch_live_peak_mib", "cuda_alloc_peak_mib",
    "cuda_reserved_peak_mib", "mem_other_mib", "mem_work_mib",  # the last two: from the live and peak counts
})  # fmt: skip
# cuBLAS needs a fixed workspace to pick the same reduction order from call to call
_CUBLAS_WORKSPACE = ":4096:8"


def repeatable_metrics(metrics: dict[str, Any]) -> dict[str, Any]:
    """The part of a run's ``metrics`` block that must be identical between repeats."""
    return {k: v for k, v in metrics.items() if k not in VOLATILE_METRICS}


def seed_everything(seed: int) -> None:
    """Seed every global generator a run may touch."""
    random.seed(seed)
    np.random.seed(seed % 2**32)
    torch.manual_seed(seed)
    cv2.setRNGSeed(seed % 2**31)  # OpenCV's global generator; its RANSAC keeps a private one (see frontend.py)


def check_mode(mode: str) -> str:
    if mode not in MODES:
        raise ConfigError(f"determinism must be one of {', '.join(MODES)}; found '{mode}'")
    return mode


def check_threads(threads: int | None) -> int | None:
    if threads is not None and (isinstance(threads, bool) or int(threads) < 1):
        raise ConfigError(f"threads must be a positive integer or null; found {threads!r}")
    return None if threads is None else int(threads)


@contextmanager
def repeatable(seed: int, threads: int | None, mode: str, device: torch.device) -> Iterator[dict[str, Any]]:
    """Set threads, seeds and kernel choice for one run; restore the process's previous settings after.

    Yields the record written to ``metrics.json``: the mode, the thread count actually in force,
    and ``deterministic`` (true when the same config and seed are expected to give the same
    numbers, timings and memory peaks aside).
    """
    check_mode(mode)
    threads = check_threads(threads)
    if seed < 0:
        raise ConfigError(f"seed must be a non-negative integer; found {seed}")
    saved = (
        torch.get_num_threads(),
        torch.are_deterministic_algorithms_enabled(),
        torch.is_deterministic_algorithms_warn_only_enabled(),
        cv2.getNumThreads(),
    )
    saved_cudnn = (torch.backends.cudnn.deterministic, torch.backends.cudnn.benchmark)
    try:
        if threads is not None:
            torch.set_num_threads(threads)
            cv2.setNumThreads(threads)
        strict = mode == "strict"
        cuda = device.type == "cuda"
        if strict and cuda:
            os.environ.setdefault("CUBLAS_WORKSPACE_CONFIG", _CUBLAS_WORKSPACE)
            torch.backends.cudnn.deterministic, torch.backends.cudnn.benchmark = True, False
        # on CUDA some kernels the torch rasterizer uses have no deterministic variant: they warn
        # instead of failing the run, and the record does not claim bit-identical results there
        torch.use_deterministic_algorithms(strict, warn_only=cuda)
        seed_everything(seed)
        record: dict[str, Any] = {
            "mode": mode,
            "deterministic": strict and not cuda,
            "threads": torch.get_num_threads(),
            "threads_fixed": threads is not None,
            "torch_deterministic_algorithms": strict,
            "seed": seed,
        }
        if strict and cuda:
            record["note"] = "cuda: deterministic kernels requested, bit-identical results not verified"
        elif threads is None:
            record["note"] = "threads=null: the machine's default thread count; results may differ between machines"
        yield record
    finally:
        # the SLAM system flushes denormals for speed (bench/slam/system.py); that CPU mode is process-wide
        # and must not outlive the run: under it scipy's cKDTree build recurses without end on the grid
        # route's street points (a segfault in the next run of a sweep), and a run's inputs would depend
        # on whether a run came before it in the same process
        torch.set_flush_denormal(False)
        torch.set_num_threads(saved[0])
        torch.use_deterministic_algorithms(saved[1], warn_only=saved[2])
        cv2.setNumThreads(saved[3])
        torch.backends.cudnn.deterministic, torch.backends.cudnn.benchmark = saved_cudnn
