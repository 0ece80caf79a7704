"""One SLAM run's state and its per-frame step: a SplaTAM-style RGB-D 3DGS-SLAM loop with a pruning hook.

Per frame (``System.step``): the pose is tracked (``bench.slam.tracking``). On a keyframe: Gaussians are
added where the map is missing or wrong and the map is optimised over a window of keyframes
(``bench.slam.mapping``), then the strategy's keep mask goes through ``GaussianMap.remove``.

``System`` is made of parts, each an object with its own state that holds references to what it reads:
``Renderer`` (the camera), ``KeyframeStore``, ``Tracking`` (with its ``LostDetector``), ``Mapping`` and
``PruneDiagnostics``. ``System`` owns the map, the pose history and the prune itself, and passes
``Mapping`` the prune context it scores the map with at the cap."""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import torch

from bench.datasets.base import Frame
from bench.errors import ConfigError, StrategyError
from bench.slam.config import SlamConfig
from bench.slam.gaussians import GaussianMap
from bench.slam.keyframes import KeyframeStore
from bench.slam.mapping import Mapping
from bench.slam.prune_diagnostics import PruneDiagnostics
from bench.slam.raster import EXTRA_STATS, RasterOutput, resolve_backend
from bench.slam.renderer import Renderer
from bench.slam.residency import STORE_DIR, MapResidency
from bench.slam.se3 import inverse, so3_log
from bench.slam.strategy import READS_MAPPING_GRAD2D, SCORE_VIEWS, PruneConfig, PruneContext, Strategy
from bench.slam.tracking import Tracking


@dataclass
class FrameResult:
    w2c: torch.Tensor  # [4, 4] estimated world-to-camera
    is_keyframe: bool
    keyframe_index: int | None = None
    n_added: int = 0
    n_pruned: int = 0
    n_candidates: int = 0  # Gaussians the strategy could prune (in view, not new), over this frame's prune calls
    n_restored: int = 0  # Gaussians map residency brought back from disk at this keyframe
    track_loss: float = 0.0
    track_s: float = 0.0
    map_s: float = 0.0
    prune_s: float = 0.0
    # what pruning removed and what came back (keyframes.csv; bench/schema.py, _prune_diagnostics)
    diag: dict[str, Any] = field(default_factory=dict)  # numbers, None, and score_views a str
    diag_s: float = 0.0  # time spent on those diagnostics (inside prune_s)


class System:
    """Owns the map, the keyframes and the pose history of one run; ``step`` takes one frame.

    Its parts: ``renderer`` (``bench.slam.renderer``), ``keyframes`` (``bench.slam.keyframes``),
    ``tracking`` (``bench.slam.tracking``; its ``lost``, ``bench.slam.lost``, judges each tracked frame),
    ``mapping`` (``bench.slam.mapping``) and ``diagnostics`` (``bench.slam.prune_diagnostics``).
    """

    def __init__(
        self,
        cfg: SlamConfig,
        K: torch.Tensor,
        height: int,
        width: int,
        strategy: Strategy,
        prune: PruneConfig | float,
        device: torch.device,
        timer=None,
        keyframe_dir: Path | None = None,
    ):
        """``prune`` is the pruning schedule, or just the shared keep ratio (the default schedule);
        ``keyframe_dir``: the folder of the keyframe store with ``slam.keyframes.residency=disk``."""
        self.prune = prune if isinstance(prune, PruneConfig) else PruneConfig(keep_ratio=float(prune))
        self.cfg, self.strategy, self.device = cfg, strategy, device
        # Adam's second moments and the gradients of far or faint Gaussians fall into float32's
        # denormal range, where CPU arithmetic is far slower; flushing them to zero changes
        # no result that matters and keeps the optimiser step from dominating a CPU run
        torch.set_flush_denormal(True)
        self.map = GaussianMap(
            device,
            lrs=asdict(cfg.lrs),
            extra=strategy.extra_params(),
            state_dtypes=strategy.state_spec(),
            adam_fused=cfg.adam_fused,
        )
        self.map.state["_track_grad_sum"] = torch.empty(0, device=device)
        self.map.state["_track_grad_n"] = torch.empty(0, device=device)
        # sum of ||dL/d means2d|| over the mapping iterations that rendered a Gaussian, and those iterations
        # (3DGS's xyz_gradient_accum and denom), kept only for a strategy that reads them
        reads = frozenset(getattr(strategy, "reads", ()))
        self.map_grad2d = READS_MAPPING_GRAD2D in reads
        if reads & set(EXTRA_STATS) and resolve_backend(cfg.raster_backend, device) == "gsplat":
            # said at the start, not at the first prune
            raise ConfigError(
                f"slam.raster_backend=gsplat: statistics {', '.join(sorted(reads & set(EXTRA_STATS)))} "
                "that the strategy reads are not implemented there (use slam.raster_backend=torch)"
            )
        if self.map_grad2d:
            self.map.state["_map_grad2d_sum"] = torch.empty(0, device=device)
            self.map.state["_map_grad2d_n"] = torch.empty(0, device=device)
        self.keyframes = KeyframeStore(cfg.keyframes, keyframe_dir)
        self.renderer = Renderer(cfg, K, height, width, strategy, self.keyframes, device)
        self.K, self.H, self.W = self.renderer.K, height, width  # [3, 3] float32 on the device; px
        self.poses: list[torch.Tensor] = []  # w2c per processed frame
        self.frames_since_kf = 0
        self._timer = timer
        # called after each prune with (kf_idx, w2c, render before [RasterOutput], keep [N before] bool or None)
        self.on_prune: Callable[[int, torch.Tensor, RasterOutput, torch.Tensor | None], None] | None = None
        # slam.residency: the Gaussians on disk (bench/slam/residency.py); None while the policy is off
        self.residency = MapResidency(cfg.residency) if cfg.residency.policy != "off" else None
        self.tracking = Tracking(cfg, self.map, self.keyframes, self.renderer, strategy, self.prune.grad_source, device)
        self.diagnostics = PruneDiagnostics(cfg, self.map, self.renderer)
        self.mapping = Mapping(
            cfg,
            self.map,
            self.keyframes,
            self.renderer,
            strategy,
            self.diagnostics,
            self.residency,
            self.prune_context,
            self.map_grad2d,
            device,
        )

    def use_run_dir(self, out: Path) -> None:
        """Map residency writes its files under the run dir ``out`` (``map_store/``)."""
        if self.residency is not None:
            self.residency.use_dir(out / STORE_DIR)

    def n_evicted(self) -> int:
        """Gaussians map residency holds on disk now (keyframes.csv ``n_evicted``)."""
        return 0 if self.residency is None else self.residency.n_evicted()

    def restore_all(self) -> int:
        """Every Gaussian map residency holds on disk back in the map (before the final evaluation)."""
        return 0 if self.residency is None else self.residency.restore_all(self.map)

    @contextlib.contextmanager
    def whole_map(self) -> Iterator[None]:
        """Within: ``self.map`` is a copy of the whole map, the Gaussians map residency holds on disk
        included (a milestone scores it); after, the live map is back as it was. Only ``self.map`` and
        ``render`` see the copy: the parts hold the live map, and none of them runs within."""
        if self.residency is None or not self.residency.on_disk:
            yield
            return
        live = self.map
        self.map = self.residency.whole_map(live)
        try:
            yield
        finally:
            self.map = live

    def render(
        self,
        w2c: torch.Tensor,
        stats: bool = False,
        training: bool = False,
        iteration: int = 0,
        extra: frozenset[str] = frozenset(),
    ) -> RasterOutput:
        """The map as it stands (the whole map within ``whole_map``) seen from ``w2c`` [4, 4]."""
        return self.renderer.render(self.map, w2c, stats=stats, training=training, iteration=iteration, extra=extra)

    def _phase(self, name: str):
        return self._timer.phase(name) if self._timer is not None else contextlib.nullcontext()

    def observe(self, frame: Frame) -> tuple[torch.Tensor, torch.Tensor]:
        """The frame as the system uses it: rgb [H, W, 3] and depth [H, W] (0 where invalid) on the device."""
        rgb = frame.rgb.to(self.device)
        depth = frame.depth_m.to(self.device)
        depth = torch.where((depth > 0) & (depth < self.cfg.max_depth_m), depth, torch.zeros_like(depth))
        return rgb, depth

    def step(self, frame: Frame) -> FrameResult:
        rgb, depth = self.observe(frame)
        t0 = time.perf_counter()
        self.tracking.begin_frame(rgb)
        if not self.poses:
            w2c = torch.eye(4, device=self.device)
            loss = 0.0
        else:
            with self._phase("tracking"):
                w2c, loss = self.tracking.track(frame.index, rgb, depth, self.poses)
        t1 = time.perf_counter()
        self.tracking.end_frame(depth)
        self.poses.append(w2c)
        self.frames_since_kf += 1
        result = FrameResult(w2c=w2c, is_keyframe=False, track_loss=loss, track_s=t1 - t0)
        if not self._is_keyframe(w2c):
            if self.prune.every == "frame" and self.keyframes:
                # the next keyframe's index: nothing is new on a frame that added no Gaussian
                with self._phase("pruning"):
                    result.n_pruned, result.n_candidates = self._prune(self.keyframes.n_made, w2c, depth, result)
                result.prune_s = time.perf_counter() - t1
        else:
            kf_idx = self.keyframes.add(frame.index, rgb, depth, w2c).kf
            if self.residency is not None:  # before densification: a revisited street is back before it is seeded
                self.residency.note_keyframe(kf_idx, w2c)
                if self.residency.due(kf_idx):
                    with self._phase("residency"):
                        result.n_restored, _ = self.residency.check(self.map, w2c, self.K, (self.H, self.W))
            with self._phase("mapping"):
                result.n_added = self.mapping.densify(rgb, depth, w2c, kf_idx)
                result.diag["n_reseeded_holes"] = self.mapping.reseeded
                result.diag["n_densify_dropped"] = self.mapping.densify_dropped
                result.diag["n_cap_removed"] = self.mapping.cap_removed
                mapped, fit = self.mapping.map_keyframe(kf_idx, (rgb, depth, w2c))
                result.diag["kf_map_iters"] = mapped
            t_fit = time.perf_counter()
            if fit is None:
                self.diagnostics.fit(result.diag, rgb, depth, w2c)
            else:  # mapping's top-up scored the map as it stands: the same figures, not rendered twice
                result.diag.update(fit)
            result.diag_s += time.perf_counter() - t_fit
            # the map at its largest in the window: after densification, with Adam's moments and
            # (as during each mapping step) a gradient for every parameter
            result.diag["state_map_bytes"] = self.map.state_bytes() + (
                sum(p.numel() * p.element_size() for p in self.map.params.values() if p.grad is None) if mapped else 0
            )
            t2 = time.perf_counter() - result.diag_s  # the fit diagnostics are not mapping time
            with self._phase("pruning"):
                result.n_pruned, result.n_candidates = self._prune(kf_idx, w2c, depth, result)
            t3 = time.perf_counter()
            result.is_keyframe, result.keyframe_index = True, kf_idx
            result.map_s, result.prune_s = t2 - t1, t3 - t2
            self.frames_since_kf = 0
        return result

    def state_dict(self) -> dict[str, Any]:
        """Everything that decides the next frames, as tensors and plain values (``torch.load(weights_only=True)``
        reads it back). Keyframe images are not stored: ``load_state_dict`` re-reads them from the sequence
        by index, which is what keeps a checkpoint small (a keyframe's float images are its bulk); with
        ``slam.keyframes.residency=disk`` it writes the store's files again from them.
        The keyframes held are there with their numbers (a window leaves out the dropped ones).
        Per-frame lists go in as one tensor or string each: ``torch.save`` pays per object, and a long
        drive has thousands of poses."""
        g = self.map
        moments = {}
        for group in g.optimizer.param_groups:
            st = g.optimizer.state.get(group["params"][0])
            if st:
                moments[group["name"]] = dict(st)
        return {
            "params": {k: p.detach() for k, p in g.params.items()},  # no copies: a checkpoint must not raise the peak
            "requires_grad": {k: p.requires_grad for k, p in g.params.items()},
            "moments": moments,
            "birth_kf": g.birth_kf,
            "state": dict(g.state),
            "keyframes": {
                "index": torch.tensor([kf.index for kf in self.keyframes], dtype=torch.long),
                "w2c": _stack([kf.w2c for kf in self.keyframes]),
                "kf": torch.tensor([kf.kf for kf in self.keyframes], dtype=torch.long),
                "count": self.keyframes.n_made,
                "submap_anchor": self.keyframes.submap_anchor,  # [4, 4] or None (slam.keyframes.submap_reset_*)
            },  # [K], [K, 4, 4], [K]
            "poses": _stack(self.poses),  # [F, 4, 4]
            "frames_since_kf": self.frames_since_kf,
            # the parts' own state, each under the keys a checkpoint has always held: bad_frames, depth_recent,
            # init_source, prev_obs, ransac_rng, track_log (tracking); rng, densify_rng, densify_start (mapping);
            # holes (the prune diagnostics)
            **self.tracking.state_dict(),
            **self.mapping.state_dict(),
            **self.diagnostics.state_dict(),
            # the Gaussians on disk travel in the checkpoint (MapResidency.state_dict says why)
            **({} if self.residency is None else {"residency": self.residency.state_dict()}),
        }

    def load_state_dict(self, sd: dict[str, Any], frame_at: Callable[[int], Frame]) -> None:
        """Undo ``state_dict``: the map with its Adam moments, the keyframe store (images from
        ``frame_at(index)``), the tracking state and the generators."""
        g = self.map
        if set(sd["params"]) != set(g.params):
            raise ValueError(f"map parameters: expected {sorted(g.params)}, found {sorted(sd['params'])}")
        g.optimizer.state.clear()
        for group in g.optimizer.param_groups:
            name = group["name"]
            new = torch.nn.Parameter(sd["params"][name].to(self.device), requires_grad=sd["requires_grad"][name])
            group["params"][0] = new
            g.params[name] = new
            if name in sd["moments"]:
                # Adam keeps "step" on the CPU (unless capturable); the moments live with the parameter
                g.optimizer.state[new] = {
                    k: v if k == "step" else v.to(self.device) for k, v in sd["moments"][name].items()
                }
        g.birth_kf = sd["birth_kf"].to(self.device)
        g.state = {k: v.to(self.device) for k, v in sd["state"].items()}
        kfs = sd["keyframes"]
        indices = kfs["index"].tolist()
        numbers = kfs["kf"].tolist() if "kf" in kfs else list(range(len(indices)))
        held = [(kf, index, w2c.to(self.device)) for kf, index, w2c in zip(numbers, indices, kfs["w2c"], strict=True)]
        self.keyframes.restore(kfs.get("count", len(indices)), held, lambda i: self.observe(frame_at(i)))
        anchor = kfs.get("submap_anchor")
        self.keyframes.submap_anchor = None if anchor is None else anchor.to(self.device)
        self.poses = [p.to(self.device) for p in sd["poses"]]
        self.frames_since_kf = sd["frames_since_kf"]
        self.tracking.load_state_dict(sd)
        self.mapping.load_state_dict(sd)
        self.diagnostics.load_state_dict(sd)
        if self.residency is not None:
            if "residency" not in sd:
                raise ValueError("map residency: expected its store in the checkpoint, found none")
            self.residency.load_state_dict(sd["residency"])

    def _is_keyframe(self, w2c: torch.Tensor) -> bool:
        if not self.keyframes:
            return True
        if self.frames_since_kf >= self.cfg.kf_every:
            return True
        rel = w2c @ inverse(self.keyframes[-1].w2c)
        trans = float(rel[:3, 3].norm())
        rot_deg = float(so3_log(rel[:3, :3]).norm()) * 57.29578
        return trans > self.cfg.kf_min_trans_m or rot_deg > self.cfg.kf_min_rot_deg

    def _prune(
        self, kf_idx: int, w2c: torch.Tensor, depth: torch.Tensor, result: FrameResult | None = None
    ) -> tuple[int, int]:
        """(Gaussians removed, candidates) after the strategy's keep mask at pose ``w2c``; the
        diagnostics of this prune go to ``result.diag`` (``depth`` [H, W]: the frame's observed depth)."""
        with torch.no_grad():
            out = self.render(w2c, stats=True)
        is_new = self.map.birth_kf == kf_idx
        candidates = (out.tile_id >= 0) & ~is_new
        ctx = self.prune_context(kf_idx, out, is_new, candidates)
        keep = self.strategy.after_mapping(ctx)
        if result is not None and ctx.views_used:
            result.diag["n_score_views"] = len(ctx.views_used)
            result.diag["score_views"] = index_ranges(ctx.views_used)
        self.map.state["_track_grad_sum"].zero_()
        self.map.state["_track_grad_n"].zero_()
        n_candidates = int(candidates.sum())
        if keep is not None:
            keep = keep.to(torch.bool) | is_new  # new Gaussians are exempt whatever the strategy says
        n_removed = 0 if keep is None else self.map.remove(keep)
        if self.on_prune is not None:  # viz.pruning (figures.pruned_run): `out` is the render before the prune
            self.on_prune(kf_idx, w2c, out, keep)
        if result is not None:
            t0 = time.perf_counter()
            self.diagnostics.record(result.diag, out, candidates, keep, n_removed, w2c, depth)
            result.diag_s += time.perf_counter() - t0
        return n_removed, n_candidates

    def prune_context(
        self,
        kf_idx: int,
        out: RasterOutput,
        is_new: torch.Tensor,
        candidates: torch.Tensor,
    ) -> PruneContext:
        """What a strategy's prune (``after_mapping``) and its score at the cap (``cap_score``) read: ``out`` the
        stats=True render of the map, ``is_new`` and ``candidates`` [N] each; the tracking gradient's mean per
        Gaussian from the map's state. ``Mapping`` calls it for the score at the cap."""
        st = self.map.state
        grad_mean = st["_track_grad_sum"] / st["_track_grad_n"].clamp_min(1)
        return PruneContext(
            kf_idx,
            self.map,
            st,
            out,
            grad_mean,
            is_new,
            candidates,
            self.prune.keep_ratio,
            (self.H, self.W),
            self.prune.target_count((self.H, self.W)),
            renderer=self.score_views,
            mapping_grad2d=(st["_map_grad2d_sum"], st["_map_grad2d_n"]) if self.map_grad2d else None,
            seed=self.cfg.seed,
        )

    def score_views(self, which: str, extra: frozenset[str]):
        """PruneContext.render_views: (keyframe index, render) of each view ``which`` selects."""
        if which not in SCORE_VIEWS:
            raise StrategyError(f"score views: expected one of {', '.join(SCORE_VIEWS)}, found {which!r}")
        held = [(kf.kf, kf) for kf in self.keyframes]  # a keyframe window holds only the newest
        if which == "window":  # the views mapping optimises over (bench.slam.mapping.Mapping.map_keyframe)
            held = held[::-1][: self.cfg.mapping_window or len(held)][::-1]
        elif which == "current":
            held = held[-1:]
        for i, kf in held:
            with torch.no_grad():
                out = self.render(kf.w2c, stats=True, extra=extra)
            yield i, out

    def keyframe_store_bytes(self) -> int:
        """Exact bytes of the keyframe store live in memory: each held keyframe's colour and depth at their
        stored dtype (none for one on disk) and its pose."""
        return self.keyframes.memory_bytes()

    def disk_bytes(self) -> dict[str, int]:
        """Exact bytes of the files the run holds on disk now, by part: the Gaussian state (map residency)
        and the keyframe store."""
        state = self.residency.disk_bytes() if self.residency is not None else 0
        return {"state": int(state), "keyframes": self.keyframes.disk_bytes()}


def index_ranges(indices: list[int]) -> str:
    """Sorted indices as ranges, "0-3;5;7-9" (keyframes.csv ``score_views``)."""
    parts: list[list[int]] = []
    for i in sorted(set(indices)):
        if parts and parts[-1][1] == i - 1:
            parts[-1][1] = i
        else:
            parts.append([i, i])
    return ";".join(f"{a}" if a == b else f"{a}-{b}" for a, b in parts)


def _stack(mats: list[torch.Tensor]) -> torch.Tensor:
    return torch.stack(mats) if mats else torch.empty(0, 4, 4)
