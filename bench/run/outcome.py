"""What the frame loop leaves behind (``LoopOutcome``): written by ``bench.run.loop``, read by
``bench.run.evaluation`` and the lifecycle; its own module, so neither of the two imports the other for it."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import torch

from bench.run.signals import Interrupted


@dataclass
class LoopOutcome:
    """What the frame loop leaves behind."""

    status: str = "ok"  # ok | lost | interrupted | failed (bad data mid-run)
    error: str | None = None
    stop: Interrupted | None = None  # the signal that ended the loop, re-raised once the record is written
    timestamps_s: list[float] = field(default_factory=list)
    gt_c2w: list[torch.Tensor | None] = field(default_factory=list)
    windows: list[dict[str, Any]] = field(default_factory=list)  # the keyframes.csv rows
    loop_s: float = 0.0  # SLAM wall time after the warm-up frames
    warmup_s: float = 0.0  # the warm-up frames' time, left out of loop_s and fps
    tail: dict[str, Any] = field(default_factory=dict)  # peaks and map size of the frames after the last keyframe
