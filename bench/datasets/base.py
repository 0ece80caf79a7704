"""The types every dataset plugin produces, and the settings every dataset shares.

A dataset plugin is a callable registered in the ``pocketbench.datasets`` entry-point group:
``open_sequence(cfg) -> FrameSequence``, where ``cfg`` is the ``dataset`` config with ``seq`` (always a
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

from bench.config.settings import check_rules, setting
from bench.errors import ConfigError

MISSING_VALUE = "???"  # OmegaConf's marker for a setting that has no default


@dataclass
class DatasetConfig:
    """Settings every dataset has; each loader's config subclasses it and holds its own defaults."""

    name: str = setting(MISSING_VALUE, "str")
    seq: str | None = setting(None, "seq", nullable=True)  # always a string; None = the dataset's default sequence
    # eval.protocol=splatam scores the pixels whose observed depth lies strictly between these (the
    # authors' loader's depth_filter_near/far, bench/metrics/protocol.py); 0 and null: every pixel with depth
    eval_depth_near_m: float = setting(0.0, "float", lo=0.0)
    eval_depth_far_m: float | None = setting(None, "float", lo=0.0, lo_open=True, nullable=True)

    def __post_init__(self) -> None:
        check_rules(self, "dataset.")  # every field's rule, the subclasses' included
        if self.eval_depth_far_m is not None and self.eval_depth_far_m <= self.eval_depth_near_m:
            raise ConfigError(
                f"dataset.eval_depth_far_m: expected more than eval_depth_near_m "
                f"({self.eval_depth_near_m:g}), found {self.eval_depth_far_m:g}"
            )

    def default_sequence(self) -> str | None:
        """The sequence a run uses when none is named (recorded as ``run.seq``)."""
        return self.seq


@dataclass
class RecordedConfig(DatasetConfig):
    """A recorded dataset on disk: where it is, which frames, at what resolution."""

    root: str = setting(MISSING_VALUE, "str", nullable=True)  # holds the dataset's sequences; dataset.root=/path
    default_seq: str = setting(MISSING_VALUE, "seq", nullable=True)  # used when seq is None
    downscale: int = setting(1, "int", lo=1)  # integer block downscale of images and depth; K scaled to match
    first: int = setting(0, "int", lo=0)  # first frame index (0-based, before stride)
    last: int | None = setting(None, "int", lo=0, nullable=True)  # last frame index, inclusive; None = to the end
    stride: int = setting(1, "int", lo=1)  # take every stride-th frame
    # depth beyond this is set to 0; None keeps all
    max_depth_m: float | None = setting(None, "float", lo=0.0, lo_open=True, nullable=True)

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.last is not None and self.last < self.first:
            raise ConfigError(f"dataset frame range: expected first <= last, found first={self.first} last={self.last}")

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


class FrameSequence(ABC):
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


class TimedSequence(FrameSequence):
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
