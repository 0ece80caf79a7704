"""How many threads each kernel runs on, and numba's threading layer (set before its first parallel kernel runs)."""

from __future__ import annotations

import os

import numba
import torch

# numba's threading layer: OpenMP first, the work queue where no OpenMP runtime is installed. A
# work-queue worker wakes and parks through the OS on every kernel and then shares the cores with
# torch's spinning OpenMP pool, which slows the whole SLAM loop where cores are few
# (profiling/loop_profile.py shows where the time goes). numba chooses when its first parallel kernel runs,
# from its config, which it re-reads from the environment; both are set, whichever module
# imported numba first. A layer named in NUMBA_THREADING_LAYER still wins.
_LAYERS = "omp workqueue tbb"
os.environ.setdefault("NUMBA_THREADING_LAYER_PRIORITY", _LAYERS)
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
    n_torch = torch.get_num_threads()
    n = n_torch if n_items >= PARALLEL_MIN_ITEMS else 1
    numba.set_num_threads(max(1, min(n, numba.config.NUMBA_NUM_THREADS)))  # type: ignore[attr-defined]  # set at run time
    if torch.get_num_threads() != n_torch:
        torch.set_num_threads(n_torch)
