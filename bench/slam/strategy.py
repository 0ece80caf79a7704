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
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar

import torch

from bench.config import plugins as registry
from bench.config.settings import check_rules, check_types, did_you_mean, setting
from bench.errors import ConfigError, StrategyError
from bench.slam.gaussians import GaussianMap, ParamSpec
from bench.slam.raster import EXTRA_STATS, RasterOutput

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
    # the core's renderer of scoring views: (which, extra) -> (keyframe index, render) per view; see render_views
    renderer: Callable[[str, frozenset[str]], Iterator[tuple[int, RasterOutput]]] | None = None
    # keyframe indices of the views render_views gave this prune (keyframes.csv: n_score_views, score_views)
    views_used: list[int] = field(default_factory=list)
    # (sum of ||dL/d means2d|| px over the mapping iterations that rendered the Gaussian, those iterations)
    # [N] each, since the Gaussian was added; filled only for a strategy that reads "mapping_grad2d"
    mapping_grad2d: tuple[torch.Tensor, torch.Tensor] | None = None
    seed: int = 0  # the run's seed (slam.seed), for a strategy that draws at random

    def render_views(
        self, which: str, extra: frozenset[str] | tuple[str, ...] = ()
    ) -> Iterator[tuple[int, RasterOutput]]:
        """(keyframe index, stats=True render with the ``extra`` statistics) per scoring view, with the
        current map and the keyframes' poses, no gradient: ``which`` is ``held_keyframes`` (every keyframe
        the system holds, the new one included), ``window`` (the mapping window) or ``current`` (the new
        keyframe). Each view is rendered as it is reached, so one at a time is held; the views go to
        keyframes.csv."""
        if self.renderer is None:
            raise StrategyError("expected a PruneContext with a renderer of scoring views, found none")
        for kf, out in self.renderer(which, frozenset(extra)):
            self.views_used.append(kf)
            yield kf, out

    @property
    def n_target(self) -> int:
        """N_tar: keep_ratio * N_init (N_init the candidates before pruning), or the absolute count."""
        if self.target_count is not None:
            return self.target_count
        return int(math.ceil(self.keep_ratio * int(self.candidates.sum())))


READS_MAPPING_GRAD2D = "mapping_grad2d"
SCORE_VIEWS: tuple[str, ...] = ("held_keyframes", "window", "current")  # what PruneContext.render_views takes
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

    # every strategy keeps this fraction of the candidates
    keep_ratio: float = setting(0.4, "float", lo=0.0, hi=1.0, lo_open=True)
    # ratio: N_tar = keep_ratio x candidates; absolute: N_tar = n_target
    target: str = setting("ratio", "str", choices=PRUNE_TARGETS)
    # the absolute N_tar (released code: 80,000 on KITTI, 60,000 on EuRoC)
    n_target: int | None = setting(None, "int", lo=0, nullable=True)
    # or the absolute N_tar per megapixel of the run's images, so that the budget scales with the resolution:
    # N_tar = round(n_target_per_mpx x H x W / 1e6) (docs/presets.md gives the released budgets per megapixel)
    n_target_per_mpx: float | None = setting(None, "float", lo=0.0, nullable=True)
    # the absolute N_tar's floor: never fewer than this many Gaussians per pixel of one image. Why: a budget under
    # one view's seeds leaves the next frame's silhouette too thin to track (conf/study/regime.yaml); 1.0 = one
    # view seeded at every pixel, the rule slam.densify.cap_floor_per_px fixed for the memory cap (issue 58)
    n_target_floor_per_px: float | None = setting(None, "float", lo=0.0, lo_open=True, nullable=True)
    # keyframe: after each keyframe's mapping; frame: also after each tracked frame
    every: str = setting("keyframe", "str", choices=PRUNE_EVERY)
    # g_i, the per-Gaussian tracking gradient that pocket's tile budgets and gradient pruning read:
    # params_last = norm of dL/d(all Gaussian parameters) at the last tracking iteration of a frame;
    # means2d_all = norm of dL/d(projected 2D mean), summed over all tracking iterations and divided
    # by the iterations that saw the Gaussian (the released code's accumulator)
    grad_source: str = setting("params_last", "str", choices=GRAD_SOURCES)

    def __post_init__(self) -> None:
        check_rules(self, "prune.")
        given = [k for k in ("n_target", "n_target_per_mpx") if getattr(self, k) is not None]
        if self.target == "absolute" and len(given) != 1:
            raise ConfigError(
                "prune.n_target / prune.n_target_per_mpx: expected exactly one of them with prune.target=absolute, "
                f"found {' and '.join(given) or 'neither'}"
            )
        if self.target == "ratio" and given:
            raise ConfigError(
                f"prune.{given[0]}: expected it only with prune.target=absolute, found prune.target=ratio"
            )
        if self.target == "ratio" and self.n_target_floor_per_px is not None:
            raise ConfigError(
                "prune.n_target_floor_per_px: expected it only with prune.target=absolute, found prune.target=ratio"
            )

    def target_count(self, image_hw: tuple[int, int]) -> int | None:
        """The absolute N_tar for PruneContext at images of ``image_hw`` (H, W), or None when N_tar follows the
        keep ratio."""
        if self.target != "absolute":
            return None
        n_pixels = image_hw[0] * image_hw[1]
        if self.n_target_per_mpx is not None:
            count = int(round(self.n_target_per_mpx * n_pixels / 1e6))
        else:
            assert self.n_target is not None  # __post_init__: exactly one of the two with target=absolute
            count = self.n_target
        if self.n_target_floor_per_px is not None:
            count = max(count, int(self.n_target_floor_per_px * n_pixels))
        return count


@dataclass
class Strategy:
    """Base class: every hook is a no-op, so ``none`` is the empty subclass."""

    description: ClassVar[str] = ""
    # what the strategy reads that the core computes only on request: names of raster.EXTRA_STATS
    # (asked of PruneContext.render_views) and "mapping_grad2d" (PruneContext.mapping_grad2d)
    reads: ClassVar[frozenset[str]] = frozenset()

    def __post_init__(self) -> None:
        """Every field declared with ``setting`` checked as the strategy is built: a bad value is one
        ``ConfigError`` line, ``strategy 'NAME': FIELD: expected ..., found ...`` (NAME: the strategy's
        module). A subclass with its own ``__post_init__`` calls this one first."""
        check_rules(self, f"strategy '{type(self).__module__.rpartition('.')[2]}': ")

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

    def cap_score(self, ctx: PruneContext) -> torch.Tensor | None:
        """[N] float, higher = more worth keeping, read by the core where it must remove Gaussians itself: at
        ``slam.densify.cap`` the lowest-scored make room for a keyframe's seeds. ``ctx`` is rendered at the
        new keyframe's pose before its seeds are added, every Gaussian a candidate. It must not change
        ``ctx.state``. None: no ranking (``slam.densify.unscored`` says what the cap does then)."""
        return None


def top_k_keep(score: torch.Tensor, candidates: torch.Tensor, k: int) -> torch.Tensor:
    """Keep all non-candidates plus the ``k`` best-scoring candidates (the shared global rule).

    A NaN among the candidates' scores has no rank (``topk`` would keep an arbitrary set): a ``StrategyError``.
    """
    keep = ~candidates
    idx = candidates.nonzero().flatten()
    n_nan = int(torch.isnan(score[idx]).sum()) if idx.numel() and score.is_floating_point() else 0
    if n_nan:
        raise StrategyError(f"top_k_keep: expected scores to rank, found {n_nan} NaN of {idx.numel()} candidates")
    if idx.numel() and k > 0:
        best = idx[torch.topk(score[idx], min(k, idx.numel())).indices]
        keep = keep.clone()
        keep[best] = True
    return keep


def is_int(value: object) -> bool:
    """True for a real integer (bools are ints to Python, not to a config)."""
    return isinstance(value, int) and not isinstance(value, bool)


def check(strategy: str, ok: bool, message: str) -> None:
    """Hyperparameter check for a strategy's ``__post_init__``: one-line ``ConfigError`` unless ``ok``."""
    if not ok:
        raise ConfigError(f"strategy '{strategy}': {message}")


def check_choice(strategy: str, field: str, value: object, allowed: tuple[str, ...]) -> None:
    """One-line ``ConfigError`` unless ``value`` is one of ``allowed``."""
    check(strategy, value in allowed, f"{field}: expected one of {', '.join(allowed)}, found {value!r}")


class CheckedStrategy(Strategy):
    """The core's side of the contract: forwards every hook and checks what comes back.

    A keep mask must be a bool tensor [N] on the map's device, a render mask or a score a finite floating
    [N], a loss a finite scalar; anything else is a ``StrategyError`` naming the strategy, raised here rather
    than as a shape error (or an arbitrary ranking of NaN) deep in the removal path. ``StrategyError``s
    raised inside a hook get the name too.
    Each hook is a method here that calls the strategy's and checks its answer (the checks below the
    class); a hook added to ``Strategy`` without one here fails ``tests/strategies/test_boundary.py``.
    """

    def __init__(self, strategy: Strategy, name: str) -> None:
        self.inner, self.name = strategy, name
        # the wrapper carries the wrapped strategy's values per instance, shadowing the class defaults
        self.description = strategy.description  # type: ignore[misc]
        self.reads = frozenset(strategy.reads)  # type: ignore[misc]
        unknown = sorted(self.reads - set(EXTRA_STATS) - {READS_MAPPING_GRAD2D})
        if unknown:
            raise StrategyError(
                f"strategy '{name}' reads: expected among "
                f"{', '.join([*EXTRA_STATS, READS_MAPPING_GRAD2D])}, found {', '.join(unknown)}"
            )

    def state_spec(self) -> dict[str, torch.dtype]:
        return _state_spec(self, self._call("state_spec"))

    def extra_params(self) -> dict[str, ParamSpec]:
        return _extra_params(self, self._call("extra_params"))

    def on_tracking_step(self, ctx: TrackingContext) -> None:
        self._call("on_tracking_step", ctx)

    def render_mask(self, ctx: MappingContext) -> torch.Tensor | None:
        return self._tensor("render_mask", self._call("render_mask", ctx), len(ctx.gaussians), "floating")

    def masked_count(self, gaussians: GaussianMap, state: dict[str, torch.Tensor]) -> int:
        return _masked_count(self, self._call("masked_count", gaussians, state), gaussians)

    def mapping_loss(self, ctx: MappingContext) -> torch.Tensor | None:
        return _mapping_loss(self, self._call("mapping_loss", ctx))

    def after_mapping(self, ctx: PruneContext) -> torch.Tensor | None:
        return _after_mapping(self, self._call("after_mapping", ctx), ctx)

    def cap_score(self, ctx: PruneContext) -> torch.Tensor | None:
        return self._tensor("cap_score", self._call("cap_score", ctx), len(ctx.gaussians), "floating")

    def _fail(self, hook: str, expected: str, found: str) -> StrategyError:
        return StrategyError(f"strategy '{self.name}' {hook}: expected {expected}, found {found}")

    def _call(self, hook: str, *args: Any) -> Any:
        try:
            return getattr(self.inner, hook)(*args)
        except StrategyError as exc:
            if f"'{self.name}'" in str(exc):
                raise
            raise StrategyError(f"strategy '{self.name}' {hook}: {exc}") from exc

    def _tensor(self, hook: str, out: Any, n: int, kind: str) -> torch.Tensor | None:
        if out is None:
            return None
        if not isinstance(out, torch.Tensor):
            raise self._fail(hook, f"a {kind} tensor [{n}] or None", type(out).__name__)
        ok_dtype = out.dtype == torch.bool if kind == "bool" else out.is_floating_point()
        if not ok_dtype or tuple(out.shape) != (n,):
            raise self._fail(hook, f"a {kind} tensor [{n}]", f"{out.dtype} {list(out.shape)}")
        if kind != "bool":
            self._finite(hook, out)
        return out

    def _finite(self, hook: str, out: torch.Tensor) -> None:
        """NaN or inf in a score or mask would rank or weigh Gaussians arbitrarily: refused here."""
        bad = ~torch.isfinite(out.detach())
        if bool(bad.any()):
            n_nan = int(torch.isnan(out.detach()).sum())
            found = f"{n_nan} NaN and {int(bad.sum()) - n_nan} infinite of {out.numel()}"
            raise self._fail(hook, "finite values", found)


def _state_spec(s: CheckedStrategy, spec: Any) -> dict[str, torch.dtype]:
    if not isinstance(spec, Mapping) or not all(isinstance(v, torch.dtype) for v in spec.values()):
        raise s._fail("state_spec", "a dict of name -> torch.dtype", repr(spec))
    return dict(spec)


def _extra_params(s: CheckedStrategy, params: Any) -> dict[str, ParamSpec]:
    if not isinstance(params, Mapping) or not all(isinstance(v, ParamSpec) for v in params.values()):
        raise s._fail("extra_params", "a dict of name -> ParamSpec", repr(params))
    return dict(params)


def _masked_count(s: CheckedStrategy, count: Any, gaussians: GaussianMap) -> int:
    if not is_int(count) or not 0 <= count <= len(gaussians):
        raise s._fail("masked_count", f"an integer in [0, {len(gaussians)}]", repr(count))
    return count


def _mapping_loss(s: CheckedStrategy, loss: Any) -> torch.Tensor | None:
    if loss is not None and (not isinstance(loss, torch.Tensor) or loss.numel() != 1):
        found = f"{loss.dtype} {list(loss.shape)}" if isinstance(loss, torch.Tensor) else type(loss).__name__
        raise s._fail("mapping_loss", "a scalar tensor or None", found)
    if loss is not None:
        s._finite("mapping_loss", loss)
    return loss


def _after_mapping(s: CheckedStrategy, keep: Any, ctx: PruneContext) -> torch.Tensor | None:
    keep = s._tensor("after_mapping", keep, len(ctx.gaussians), "bool")
    if keep is not None and keep.device != ctx.candidates.device:
        raise s._fail("after_mapping", f"a keep mask on {ctx.candidates.device}", f"one on {keep.device}")
    return keep


# the hooks of the contract: what CheckedStrategy forwards (each checked there) and plugins may override
HOOKS: tuple[str, ...] = tuple(n for n, v in vars(Strategy).items() if callable(v) and not n.startswith("_"))


def available() -> list[str]:
    return registry.available(GROUP)


def strategy_class(name: str) -> type[Strategy]:
    """The dataclass registered as strategy ``name``; a one-line ``StrategyError`` if it is none."""
    cls = registry.load(GROUP, "strategy", name, StrategyError)
    if not (isinstance(cls, type) and issubclass(cls, Strategy) and dataclasses.is_dataclass(cls)):
        raise StrategyError(
            f"strategy '{name}': expected a @dataclass subclass of bench.slam.strategy.Strategy, found {cls!r}"
        )
    return cls


def unknown_params(name: str, cls: type[Strategy], params: Mapping[str, Any]) -> None:
    """A ``ConfigError`` naming the keys of ``params`` that strategy ``name`` has no field for."""
    fields = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(params) - fields)
    if unknown:
        raise ConfigError(
            f"strategy '{name}': expected parameters among {', '.join(sorted(fields)) or '(none)'}, "
            f"found {', '.join(repr(u) for u in unknown)}{did_you_mean(unknown[0], fields)}"
        )


def load_strategy(name: str, params: Strategy | Mapping[str, Any] | None = None) -> Strategy:
    """Strategy ``name`` from the entry points; a run wraps it in ``CheckedStrategy``.

    ``params`` is the strategy's own dataclass instance (what the typed config holds once its schema
    is registered; returned as it is) or a mapping of hyperparameters (the strategy is built from it).
    """
    cls = strategy_class(name)
    if isinstance(params, Strategy):
        if not isinstance(params, cls):
            found = type(params).__name__
            raise StrategyError(f"strategy '{name}': expected parameters of {cls.__name__}, found {found}")
        return params
    params = dict(params or {})
    unknown_params(name, cls, params)
    check_types(f"strategy '{name}' parameter ", cls, params)  # types from the annotations, ranges below
    try:
        return cls(**params)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"strategy '{name}': expected valid parameters, found {exc}") from exc
