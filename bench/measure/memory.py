"""Peak memory per keyframe window (CPU RSS, torch live bytes, the CUDA allocator).


The paper's headline is peak memory per keyframe window, so every figure here is a *peak inside a
window* (``start_window`` .. ``end_window``), in MiB (2**20 bytes), or ``None`` where it cannot be
measured on this machine.

``cpu_rss_peak_mib`` - the process's peak resident set, from the kernel. On Linux the window
    resets the high-water mark by writing ``5`` to ``/proc/self/clear_refs`` and reads ``VmHWM``
    from ``/proc/self/status`` at the end: exact, zero overhead, and it sees every allocation (torch,
    numpy, OpenCV, Python). The probe checks once that the reset really lowers ``VmHWM`` (it touches
    and frees 16 MiB, then resets); if the write is refused or has no effect (old kernels, some
    sandboxes) it falls back to a psutil sampler thread polling RSS every 5 ms, which can miss
    spikes shorter than that. ``rss_method`` records which: ``"vmhwm+clear_refs"``,
    ``"psutil-sampled"`` or ``"unavailable"``.

``torch_live_peak_mib`` - peak bytes held by torch's CPU allocator (tensor storages, autograd
    buffers, kernel temporaries), counted from the probe's creation: create the probe before the
    SLAM state is built. Why not RSS alone: RSS includes allocator caching and fragmentation and
    lags frees; the live figure isolates what the algorithm holds. Method (``torch_live_method``):

    * ``"profiler-memory"`` (default): a kineto profiler session with ``profile_memory=True`` and no
      CPU op activity (a non-CPU activity is requested, so no per-op RecordFunction callbacks are
      installed). c10's CPU allocator then reports each alloc/free (+/- bytes) from C++; the session
      is cycled at each window end, and the peak is the maximum running sum in time order after
      the window's start mark (two odd-sized allocations). Cost: a C++ append per allocation, and
      per window end the stop/restart plus a small cost per recorded event. Kineto
      prints a line or two per stop; fd 2 is silenced for the duration of that call only. Blocks
      allocated before the probe are unknown to it; c10 warns once when one is freed.
    * ``"dispatch-mode"`` (fallback when kineto is unavailable or another profiler is running):
      a ``TorchDispatchMode`` that records the storages of non-aliasing op outputs and subtracts
      them through weakref callbacks. Public API, but a Python call per aten op, and blind to
      kernel-internal temporaries.

    The overhead of each method is what ``profiling/probe_overhead.py`` reports: a cost per
    alloc/free event plus a fixed cost per window, so it shrinks as ops get larger. Pass
    ``torch_live=False`` to skip it (also when running ``torch.profiler`` yourself: only one
    profiler can be active). On CUDA devices the figure is
    ``None``: the CUDA allocator's own peak (below) is the exact equivalent there and costs nothing.

``cuda_alloc_peak_mib`` / ``cuda_reserved_peak_mib`` - ``torch.cuda.max_memory_allocated`` /
    ``max_memory_reserved`` after ``reset_peak_memory_stats`` at window start; ``None`` on CPU.
"""

from __future__ import annotations

import contextlib
import os
import random
import re
import sys
import threading
import weakref
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import torch

from bench.errors import ConfigError
from bench.schema import MIB

_STATUS = Path("/proc/self/status")
_CLEAR_REFS = Path("/proc/self/clear_refs")
_SAMPLE_PERIOD_S = 0.005


# ---------------------------------------------------------------------------------------------
# CPU RSS peak


def _read_status_kib() -> dict[str, int]:
    """``VmHWM``/``VmRSS`` from /proc/self/status, in KiB."""
    text = _STATUS.read_text()
    return {k: int(v) for k, v in re.findall(r"^(VmHWM|VmRSS):\s+(\d+)\s+kB", text, flags=re.M)}


def _reset_hwm() -> None:
    with _CLEAR_REFS.open("w") as f:
        f.write("5")


def _hwm_reset_works() -> bool:
    """Touch and free 16 MiB (so VmHWM sits above VmRSS), reset, and check VmHWM came down."""
    try:
        blob = b"\x01" * (16 * 2**20)  # written, so resident; freed via munmap below
        del blob
        before = _read_status_kib()
        _reset_hwm()
        after = _read_status_kib()
    except (OSError, ValueError):
        return False
    if "VmHWM" not in before or "VmHWM" not in after:
        return False
    if before["VmHWM"] - before["VmRSS"] >= 8 * 1024:  # a visible gap: the reset must close it
        return after["VmHWM"] < before["VmHWM"] - 8 * 1024
    return after["VmHWM"] <= after["VmRSS"] + 1024  # no gap to test: at least no stale peak


class _RssSampler:
    """Polls RSS in a daemon thread (psutil) and keeps the maximum since the last reset."""

    def __init__(self, period_s: float = _SAMPLE_PERIOD_S) -> None:
        import psutil

        self._proc = psutil.Process()
        self._period_s = period_s
        self._peak_b = self._proc.memory_info().rss
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="bench-rss-sampler", daemon=True)
        self._thread.start()

    def _sample(self) -> None:
        rss = self._proc.memory_info().rss
        with self._lock:
            self._peak_b = max(self._peak_b, rss)

    def _loop(self) -> None:
        while not self._stop.wait(self._period_s):
            self._sample()

    def reset(self) -> None:
        with self._lock:
            self._peak_b = 0
        self._sample()

    def peak_bytes(self) -> int:
        self._sample()
        with self._lock:
            return self._peak_b

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=1.0)


# ---------------------------------------------------------------------------------------------
# How the process holds memory it has freed (glibc's malloc)

MALLOC_POLICIES = ("retain", "system")
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3  # glibc's mallopt parameter numbers (malloc.h)
_MMAP_THRESHOLD_MAX_B = 4 * 1024 * 1024 * 8  # glibc's ceiling on 64-bit hosts: 32 MiB
_SYSTEM_THRESHOLD_B = 128 * 1024  # glibc's starting values of both thresholds


def set_malloc_policy(policy: str) -> str:
    """Apply ``memory.malloc`` to this process; returns what holds: the policy, or ``"unavailable"`` off glibc.

    ``retain``: blocks up to 32 MiB come from the heap (not a fresh ``mmap`` each) and a free never
    returns the heap's top to the kernel, so the next iteration's tensors of the same sizes reuse pages
    already mapped. With glibc's own thresholds a mapping iteration's per-Gaussian tensors (a few MiB
    each on a large map) were unmapped at their free and page-faulted in again at the next allocation,
    every iteration. What it changes: speed, and the RSS figures, which then read the heap's high-water
    (freed pages stay resident); the torch live bytes, the CPU headline peak, count allocations and
    frees and do not change. ``system``: glibc's starting thresholds (128 KiB; the dynamic adjustment
    glibc makes on its own is off once a threshold is set, so a process switches back only
    approximately).
    """
    if policy not in MALLOC_POLICIES:
        raise ConfigError(f"memory.malloc: expected one of {', '.join(MALLOC_POLICIES)}, found {policy!r}")
    import ctypes
    import ctypes.util

    name = ctypes.util.find_library("c")
    try:
        libc = ctypes.CDLL(name) if name else None
        mallopt = libc.mallopt if libc is not None else None
    except (OSError, AttributeError):
        mallopt = None
    if mallopt is None:
        return "unavailable"
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    mmap_b, trim_b = (
        (_MMAP_THRESHOLD_MAX_B, 2**31 - 1) if policy == "retain" else (_SYSTEM_THRESHOLD_B, _SYSTEM_THRESHOLD_B)
    )
    ok = mallopt(_M_MMAP_THRESHOLD, mmap_b) == 1 and mallopt(_M_TRIM_THRESHOLD, trim_b) == 1
    return policy if ok else "unavailable"


# ---------------------------------------------------------------------------------------------
# torch live-bytes peak


@contextlib.contextmanager
def _silenced_fd2() -> Iterator[None]:
    """Send fd 2 to /dev/null for a moment (kineto logs straight to the C stderr on start/stop)."""
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError, AttributeError):
        yield
        return
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)
        os.close(devnull)


class _ProfilerLive:
    """Live CPU-allocator bytes from kineto memory events (see module docstring)."""

    method = "profiler-memory"

    def __init__(self) -> None:
        from torch._C._profiler import ProfilerActivity, ProfilerConfig, ProfilerState, _ExperimentalConfig

        if not torch.autograd.kineto_available():
            raise RuntimeError("kineto not available")
        if torch.autograd._profiler_enabled():
            raise RuntimeError("another profiler is active")
        self._config = ProfilerConfig(ProfilerState.KINETO, False, True, False, False, False, _ExperimentalConfig())
        # Any non-CPU activity: keeps kineto's memory reporting, skips per-op callbacks.
        self._activities = {ProfilerActivity.XPU}
        # Window starts are marked in the event stream by allocating and freeing two buffers of
        # odd random sizes (+a, +b, -b, -a), so start_window needs no profiler stop/restart.
        rng = random.Random()
        self._marker_b = (rng.randrange(100_001, 130_000, 2), rng.randrange(130_001, 160_000, 2))
        self._pending_mark = False
        self.live_b = 0
        self.peak_b = 0
        self._running = False
        with _silenced_fd2():
            self._start()

    def _start(self) -> None:
        torch.autograd._prepare_profiler(self._config, self._activities)
        torch.autograd._enable_profiler(self._config, self._activities)
        self._running = True

    def _collect(self) -> None:
        """Stop, restart at once (no gap for this thread), then fold the events into the counters."""
        if not self._running:
            return
        with _silenced_fd2():
            result = torch.autograd._disable_profiler()
            self._running = False
            self._start()
        events = result.events()  # only memory events: no op activity was requested
        n, kineto_event = len(events), torch._C._autograd._KinetoEvent
        # [E] +alloc / -free; torch's stub of _KinetoEvent leaves out nbytes, which the class has
        nbytes = np.fromiter(map(kineto_event.nbytes, events), np.int64, n)  # type: ignore[attr-defined]
        start_ns = np.fromiter(map(kineto_event.start_ns, events), np.int64, n)  # [E]
        device_index = np.fromiter(map(kineto_event.device_index, events), np.int64, n)  # [E]
        nbytes[device_index >= 0] = 0  # CPU events carry index -1; CUDA/XPU allocators report >= 0
        if np.any(start_ns[1:] < start_ns[:-1]):  # several threads' queues: put them in time order
            nbytes = nbytes[np.argsort(start_ns, kind="stable")]
        if self._pending_mark:
            a, b = self._marker_b
            starts = np.flatnonzero(nbytes[:-3] == a) if len(nbytes) >= 4 else np.zeros(0, np.int64)
            hits = [i for i in starts if nbytes[i + 1] == b and nbytes[i + 2] == -b and nbytes[i + 3] == -a]
            cut = int(hits[-1]) + 4 if hits else 0  # no mark found: treat every event as in-window
            self.live_b += int(nbytes[:cut].sum())
            self.peak_b = self.live_b
            nbytes = nbytes[cut:]
            self._pending_mark = False
        if len(nbytes):
            running = self.live_b + np.cumsum(nbytes)  # [E] live bytes after each event
            self.peak_b = max(self.peak_b, int(running.max()))
            self.live_b = int(running[-1])

    def reset_peak(self) -> None:
        a, b = self._marker_b
        first = torch.empty(a, dtype=torch.uint8)
        second = torch.empty(b, dtype=torch.uint8)
        del second, first
        self._pending_mark = True

    def read_peak(self) -> int:
        self._collect()
        return self.peak_b

    def close(self) -> None:
        if self._running:
            with _silenced_fd2():
                torch.autograd._disable_profiler()
            self._running = False


class _DispatchLive:
    """Live bytes of CPU storages created by aten ops, through a ``TorchDispatchMode``."""

    method = "dispatch-mode"

    def __init__(self) -> None:
        from torch.utils._python_dispatch import TorchDispatchMode

        probe = self

        class _Mode(TorchDispatchMode):
            def __torch_dispatch__(self, func, types, args=(), kwargs=None):
                out = func(*args, **(kwargs or {}))
                probe._track(func, out)
                return out

        self.live_b = 0
        self.peak_b = 0
        self._refs: dict[int, weakref.ref] = {}
        self._fresh: dict[object, bool] = {}  # per op overload: do its outputs own new storage?
        self._mode = _Mode()
        self._mode.__enter__()

    def _release(self, key: int, nbytes: int):
        def callback(_ref: weakref.ref) -> None:
            self.live_b -= nbytes
            self._refs.pop(key, None)

        return callback

    def _track(self, func: object, out: object) -> None:
        fresh = self._fresh.get(func)
        if fresh is None:
            returns = func._schema.returns  # type: ignore[attr-defined]
            fresh = self._fresh[func] = not any(r.alias_info is not None for r in returns)
        if not fresh:
            return  # views and in-place ops return storage that exists already
        for t in out if isinstance(out, (tuple, list)) else (out,):
            if not isinstance(t, torch.Tensor) or t.device.type != "cpu":
                continue
            storage = t.untyped_storage()
            key = storage._cdata
            if key in self._refs:
                continue
            nbytes = storage.nbytes()
            self._refs[key] = weakref.ref(storage, self._release(key, nbytes))
            self.live_b += nbytes
            if self.live_b > self.peak_b:
                self.peak_b = self.live_b

    def reset_peak(self) -> None:
        self.peak_b = self.live_b

    def read_peak(self) -> int:
        return self.peak_b

    def close(self) -> None:
        self._mode.__exit__(None, None, None)


# ---------------------------------------------------------------------------------------------


class MemoryProbe:
    """Peak memory inside a window (one keyframe's mapping, say); see the module docstring."""

    rss_method: str
    torch_live_method: str

    def __init__(self, device: torch.device, torch_live: bool = True, *, live_method: str = "auto") -> None:
        """``live_method``: ``"auto"`` (profiler, else dispatch), ``"profiler-memory"`` or ``"dispatch-mode"``."""
        if live_method not in ("auto", _ProfilerLive.method, _DispatchLive.method):
            raise ConfigError(
                f"unknown live_method: expected auto, profiler-memory or dispatch-mode, found {live_method!r}"
            )
        self.device = torch.device(device)
        self._is_cuda = self.device.type == "cuda"
        self._sampler: _RssSampler | None = None
        if _STATUS.exists() and _hwm_reset_works():
            self.rss_method = "vmhwm+clear_refs"
        else:
            try:
                self._sampler = _RssSampler()
                self.rss_method = "psutil-sampled"
            except Exception:  # psutil missing or unsupported platform
                self.rss_method = "unavailable"
        self._live: _ProfilerLive | _DispatchLive | None = None
        self.torch_live_method = "off"
        if torch_live and not self._is_cuda:
            if live_method == _DispatchLive.method:
                self._live = _DispatchLive()
            elif live_method == _ProfilerLive.method:
                self._live = _ProfilerLive()  # raises if kineto is missing or busy
            else:
                try:
                    self._live = _ProfilerLive()
                except Exception:
                    self._live = _DispatchLive()
            self.torch_live_method = self._live.method
        self._closed = False
        self._held: dict[str, float | None] = {}  # peaks read before a pause, merged into the window's

    def start_window(self) -> None:
        """Reset every peak to the current level."""
        self._held = {}
        if self._is_cuda:
            torch.cuda.synchronize(self.device)
            torch.cuda.reset_peak_memory_stats(self.device)
        if self._live is not None:
            self._live.reset_peak()
        if self.rss_method == "vmhwm+clear_refs":
            _reset_hwm()
        elif self._sampler is not None:
            self._sampler.reset()

    def end_window(self) -> dict[str, float | None]:
        """Peaks since ``start_window`` in MiB: cpu_rss, torch_live, cuda_alloc, cuda_reserved."""
        out: dict[str, float | None] = {
            "cpu_rss_peak_mib": None,
            "torch_live_peak_mib": None,
            "cuda_alloc_peak_mib": None,
            "cuda_reserved_peak_mib": None,
        }
        if self._is_cuda:
            torch.cuda.synchronize(self.device)
            out["cuda_alloc_peak_mib"] = torch.cuda.max_memory_allocated(self.device) / MIB
            out["cuda_reserved_peak_mib"] = torch.cuda.max_memory_reserved(self.device) / MIB
        if self._live is not None:
            out["torch_live_peak_mib"] = self._live.read_peak() / MIB
        if self.rss_method == "vmhwm+clear_refs":
            out["cpu_rss_peak_mib"] = _read_status_kib()["VmHWM"] / 1024.0
        elif self._sampler is not None:
            out["cpu_rss_peak_mib"] = self._sampler.peak_bytes() / MIB
        for key, before in self._held.items():
            if before is not None:
                now = out[key]
                out[key] = before if now is None else max(before, now)
        return out

    @contextlib.contextmanager
    def paused(self) -> Iterator[None]:
        """Leave the work inside (a milestone evaluation) out of the window's peaks.

        The peaks up to the pause stand and the window goes on from the level after it, so what the
        work allocated and freed is never counted; what it leaves alive counts from then on.
        """
        held = self.end_window()
        try:
            yield
        finally:
            self.start_window()
            self._held = held

    def live_mib(self) -> float | None:
        """Bytes held now, in MiB, by the allocator the headline peak reads: CUDA's allocated bytes,
        or torch's live CPU tensors (as counted since the probe was made; call after ``end_window``,
        which folds the pending events in); None where neither is measured."""
        if self._is_cuda:
            return torch.cuda.memory_allocated(self.device) / MIB
        return None if self._live is None else self._live.live_b / MIB

    def close(self) -> None:
        """Stop the profiler session / dispatch mode / sampler thread; idempotent."""
        if self._closed:
            return
        self._closed = True
        if self._live is not None:
            self._live.close()
        if self._sampler is not None:
            self._sampler.close()

    def __enter__(self) -> MemoryProbe:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
