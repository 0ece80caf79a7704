"""Every process on kernels loaded from numba's cache: absent ones are compiled into it first, in a child process."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path
from typing import Any

from bench.slam.raster_fused.binning import bin_pairs_kernel, depth_order, in_view_kernel
from bench.slam.raster_fused.compositing import (
    composite_bwd,
    composite_fwd,
    pack,
    reduce_stats,
    reduce_sum,
    tile_schedule,
)
from bench.slam.raster_fused.criteria_stats import criteria_extra
from bench.slam.raster_fused.projection import project_bwd, project_fwd, sum_rows
from bench.slam.raster_fused.ssim import ssim_bwd, ssim_fwd
from bench.slam.raster_fused.threads import use_threading_layer
from bench.slam.raster_fused.view import gather_view, scatter_view

_COMPILING_ENV = "POCKETBENCH_COMPILING_KERNELS"
_cache_checked = False


def load_from_cache() -> None:
    """Compile the kernels in a child process when numba's cache lacks them, so that this process
    loads them from the cache like every later one.

    Kernels compiled in the process that runs them gave other roundings than the same kernels loaded
    from numba's cache (the compositing forward, on identical inputs), so a run that compiled them,
    the first after an install or a change, did not repeat bit for bit; with every process on cached
    code it does. Where the cache cannot be written (or numba's internals differ), the kernels
    compile here as before."""
    global _cache_checked
    use_threading_layer()  # before numba compiles or starts a thread, here or in the child below
    if _cache_checked or os.environ.get(_COMPILING_ENV):
        return
    _cache_checked = True
    try:
        kernels: tuple[Any, ...] = (  # numba dispatchers; their cache internals are untyped
            project_fwd,
            project_bwd,
            sum_rows,
            in_view_kernel,
            depth_order,
            bin_pairs_kernel,
            gather_view,
            pack,
            tile_schedule,
            composite_fwd,
            composite_bwd,
            reduce_sum,
            reduce_stats,
            scatter_view,
            criteria_extra,
            ssim_fwd,
            ssim_bwd,
        )
        if all(k._cache._cache_file._load_index() for k in kernels):
            return
    except Exception:  # noqa: BLE001 - a numba without these internals: compile in this process
        return
    root = str(Path(__file__).resolve().parents[3])  # the folder holding the bench package
    env = dict(os.environ, **{_COMPILING_ENV: "1"})
    env["PYTHONPATH"] = os.pathsep.join(p for p in (root, env.get("PYTHONPATH")) if p)
    subprocess.run(
        [sys.executable, "-c", "from bench.slam.raster_fused import compile_kernels; compile_kernels()"],
        env=env,
        cwd=root,  # python -c puts the working dir first on sys.path: another checkout's bench there would compile
        capture_output=True,
        check=False,
    )
