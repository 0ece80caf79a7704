"""The types every dataset plugin produces, and the settings every dataset shares.

A dataset plugin is a callable registered in the ``pocketbench.datasets`` entry-point group:
``open_sequence(cfg) -> Sequence``, where ``cfg`` is the ``dataset`` config with ``seq`` (always a
string) merged in: the loader's own ``DatasetConfig`` subclass for the built-in datasets (a plain
mapping is checked against it), a plain dict for a plugin without a registered schema.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from bench.errors import ConfigError

MISSING_VALUE = "???"  # OmegaConf's marker for a setting that has no default


@dataclass
class DatasetConfig:
    """Settings every dataset has; each loader's config subclasses it and holds its own defaults."""

    name: str = MISSING_VALUE
    seq: str | None = None  # always a string; None = the dataset's default sequence

    def default_sequence(self) -> str | None:
        """The sequence a run uses when none is named (recorded as ``run.seq``)."""
        return self.seq


@dataclass
class RecordedConfig(DatasetConfig):
    """A recorded dataset on disk: where it is, which frames, at what resolution."""

    root: str = MISSING_VALUE  # holds the dataset's sequences; override: dataset.root=/path
    default_seq: str = MISSING_VALUE  # used when seq is None
    downscale: int = 1  # integer block downscale of images and depth; K scaled to match
    first: int = 0  # first frame index (0-based, before stride)
    last: int | None = None  # last frame index, inclusive; None = to the end
    stride: int = 1  # take every stride-th frame
    max_depth_m: float | None = None  # depth beyond this is set to 0; None keeps all

    def __post_init__(self) -> None:
        for key, least in (("downscale", 1), ("first", 0), ("last", 0), ("stride", 1)):
            value = getattr(self, key)
            if value is not None and value < least:
                raise ConfigError(f"{self.name} {key}: expected an integer >= {least}, found {value}")
        if self.max_depth_m is not None and not self.max_depth_m > 0:
            raise ConfigError(f"{self.name} max_depth_m: expected a positive number or null, found {self.max_depth_m}")

    def default_sequence(self) -> str:
        seq = self.seq if self.seq is not None and str(self.seq).strip() else self.default_seq
        if seq is None or not str(seq).strip():
            raise ConfigError(f"{self.name}: expected a sequence in seq or default_seq, found none")
        return str(seq).strip()


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


class TimedSequence(Sequence):
    """A sequence known by its timestamps and optional ground truth; subclasses only load images.

    Holds what every built-in loader shares: the length, ``has_gt``, ``gt_poses``, the bounds
    check and the ``Frame`` assembly.
    """

    def __init__(self, name: str, timestamps_s: np.ndarray, gt_c2w: np.ndarray | None) -> None:
        self.name = name
        self.timestamps_s = np.asarray(timestamps_s, dtype=np.float64)  # [N]
        self._gt = gt_c2w  # [N, 4, 4] float64 camera-to-world, or None

    @abstractmethod
    def load(self, i: int) -> tuple[torch.Tensor, torch.Tensor]:
        """(rgb [H, W, 3] float32 in [0, 1], depth [H, W] float32 m) of frame ``i`` in range."""

    def __len__(self) -> int:
        return len(self.timestamps_s)

    @property
    def has_gt(self) -> bool:
        return self._gt is not None

    @property
    def gt_poses(self) -> torch.Tensor | None:
        """All ground-truth c2w [N, 4, 4] float64 without decoding any image (for evaluation)."""
        return None if self._gt is None else torch.from_numpy(self._gt.copy())

    def __getitem__(self, i: int) -> Frame:
        if not -len(self) <= i < len(self):
            raise IndexError(f"{self.name}: frame {i} out of range for {len(self)} frames")
        i %= len(self)
        rgb, depth = self.load(i)
        return Frame(
            index=i,
            timestamp_s=float(self.timestamps_s[i]),
            rgb=rgb,
            depth_m=depth,
            gt_c2w=None if self._gt is None else torch.from_numpy(self._gt[i].copy()),
        )
