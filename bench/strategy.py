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
    target_count: int | None = None  # prune.target=absolute: N_tar as a fixed count, not a ratio

    @property
    def n_target(self) -> int:
        """N_tar: keep_ratio * N_init (N_init the candidates before pruning), or the absolute count."""
        if self.target_count is not None:
            return self.target_count
        return int(math.ceil(self.keep_ratio * int(self.candidates.sum())))


PRUNE_TARGETS: tuple[str, ...] = ("ratio", "absolute")
PRUNE_EVERY: tuple[str, ...] = ("keyframe", "frame")
GRAD_SOURCES: tuple[str, ...] = ("params_last", "means2d_all")


@dataclass
class PruneConfig:
    """The pruning schedule shared by every strategy (``prune:`` in conf/config.yaml).

    The defaults follow the paper's text: after each keyframe's mapping, keep ``keep_ratio`` of
    the candidates. The other choices reproduce the authors' released code, which differs: an
    absolute target N_tar, pruning on every frame, and g_i from the screen-space mean gradient.
    """

    keep_ratio: float = 0.4  # every strategy keeps this fraction of the candidates
    target: str = "ratio"  # ratio: N_tar = keep_ratio x candidates; absolute: N_tar = n_target
    n_target: int | None = None  # the absolute N_tar (released code: 80,000 on KITTI, 60,000 on EuRoC)
    every: str = "keyframe"  # keyframe: after each keyframe's mapping; frame: also after each tracked frame
    # g_i, the per-Gaussian tracking gradient that pocket's tile budgets and gradient pruning read:
    # params_last = norm of dL/d(all Gaussian parameters) at the last tracking iteration of a frame;
    # means2d_all = norm of dL/d(projected 2D mean), summed over all tracking iterations and divided
    # by the iterations that saw the Gaussian (the released code's accumulator)
    grad_source: str = "params_last"

    def __post_init__(self) -> None:
        if not 0.0 < self.keep_ratio <= 1.0:
            raise ConfigError(f"prune.keep_ratio must be in (0, 1], got {self.keep_ratio}")
        for name, allowed in (("target", PRUNE_TARGETS), ("every", PRUNE_EVERY), ("grad_source", GRAD_SOURCES)):
            if getattr(self, name) not in allowed:
                raise ConfigError(f"prune.{name} must be one of {', '.join(allowed)}, got '{getattr(self, name)}'")
        if self.target == "absolute" and (not isinstance(self.n_target, int) or self.n_target < 0):
            raise ConfigError(f"prune.target=absolute needs an integer prune.n_target >= 0, got {self.n_target!r}")

    @property
    def target_count(self) -> int | None:
        """The absolute N_tar for PruneContext, or None when N_tar follows the keep ratio."""
        return self.n_target if self.target == "absolute" else None


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

    check_fields(f"strategy '{name}' parameter", cls, params, sep=" ")  # types from the annotations, ranges below
    try:
        return cls(**params)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"strategy '{name}' rejected its parameters: {exc}") from exc
