"""The pruning-strategy contract and its entry-point registry (gsplat ``strategy/`` style).

A strategy is a ``@dataclass`` of typed hyperparameters plus hooks. The core owns every
per-Gaussian tensor; a strategy reads a context and returns data (a keep mask, a loss term,
a render mask). It may write only into its own entries of ``ctx.state`` (declared by
``state_spec``), and it never touches the optimizer: removal goes through
``GaussianMap.remove``, which keeps Adam moments and state aligned.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any, ClassVar

import torch

from bench import registry
from bench.errors import ConfigError, StrategyError
from bench.slam.gaussians import GaussianMap, ParamSpec
from bench.slam.raster import RasterOutput

GROUP = "pocketbench.strategies"


@dataclass(frozen=True)
class TrackingContext:
    """After a frame's tracking: what the last tracking iteration saw."""

    frame_index: int
    keyframe_index: int  # keyframes so far (the next keyframe will have this index)
    gaussians: GaussianMap  # read-only view
    state: dict[str, torch.Tensor]  # per-Gaussian, [N, ...], owned by the core
    raster: RasterOutput  # stats=True outputs at the tracked pose
    grad_norm: torch.Tensor  # [N] g_i = ||dL/dG_i|| over all Gaussian parameters


@dataclass(frozen=True)
class MappingContext:
    """One mapping iteration, before the backward pass."""

    keyframe_index: int
    iteration: int
    gaussians: GaussianMap
    state: dict[str, torch.Tensor]
    training: bool  # False when rendering for tracking or evaluation


@dataclass(frozen=True)
class PruneContext:
    """After a keyframe's mapping has converged, rendered at the keyframe's pose."""

    keyframe_index: int
    gaussians: GaussianMap
    state: dict[str, torch.Tensor]
    raster: RasterOutput  # stats=True outputs of the current keyframe
    track_grad_mean: torch.Tensor  # [N] mean g_i over tracking steps since the previous keyframe
    is_new: torch.Tensor  # [N] bool, added in this mapping round (exempt from pruning)
    candidates: torch.Tensor  # [N] bool, centre in this keyframe's image, in front, not new
    keep_ratio: float  # fraction of candidates to keep (shared by all strategies)
    image_hw: tuple[int, int]

    @property
    def n_target(self) -> int:
        """N_tar = keep_ratio * N_init, N_init being the candidates before pruning."""
        return int(math.ceil(self.keep_ratio * int(self.candidates.sum())))


@dataclass
class Strategy:
    """Base class: every hook is a no-op, so ``none`` is the empty subclass."""

    description: ClassVar[str] = ""

    def state_spec(self) -> dict[str, torch.dtype]:
        """Per-Gaussian state entries this strategy writes (zero-initialised for new Gaussians)."""
        return {}

    def extra_params(self) -> dict[str, ParamSpec]:
        """Per-Gaussian learnable parameters the core should own and optimise in mapping."""
        return {}

    def on_tracking_step(self, ctx: TrackingContext) -> None:
        """Accumulate statistics from a tracked frame."""

    def render_mask(self, ctx: MappingContext) -> torch.Tensor | None:
        """[N] multiplier on opacity (differentiable in training); None renders everything."""
        return None

    def masked_count(self, gaussians: GaussianMap, state: dict[str, torch.Tensor]) -> int:
        """Gaussians kept in memory but hidden from rendering (reported in keyframes.csv)."""
        return 0

    def mapping_loss(self, ctx: MappingContext) -> torch.Tensor | None:
        """Extra loss term added to the mapping objective."""
        return None

    def after_mapping(self, ctx: PruneContext) -> torch.Tensor | None:
        """[N] bool keep mask; None keeps everything."""
        return None


def top_k_keep(score: torch.Tensor, candidates: torch.Tensor, k: int) -> torch.Tensor:
    """Keep all non-candidates plus the ``k`` best-scoring candidates (the shared global rule)."""
    keep = ~candidates
    idx = candidates.nonzero().flatten()
    if idx.numel() and k > 0:
        best = idx[torch.topk(score[idx], min(k, idx.numel())).indices]
        keep = keep.clone()
        keep[best] = True
    return keep


def available() -> list[str]:
    return registry.available(GROUP)


def load_strategy(name: str, params: dict[str, Any] | None = None) -> Strategy:
    """Instantiate strategy ``name`` from the entry points with hyperparameters ``params``."""
    cls = registry.load(GROUP, "strategy", name, StrategyError)
    if not (isinstance(cls, type) and issubclass(cls, Strategy) and dataclasses.is_dataclass(cls)):
        raise StrategyError(f"strategy '{name}' must be a @dataclass subclass of bench.strategy.Strategy, got {cls!r}")
    fields = {f.name for f in dataclasses.fields(cls)}
    params = dict(params or {})
    unknown = sorted(set(params) - fields)
    if unknown:
        raise ConfigError(
            f"strategy '{name}' has no parameter {', '.join(repr(u) for u in unknown)}; "
            f"expected one of: {', '.join(sorted(fields)) or '(none)'}"
        )
    from bench.validate import check_fields

    check_fields("strategy.params", cls, params)  # types from the annotations, ranges below
    try:
        return cls(**params)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"strategy '{name}' rejected its parameters: {exc}") from exc
