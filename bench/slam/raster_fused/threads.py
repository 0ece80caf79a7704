"""How many threads each kernel runs on, and numba's threading layer (set before its first parallel kernel runs)."""

from __future__ import annotations

import os

import numba
import torch

# numba's threading layer: OpenMP first, the work queue where no OpenMP runtime is installed. A
# work-queue worker wakes and parks through the OS on every kernel and then shares the cores with
# torch's spinning OpenMP pool, which slows the whole SLAM loop where cores are few
# (profiling/loop_profile.py shows where the time goes). A layer named in NUMBA_THREADING_LAYER still wins.
LAYER_PRIORITY = "omp workqueue tbb"


def use_threading_layer() -> None:
    """Put numba's threading-layer priority in place before its first parallel kernel runs or its threads
    start: in numba's config, which numba reads when it chooses, and in the environment, which a child
    process that compiles the kernels (``kernel_cache``) inherits. Called where the kernels start
    (``kernel_cache.load_from_cache``, ``set_threads``), not at import; a priority already in the
    environment wins. Idempotent."""
    os.environ.setdefault("NUMBA_THREADING_LAYER_PRIORITY", LAYER_PRIORITY)
    # numba.config's settings are set at run time from the environment, not visible to mypy
    numba.config.THREADING_LAYER_PRIORITY = os.environ["NUMBA_THREADING_LAYER_PRIORITY"].split()  # type: ignore[attr-defined]


# below this many work items a kernel runs on one thread: a parallel region ends at a barrier, and
# on a loaded machine (a sweep running jobs side by side) waiting there for a descheduled worker
# costs more than the work itself
PARALLEL_MIN_ITEMS = 32_768


def set_threads(n_items: int) -> None:
    """Run the next kernel on as many threads as torch uses (``threads=``), or one for small work.

    numba's OpenMP pool starts on numba's first call and then sets the OpenMP runtime's thread count,
    which torch shares, to all the cores (``NUMBA_NUM_THREADS``): a run at ``threads=1`` ran every
    torch operation after its first render on every core. Torch's count is put back."""
    use_threading_layer()  # before set_num_threads, which starts numba's threads
    n_torch = torch.get_num_threads()
    n = n_torch if n_items >= PARALLEL_MIN_ITEMS else 1
    numba.set_num_threads(max(1, min(n, numba.config.NUMBA_NUM_THREADS)))  # type: ignore[attr-defined]  # set at run time
    if torch.get_num_threads() != n_torch:
        torch.set_num_threads(n_torch)
