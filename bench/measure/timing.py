"""Wall time per SLAM phase (tracking, mapping, densification, pruning, refinement) of one run."""

from __future__ import annotations

import contextlib
import time
from collections.abc import Iterator

import torch


class PhaseTimer:
    """Wall-clock seconds per named phase, summed over calls; CUDA work is synchronised at both ends.

    Without the synchronisation, asynchronous kernels would be billed to whichever phase next
    waits on the GPU.
    """

    def __init__(self, device: torch.device | str = "cpu") -> None:
        self.device = torch.device(device)
        self._totals_s: dict[str, float] = {}
        self._counts: dict[str, int] = {}

    def _sync(self) -> None:
        if self.device.type == "cuda":
            torch.cuda.synchronize(self.device)

    @contextlib.contextmanager
    def phase(self, name: str) -> Iterator[None]:
        """Time the block under ``name`` (nested phases each count their own full duration)."""
        self._sync()
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self._sync()
            self._totals_s[name] = self._totals_s.get(name, 0.0) + time.perf_counter() - t0
            self._counts[name] = self._counts.get(name, 0) + 1

    def totals(self) -> dict[str, float]:
        """Seconds per phase, in first-use order."""
        return dict(self._totals_s)

    def counts(self) -> dict[str, int]:
        """How many times each phase ran."""
        return dict(self._counts)

    def restore(self, totals_s: dict[str, float], counts: dict[str, int]) -> None:
        """Continue from the totals of a run resumed from a checkpoint."""
        self._totals_s, self._counts = dict(totals_s), dict(counts)

    def reset(self) -> None:
        self._totals_s.clear()
        self._counts.clear()
