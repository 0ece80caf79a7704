"""The types every dataset plugin produces.

A dataset plugin is a callable registered in the ``pocketbench.datasets`` entry-point group:
``open_sequence(cfg: Mapping[str, Any]) -> Sequence``, where ``cfg`` is the resolved
``dataset`` config group with ``seq`` (always a string) merged in.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import torch


@dataclass
class Frame:
    """One RGB-D observation; ground truth rides along for evaluation only."""

    index: int  # position in the (range/stride-selected) sequence, 0-based
    timestamp_s: float
    rgb: torch.Tensor  # [H, W, 3] float32 in [0, 1]; grayscale sources are replicated
    depth_m: torch.Tensor  # [H, W] float32 metres; 0 where invalid
    gt_c2w: torch.Tensor | None  # [4, 4] float64 camera-to-world, or None without ground truth


class Sequence(ABC):
    """A finite, indexable stream of frames from one calibrated camera."""

    name: str  # e.g. "kitti/06"
    K: torch.Tensor  # [3, 3] float32 pinhole intrinsics at the delivered resolution
    height: int
    width: int
    # Files the frames are read from (calibration, lists, ground truth, images): the resume key
    # fingerprints them, so a run over a fixed file is redone. Empty for generated data.
    source_files: tuple[Path, ...] = ()

    @abstractmethod
    def __len__(self) -> int: ...

    @abstractmethod
    def __getitem__(self, i: int) -> Frame: ...

    @property
    def has_gt(self) -> bool:
        """Whether frames carry ground-truth poses (KITTI 11-21 do not)."""
        return True

    def __iter__(self) -> Iterator[Frame]:
        for i in range(len(self)):
            yield self[i]
