"""What ``System``'s halves (``Tracking``, ``Mapping``, ``PruneDiagnostics``) read and call on ``self``.

``System`` (``bench.slam.system``) sets these attributes in its ``__init__`` and defines the methods
declared here; the declarations give them types for the halves. Annotations only: at run time this
class holds no attribute and no method.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import random

    import numpy as np
    import torch

    from bench.slam.config import SlamConfig
    from bench.slam.frontend import FlowPnpConfig
    from bench.slam.gaussians import GaussianMap
    from bench.slam.keyframes import KeyframeStore
    from bench.slam.lost import LostDetector
    from bench.slam.raster import RasterOutput
    from bench.slam.residency import MapResidency
    from bench.slam.strategy import PruneConfig, PruneContext, Strategy


class SystemState:
    """The state of one run that the halves of ``System`` share (set in ``System.__init__``)."""

    cfg: SlamConfig
    strategy: Strategy
    prune: PruneConfig
    keep_ratio: float
    device: torch.device
    K: torch.Tensor  # [3, 3]
    H: int
    W: int
    map: GaussianMap
    _map_grad2d: bool
    keyframes: KeyframeStore
    poses: list[torch.Tensor]
    frames_since_kf: int
    lost: LostDetector
    _rng: random.Random
    _densify_rng: np.random.Generator
    _ransac_rng: np.random.Generator
    _pix: torch.Tensor  # [H, W, 2]
    _flow_cfg: FlowPnpConfig
    _gray: np.ndarray | None
    _prev_obs: tuple | None
    init_source: list[str]
    _features: tuple[torch.Tensor, torch.Tensor] | None
    on_prune: Callable[[int, torch.Tensor, RasterOutput, torch.Tensor | None], None] | None
    _holes: list[np.ndarray]
    _reseeded: int
    _densify_dropped: int  # candidate pixels the last densification's budget and cap left out
    _cap_removed: int  # Gaussians the last densification removed to make room at the cap
    _densify_start: int | None  # the map's size after keyframe 0 (slam.densify.budget=taming's start)
    track_log: list[tuple[int, float, float, float]]
    _residency: MapResidency | None

    if TYPE_CHECKING:
        # defined by System (render) and by the other halves (_depth_l1 in Tracking, _count_in_holes in
        # PruneDiagnostics, _prune_context in System)
        def render(
            self,
            w2c: torch.Tensor,
            stats: bool = False,
            training: bool = False,
            iteration: int = 0,
            extra: frozenset[str] = frozenset(),
        ) -> RasterOutput: ...

        def _depth_l1(
            self, out: RasterOutput, depth: torch.Tensor, mask: torch.Tensor | None = None
        ) -> torch.Tensor: ...

        def _count_in_holes(self, sel: torch.Tensor, depth: torch.Tensor, w2c: torch.Tensor) -> int: ...

        def _prune_context(
            self,
            kf_idx: int,
            out: RasterOutput,
            is_new: torch.Tensor,
            candidates: torch.Tensor,
        ) -> PruneContext: ...
