"""The keyframe store: each keyframe's image, depth and pose, held under a policy (``slam.keyframes.*``).

Why a policy: the store is the part of the peak no pruning strategy touches (reports/scale), and the
large 3DGS-SLAM systems bound it in three ways, each an option here that changes only what it names:

- ``precision``: ``float32`` (as observed), or ``compact``: colour as uint8 and depth as float16, as
  DROID-Splat keeps its keyframe images. 5 bytes a pixel instead of 16. The rounding it brings: colour
  in steps of 1/255 (error at most 0.5/255 for colour in [0, 1], values outside clamped), depth with
  a relative error of at most 2**-11 (about 4.9e-4; float16's 11-bit significand) and exact zeros (no depth).
- ``window``: keep only the K newest keyframes (older ones dropped from memory and disk). Whatever reads
  keyframes can only read those held: the mapping window draws from them (a ``slam.mapping_window``
  longer than K acts as K), the final refinement samples them instead of every keyframe of the drive, and
  a prune's score views (``PruneContext.render_views``) render them. Keyframe numbers (``kf``) keep counting
  over the drive, so the keyframes.csv ``kf`` column and a Gaussian's birth keyframe mean the same as without
  a window; ``score_views`` names the views actually used.
- ``submap_reset_m`` / ``submap_reset_deg``: a new submap once a keyframe is farther than this from the
  submap's first keyframe (camera centres), or turned more than this from it, as Gaussian-SLAM and LoopSplat
  start one after 0.5 m or 50 degrees: the store then drops every keyframe it holds and starts over
  with the new one. Only the keyframes go; the Gaussians stay one map (moving them out is map
  residency's part). What reads keyframes reads the current submap's, as with a window.
- ``residency``: ``memory``, or ``disk``: each keyframe's (stored-precision) images go to one file in the
  run's ``keyframe_store/`` when the keyframe is made, and are read back each time something draws it (a
  mapping or refinement iteration, a score view); in memory stay its pose, frame and keyframe number,
  as RTG-SLAM keeps keyframes off the device until an optimisation uses them.

Callers never see the stored dtype or where it lives: ``Keyframe.images()`` (and the ``rgb`` and ``depth``
properties) give float32 tensors on the pose's device. With every option at its default (float32,
no window, memory) the stored tensors are returned as they are, so a run is bit-identical to one
without the policy.
"""

from __future__ import annotations

import math
import shutil
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import overload

import torch

from bench.config.settings import check_rules, setting
from bench.errors import ConfigError
from bench.slam.se3 import inverse, so3_log

PRECISIONS = ("float32", "compact")  # slam.keyframes.precision
RESIDENCIES = ("memory", "disk")  # slam.keyframes.residency
STORE_DIR = "keyframe_store"  # under the run dir, with residency=disk


@dataclass
class KeyframeStoreConfig:
    """``slam.keyframes.*``: how the keyframe store holds its keyframes (see the module docstring)."""

    precision: str = setting("float32", "str", choices=PRECISIONS)
    window: int | None = setting(None, "int", lo=1, nullable=True)  # the K newest keyframes held; None = all
    residency: str = setting("memory", "str", choices=RESIDENCIES)
    # a new submap (the store cleared) past this distance or turn from the submap's first keyframe; None = never
    submap_reset_m: float | None = setting(None, "float", lo=0.0, lo_open=True, nullable=True)
    submap_reset_deg: float | None = setting(None, "float", lo=0.0, lo_open=True, nullable=True)

    def __post_init__(self) -> None:
        check_rules(self, "slam.keyframes.")


@dataclass
class Keyframe:
    """One keyframe; ``rgb_stored``/``depth_stored`` are as the store keeps them (None while on disk):
    read them through ``images()``."""

    index: int  # frame index
    rgb_stored: torch.Tensor | None  # [H, W, 3] float32 or uint8
    depth_stored: torch.Tensor | None  # [H, W] float32 or float16
    w2c: torch.Tensor  # [4, 4]
    kf: int = 0  # keyframe number over the drive (the store's count when it was made)
    path: Path | None = None  # its file, with residency=disk

    def images(self) -> tuple[torch.Tensor, torch.Tensor]:
        """(rgb [H, W, 3], depth [H, W]) as float32 on the pose's device, read from disk if it lives there."""
        if self.path is None:
            assert self.rgb_stored is not None and self.depth_stored is not None
            rgb, depth = self.rgb_stored, self.depth_stored
        else:
            saved = torch.load(self.path, map_location=self.w2c.device, weights_only=True)
            rgb, depth = saved["rgb"], saved["depth"]
        return expand(rgb, depth)

    @property
    def rgb(self) -> torch.Tensor:  # [H, W, 3] float32
        return self.images()[0]

    @property
    def depth(self) -> torch.Tensor:  # [H, W] float32
        return self.images()[1]

    def memory_bytes(self) -> int:
        """Bytes this keyframe holds in memory: its stored images (none while on disk) and its pose."""
        held = (t for t in (self.rgb_stored, self.depth_stored, self.w2c) if t is not None)
        return sum(t.numel() * t.element_size() for t in held)


def compact(rgb: torch.Tensor, depth: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """float32 images -> (uint8 colour [H, W, 3], float16 depth [H, W]); ``expand`` undoes it up to the
    rounding the module docstring states."""
    return (rgb.clamp(0, 1) * 255).round().to(torch.uint8), depth.to(torch.float16)


def expand(rgb: torch.Tensor, depth: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Stored images -> float32; float32 ones are returned as they are (no copy)."""
    if rgb.dtype == torch.uint8:
        rgb = rgb.to(torch.float32) / 255
    return rgb, depth.to(torch.float32)


def torch_owned(rgb: torch.Tensor) -> torch.Tensor:
    """The keyframe store holds its images in torch's allocator, as on a GPU (where .to() copies): on CPU
    ``rgb`` may be the dataset's numpy-backed frame (synthetic), a storage torch did not allocate (not
    resizable), which the live-tensor peak would never see."""
    return rgb if rgb.untyped_storage().resizable() else rgb.clone()


class KeyframeStore(Sequence[Keyframe]):
    """The keyframes held, oldest first, under ``KeyframeStoreConfig``; ``n_made`` counts every keyframe made.

    Indexing and ``len`` are over the keyframes held (all of them without a window)."""

    def __init__(self, cfg: KeyframeStoreConfig, folder: Path | None = None) -> None:
        if cfg.residency == "disk" and folder is None:
            raise ConfigError(
                "slam.keyframes.residency=disk: expected a folder for the keyframe store (a run dir), found none"
            )
        self.cfg, self.folder = cfg, folder if cfg.residency == "disk" else None
        self.n_made = 0
        self._held: list[Keyframe] = []
        self._file_bytes: dict[int, int] = {}  # kf -> bytes of its file (residency=disk)
        self.submap_anchor: torch.Tensor | None = None  # [4, 4] w2c of the current submap's first keyframe
        self._clear_folder()

    def add(
        self, index: int, rgb: torch.Tensor, depth: torch.Tensor, w2c: torch.Tensor, kf: int | None = None
    ) -> Keyframe:
        """Store a keyframe (``rgb`` [H, W, 3], ``depth`` [H, W] float32 as observed); the oldest goes when
        the window is full. ``kf``: its number (a resume's), else the next."""
        number = self.n_made if kf is None else kf
        self.n_made = max(self.n_made, number + 1)
        if kf is None and self._new_submap(w2c):
            for old in self._held:
                self._drop(old)
            self._held = []
        if self.cfg.precision == "compact":
            rgb, depth = compact(rgb, depth)
        else:
            rgb = torch_owned(rgb)
        path = None
        stored: tuple[torch.Tensor | None, torch.Tensor | None] = (rgb, depth)
        if self.folder is not None:
            path = self.folder / f"kf_{number:05d}.pt"
            torch.save({"rgb": rgb.cpu(), "depth": depth.cpu()}, path)
            self._file_bytes[number] = path.stat().st_size
            stored = (None, None)
        keyframe = Keyframe(index, stored[0], stored[1], w2c, number, path)
        self._held.append(keyframe)
        if self.cfg.window is not None and len(self._held) > self.cfg.window:
            self._drop(self._held.pop(0))
        return keyframe

    def _new_submap(self, w2c: torch.Tensor) -> bool:
        """Whether ``w2c`` starts a new submap (the first keyframe starts one); it becomes the anchor if so."""
        m, deg = self.cfg.submap_reset_m, self.cfg.submap_reset_deg
        if m is None and deg is None:
            return False
        if self.submap_anchor is not None:
            rel = w2c @ inverse(self.submap_anchor)  # the anchor camera in the new one's frame
            far = m is not None and float(rel[:3, 3].norm()) > m
            if not far and not (deg is not None and math.degrees(float(so3_log(rel[:3, :3]).norm())) > deg):
                return False
        self.submap_anchor = w2c.detach().clone()
        return True

    def _drop(self, keyframe: Keyframe) -> None:
        if keyframe.path is not None:
            keyframe.path.unlink(missing_ok=True)
            self._file_bytes.pop(keyframe.kf, None)

    def _clear_folder(self) -> None:
        """An empty folder: files of an earlier start of this run are not this store's."""
        if self.folder is not None:
            shutil.rmtree(self.folder, ignore_errors=True)
            self.folder.mkdir(parents=True)

    def restore(
        self,
        count: int,
        held: list[tuple[int, int, torch.Tensor]],
        images: Callable[[int], tuple[torch.Tensor, torch.Tensor]],
    ) -> None:
        """A checkpoint's store: ``held`` as (kf, frame index, w2c), images re-read by ``images(frame index)``
        and stored again (for residency=disk, files written again), so it matches the store the
        checkpoint was taken from byte for byte. The submap anchor is the checkpoint's to set (``submap_anchor``)."""
        self._held, self._file_bytes = [], {}
        self._clear_folder()
        for kf, index, w2c in held:
            rgb, depth = images(index)
            self.add(index, rgb, depth, w2c, kf)
        self.n_made = count

    def close(self) -> None:
        """Remove the on-disk store (the run is over; a resume writes it again from the sequence)."""
        if self.folder is not None:
            shutil.rmtree(self.folder, ignore_errors=True)
        self._file_bytes = {}

    def memory_bytes(self) -> int:
        """Exact bytes the store holds in memory: stored images (at their stored dtype) and poses (the
        submap's first pose included)."""
        anchor = 0 if self.submap_anchor is None else self.submap_anchor.numel() * self.submap_anchor.element_size()
        return int(sum(kf.memory_bytes() for kf in self._held) + anchor)

    def disk_bytes(self) -> int:
        """Exact bytes of the store's files on disk (0 with residency=memory)."""
        return int(sum(self._file_bytes.values()))

    def __len__(self) -> int:
        return len(self._held)

    @overload
    def __getitem__(self, i: int) -> Keyframe: ...

    @overload
    def __getitem__(self, i: slice) -> list[Keyframe]: ...

    def __getitem__(self, i: int | slice) -> Keyframe | list[Keyframe]:
        return self._held[i]

    def __iter__(self) -> Iterator[Keyframe]:
        return iter(self._held)
