"""The inverse of a 2D screen covariance, shared by both rasterizer backends.

In a module of its own (torch only) so that the torch backend needs no numba, and the fused kernels'
warm-up needs no import of ``bench.slam.raster``."""

from __future__ import annotations

import torch


def conic(a: torch.Tensor, b: torch.Tensor, c: torch.Tensor) -> torch.Tensor:
    """[N, 3] (a', b', c') of the inverse of the covariances [[a, b], [b, c]] (each [N]); differentiable.

    A non-positive determinant (such a Gaussian is culled) divides by 1 instead, so no inf or nan
    reaches autograd."""
    det = a * c - b * b
    det_safe = torch.where(det > 0, det, torch.ones_like(det))
    return torch.stack([c / det_safe, -b / det_safe, a / det_safe], -1)
