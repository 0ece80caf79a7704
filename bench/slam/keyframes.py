"""A keyframe as the map's store holds it: its image, depth and pose."""

from __future__ import annotations

from dataclasses import dataclass

import torch


@dataclass
class Keyframe:
    index: int
    rgb: torch.Tensor  # [H, W, 3]
    depth: torch.Tensor  # [H, W]
    w2c: torch.Tensor  # [4, 4]


def torch_owned(rgb: torch.Tensor) -> torch.Tensor:
    """The keyframe store holds its images in torch's allocator, as on a GPU (where .to() copies): on CPU
    ``rgb`` may be the dataset's numpy-backed frame (synthetic), a storage torch did not allocate (not
    resizable), which the live-tensor peak would never see."""
    return rgb if rgb.untyped_storage().resizable() else rgb.clone()
