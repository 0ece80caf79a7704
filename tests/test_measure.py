"""Memory probe windows, exact tensor bytes, phase timer."""

from __future__ import annotations

import mmap
import subprocess
import sys
import time

import pytest
import torch

import bench.measure.memory as measure
from bench.errors import ConfigError
from bench.measure.memory import MemoryProbe
from bench.measure.timing import PhaseTimer
from bench.slam.gaussians import tensor_bytes

BIG_MIB = 200
CPU = torch.device("cpu")


def _window(probe: MemoryProbe, alloc_mib: int = 0, hold_s: float = 0.0) -> dict[str, float | None]:
    """One window; optionally allocate (and write, so it is resident) a tensor and free it inside."""
    probe.start_window()
    if alloc_mib:
        big = torch.ones(alloc_mib * 2**20 // 4)  # [n] float32, pages touched
        if hold_s:
            time.sleep(hold_s)
        del big
    return probe.end_window()


def _mmap_window(probe: MemoryProbe, alloc_mib: int, hold_s: float) -> dict[str, float | None]:
    """A window holding fresh anonymous pages: unlike a malloc'd tensor, they cannot reuse memory an
    earlier test freed but the allocator kept resident (seen in CI: a 200 MiB tensor moved RSS by 0)."""
    probe.start_window()
    blob = mmap.mmap(-1, alloc_mib * 2**20)
    blob.write(b"\x01" * len(blob))  # touched, so resident
    time.sleep(hold_s)
    blob.close()  # munmap: RSS drops at once
    return probe.end_window()


def _check_big_window_rises(probe: MemoryProbe, rss_resets: bool) -> None:
    """The tensor window checks the torch-live peak; RSS is checked on fresh mmap pages, because a
    malloc'd tensor may reuse pages an earlier test freed but the allocator kept resident (seen in
    CI twice: a 200 MiB tensor moved RSS by 0 once the suite had run long enough)."""
    empty = _window(probe)
    big = _window(probe, BIG_MIB, hold_s=0.03)
    after = _window(probe)
    assert big["torch_live_peak_mib"] - empty["torch_live_peak_mib"] >= 190
    assert after["torch_live_peak_mib"] < empty["torch_live_peak_mib"] + 10
    assert big["cuda_alloc_peak_mib"] is None and big["cuda_reserved_peak_mib"] is None
    empty = _window(probe)
    big = _mmap_window(probe, BIG_MIB, hold_s=0.03)
    after = _window(probe)
    assert big["cpu_rss_peak_mib"] - empty["cpu_rss_peak_mib"] >= 190
    if rss_resets:
        assert after["cpu_rss_peak_mib"] < big["cpu_rss_peak_mib"] - 150


@pytest.mark.parametrize("method", ["profiler-memory", "dispatch-mode"])
def test_window_peaks_follow_a_big_allocation(method: str) -> None:
    with MemoryProbe(CPU, live_method=method) as probe:
        assert probe.torch_live_method == method
        _check_big_window_rises(probe, rss_resets=probe.rss_method == "vmhwm+clear_refs")


@pytest.mark.parametrize("method", ["profiler-memory", "dispatch-mode"])
def test_live_bytes_held_across_windows_stay_counted(method: str) -> None:
    with MemoryProbe(CPU, live_method=method) as probe:
        base = _window(probe)["torch_live_peak_mib"]
        probe.start_window()
        kept = torch.zeros(16 * 2**20 // 4)  # [n] float32, 16 MiB, kept past the window
        first = probe.end_window()["torch_live_peak_mib"]
        second = _window(probe)["torch_live_peak_mib"]
        assert first - base == pytest.approx(16, abs=0.5)
        assert second - base == pytest.approx(16, abs=0.5)  # still live, so still the floor
        del kept
        assert _window(probe)["torch_live_peak_mib"] == pytest.approx(base, abs=0.5)


@pytest.mark.parametrize("method", ["profiler-memory", "dispatch-mode"])
def test_autograd_buffers_are_counted(method: str) -> None:
    """Backward allocates gradients and frees saved activations: the peak sees them."""
    w = torch.randn(2**20, requires_grad=True)  # 4 MiB parameter, made before the probe
    with MemoryProbe(CPU, live_method=method) as probe:
        probe.start_window()
        loss = (w.exp() * 2).sin().sum()  # saves ~4 MiB activations per op
        loss.backward()
        peak = probe.end_window()["torch_live_peak_mib"]
    assert 8 <= peak <= 40


def test_rss_falls_back_to_sampler(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(measure, "_hwm_reset_works", lambda: False)
    with MemoryProbe(CPU, torch_live=False) as probe:
        assert probe.rss_method == "psutil-sampled"
        empty = _window(probe)
        big = _mmap_window(probe, BIG_MIB, hold_s=0.05)  # held for 10 sampling periods
        after = _window(probe)
    assert empty["torch_live_peak_mib"] is None
    assert big["cpu_rss_peak_mib"] - empty["cpu_rss_peak_mib"] >= 190
    assert after["cpu_rss_peak_mib"] < big["cpu_rss_peak_mib"] - 150


def test_torch_live_off_and_busy_profiler_fallback() -> None:
    with MemoryProbe(CPU, torch_live=False) as off:
        assert off.torch_live_method == "off"
        assert _window(off)["torch_live_peak_mib"] is None
    with torch.profiler.profile(activities=[torch.profiler.ProfilerActivity.CPU]):
        busy = MemoryProbe(CPU)  # only one profiler at a time: falls back
        try:
            assert busy.torch_live_method == "dispatch-mode"
            assert _window(busy)["torch_live_peak_mib"] is not None
        finally:
            busy.close()
            busy.close()  # idempotent


def test_unknown_live_method() -> None:
    with pytest.raises(ConfigError, match="unknown live_method"):
        MemoryProbe(CPU, live_method="magic")


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_cuda_peaks() -> None:
    dev = torch.device("cuda")
    with MemoryProbe(dev) as probe:
        assert probe.torch_live_method == "off"
        empty = _window_cuda(probe, dev, 0)
        big = _window_cuda(probe, dev, BIG_MIB)
        after = _window_cuda(probe, dev, 0)
    assert big["cuda_alloc_peak_mib"] - empty["cuda_alloc_peak_mib"] >= 190
    assert big["cuda_reserved_peak_mib"] >= big["cuda_alloc_peak_mib"]
    assert after["cuda_alloc_peak_mib"] < big["cuda_alloc_peak_mib"] - 150
    assert big["torch_live_peak_mib"] is None


def _window_cuda(probe: MemoryProbe, dev: torch.device, mib: int) -> dict[str, float | None]:
    probe.start_window()
    if mib:
        x = torch.ones(mib * 2**20 // 4, device=dev)
        del x
    return probe.end_window()


def test_tensor_bytes_exact() -> None:
    ts = [
        torch.zeros(1000, 3),  # float32
        torch.zeros(7, dtype=torch.float64),
        torch.zeros(5, 2, dtype=torch.uint8),
        torch.zeros(3, dtype=torch.bool),
        torch.zeros(0, 4),
    ]
    assert tensor_bytes(ts) == 1000 * 3 * 4 + 7 * 8 + 10 + 3 + 0
    assert tensor_bytes(t for t in ts[:1]) == 12_000
    assert tensor_bytes([]) == 0


def test_phase_timer_sums_per_phase() -> None:
    timer = PhaseTimer(CPU)
    for _ in range(2):
        with timer.phase("tracking"):
            time.sleep(0.02)
    with timer.phase("mapping"):
        time.sleep(0.01)
    with pytest.raises(RuntimeError), timer.phase("mapping"):
        raise RuntimeError("boom")  # time up to the exception still counts
    totals = timer.totals()
    assert list(totals) == ["tracking", "mapping"]
    assert 0.04 <= totals["tracking"] < 0.5
    assert 0.01 <= totals["mapping"] < 0.5
    assert timer.counts() == {"tracking": 2, "mapping": 2}
    timer.reset()
    assert timer.totals() == {} and timer.counts() == {}


@pytest.mark.parametrize("method", ["profiler-memory", "dispatch-mode"])
def test_a_paused_stretch_is_left_out_of_the_window_peak(method: str) -> None:
    """A milestone evaluation inside a keyframe window must not become that window's peak, while
    what the window held before the pause still counts."""
    with MemoryProbe(CPU, live_method=method) as probe:
        base = _window(probe)["torch_live_peak_mib"]
        probe.start_window()
        before = torch.ones(32 * 2**20 // 4)  # [n] float32, 32 MiB, freed before the pause
        del before
        with probe.paused():
            inside = torch.ones(BIG_MIB * 2**20 // 4)  # [n] float32, freed inside the pause
            del inside
        peak = probe.end_window()["torch_live_peak_mib"]
        assert peak - base == pytest.approx(32, abs=1)
        assert _window(probe)["torch_live_peak_mib"] - base < 1  # the next window starts clean


_REUSE_PROBE = """
import resource, sys, torch
from bench.measure.memory import set_malloc_policy
print(set_malloc_policy(sys.argv[1]))
torch.set_num_threads(1)
faults = []
for _ in range(20):  # an iteration's worth of tensors of a few sizes, each written, freed in another order
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    t = torch.empty(4 * 2**20).fill_(1.0)  # [4 Mi] float32, 16 MiB
    u = torch.empty(3 * 2**20).fill_(2.0)  # 12 MiB
    del t
    w = torch.empty(5 * 2**20).fill_(3.0)  # 20 MiB
    del u, w
    faults.append(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
print(sum(faults[10:]))
"""


@pytest.mark.skipif(sys.platform != "linux", reason="glibc's mallopt")
def test_malloc_retain_reuses_freed_pages_and_system_faults_them_in_again() -> None:
    """``memory.malloc``: under ``retain`` the tensors of later iterations reuse the pages the earlier ones
    freed (after a few iterations, no page fault); under ``system`` each is a fresh mapping (a fault a page)."""
    faults = {}
    for policy in ("retain", "system"):
        out = subprocess.run(
            [sys.executable, "-c", _REUSE_PROBE, policy], capture_output=True, text=True, check=True
        ).stdout.split()
        assert out[0] == policy
        faults[policy] = int(out[1])
    pages = 10 * 48 * 2**20 // mmap.PAGESIZE  # written in the last 10 iterations
    assert faults["retain"] < pages // 100 and faults["system"] > pages // 2, faults


def test_malloc_policy_rejects_an_unknown_name() -> None:
    with pytest.raises(ConfigError, match="memory.malloc: expected one of retain, system, found 'lazy'"):
        measure.set_malloc_policy("lazy")
