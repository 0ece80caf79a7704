"""Mapping on a keyframe: Gaussians added where the map is missing or wrong, then the map optimised over a
window of keyframes; and the refinement over every keyframe once the drive is over."""

from __future__ import annotations

import random
from collections.abc import Callable
from typing import Any, cast

import numpy as np
import torch

from bench.slam.config import SlamConfig
from bench.slam.densify import cap_keep, map_cap, pick_seeds, seed_budget
from bench.slam.gaussians import GaussianMap
from bench.slam.keyframes import Keyframe, KeyframeStore
from bench.slam.losses import depth_l1, dssim
from bench.slam.prune_diagnostics import PruneDiagnostics, own_fit
from bench.slam.raster import RasterOutput, resolve_backend
from bench.slam.renderer import Renderer
from bench.slam.residency import MapResidency
from bench.slam.strategy import MappingContext, PruneContext, Strategy

# (keyframe index, its stats=True render, is_new [N], candidates [N]) -> what the strategy's cap_score reads
PruneContextOf = Callable[[int, RasterOutput, torch.Tensor, torch.Tensor], PruneContext]


class Mapping:
    """The mapping part of ``System``: densification and optimisation of its map, with the generators they
    draw from and what the last densification's budget and cap did.

    It reads the prune diagnostics' opened pixels (``PruneDiagnostics.count_in_holes``), the keyframes held,
    map residency (a view whose part of the map is on disk is left out), and asks ``prune_context`` for
    what the strategy scores the map with at the cap (``slam.densify.cap``)."""

    def __init__(
        self,
        cfg: SlamConfig,
        gaussians: GaussianMap,
        keyframes: KeyframeStore,
        renderer: Renderer,
        strategy: Strategy,
        diagnostics: PruneDiagnostics,
        residency: MapResidency | None,
        prune_context: PruneContextOf,
        map_grad2d: bool,
        device: torch.device,
    ) -> None:
        """``map_grad2d``: add the mapping iterations' ||dL/d means2d|| to the map's state (a strategy reads it)."""
        self.cfg, self.map, self.keyframes, self.renderer = cfg, gaussians, keyframes, renderer
        self.strategy, self.diagnostics, self.residency = strategy, diagnostics, residency
        self.prune_context, self.map_grad2d, self.device = prune_context, map_grad2d, device
        # the D-SSIM term through the compiled kernels where the rasterizer runs them, else torch's reference
        self.fused_ssim = resolve_backend(cfg.raster_backend, device) == "fused"
        # one generator per consumer, all from the run seed, so that a change in one (say, more
        # keyframes) does not shift the draws of another
        self.rng = random.Random(cfg.seed)  # keyframe sampling in mapping and refinement
        self.densify_rng = np.random.default_rng([cfg.seed, 1])  # seeding-grid offsets per keyframe
        self.reseeded = 0  # seeds of the last densification that landed in pixels prunes opened
        # slam.densify: what the last densification's budget and cap left out and removed (keyframes.csv), and
        # the map's size after keyframe 0, where budget=taming's curve starts (checkpointed)
        self.densify_dropped = self.cap_removed = 0
        self.densify_start: int | None = None

    def state_dict(self) -> dict[str, Any]:
        """The generators and the taming curve's start, under the keys ``System.state_dict`` has always written."""
        return {
            "rng": _py_rng_state(self.rng),
            "densify_rng": cast(dict[str, Any], self.densify_rng.bit_generator.state),  # str and int: loads as weights
            "densify_start": self.densify_start,
        }

    def load_state_dict(self, sd: dict[str, Any]) -> None:
        self.rng.setstate(_py_rng_from(sd["rng"]))
        self.densify_rng.bit_generator.state = sd["densify_rng"]
        self.densify_start = sd.get("densify_start")  # absent from checkpoints before slam.densify

    @torch.no_grad()
    def densify(self, rgb: torch.Tensor, depth: torch.Tensor, w2c: torch.Tensor, kf_idx: int) -> int:
        cfg = self.cfg
        valid = depth > 0
        deficit = err = None  # [H, W] each: what slam.densify.seed_order=need ranks by
        if len(self.map):
            out = self.renderer.render(self.map, w2c)
            err = (out.depth - depth).abs()
            deficit = 1 - out.alpha
            if cfg.densify_err_median == "image":  # SplaTAM: over every pixel, those without depth at 0
                med = (err * valid).median()
            else:
                seen = err[valid & (out.alpha > cfg.silhouette_min)]
                med = seen.median() if seen.numel() else err.new_tensor(float("inf"))
            need = (out.alpha < cfg.densify_silhouette) | (
                (err > cfg.densify_depth_err_mult * med) & (out.depth > depth)
            )
            if cfg.densify_color_err > 0:
                need |= (out.color - rgb).abs().mean(-1) > cfg.densify_color_err
        else:
            need = torch.ones_like(valid)
        s = cfg.densify_stride
        oy, ox = (int(o) for o in self.densify_rng.integers(0, s, size=2))  # the grid's phase varies with the seed
        grid = torch.zeros_like(valid)
        grid[oy::s, ox::s] = True
        sel = need & valid & grid
        self.densify_dropped = self.cap_removed = 0
        if cfg.densify.cap is not None or cfg.densify.cap_per_mpix_kf is not None or cfg.densify.budget is not None:
            ones = torch.ones_like(depth)  # no map yet: every pixel's deficit is whole, its error even
            sel = self._bound_seeds(
                sel, kf_idx, w2c, ones if deficit is None else deficit, err if err is not None else ones
            )
        self.reseeded = self.diagnostics.count_in_holes(sel, depth, w2c)
        if not sel.any():
            return 0
        z = depth[sel]  # [M]
        means = self.renderer.unproject(sel, depth, w2c)  # [M, 3]
        fx = self.renderer.K[0, 0]
        sigma_px = 0.5 * s + 0.25 if cfg.densify_sigma_px is None else cfg.densify_sigma_px
        n = z.shape[0]
        init_logit = torch.logit(torch.tensor(cfg.init_opacity)).item()
        self.map.add(
            {
                "means": means,
                "log_scales": torch.log(z * sigma_px / fx)[:, None].repeat(1, 3),
                "quats": torch.tensor([1.0, 0, 0, 0], device=self.device).repeat(n, 1),
                "opacity_logits": torch.full((n,), init_logit, device=self.device),
                "colors": rgb[sel],
            },
            keyframe=kf_idx,
        )
        return n

    def _bound_seeds(
        self, sel: torch.Tensor, kf_idx: int, w2c: torch.Tensor, deficit: torch.Tensor, err: torch.Tensor
    ) -> torch.Tensor:
        """The candidate pixels ``sel`` [H, W] cut to the keyframe's budget and to the cap (``slam.densify``).

        At the cap the strategy's score ranks the map, and the lowest-scored Gaussians leave through
        ``GaussianMap.remove`` (the one removal path: Adam moments and state follow) to make room for the
        budgeted seeds; a strategy without a score removes nothing under ``unscored=drop`` and the seeds
        beyond the cap are dropped. Sets ``densify_dropped`` and ``cap_removed`` (keyframes.csv).
        """
        dcfg = self.cfg.densify
        n_cand = int(sel.sum())
        k = n_cand
        budget = seed_budget(dcfg, kf_idx, len(self.map), self.densify_start)
        if budget is not None:
            k = min(k, budget)
        cap = map_cap(dcfg, kf_idx, sel.numel())
        if cap is not None and len(self.map) + k > cap:
            score = self._cap_score(kf_idx, w2c) if len(self.map) else None
            if score is not None:
                self.cap_removed = self.map.remove(cap_keep(score, max(cap - k, 0)))
            k = max(min(k, cap - len(self.map)), 0)
        if self.densify_start is None:  # the taming curve starts from the map as keyframe 0 leaves it
            self.densify_start = len(self.map) + k
        self.densify_dropped = n_cand - k
        return pick_seeds(sel, k, dcfg.seed_order, deficit, err, self.densify_rng)

    def _cap_score(self, kf_idx: int, w2c: torch.Tensor) -> torch.Tensor | None:
        """[N] the strategy's score of the map at the new keyframe's pose (every Gaussian a candidate, none
        new), or opacity under ``unscored=opacity``; None when neither ranks."""
        out = self.renderer.render(self.map, w2c, stats=True)
        none = torch.zeros(len(self.map), dtype=torch.bool, device=self.device)
        score = self.strategy.cap_score(self.prune_context(kf_idx, out, none, ~none))
        if score is None and self.cfg.densify.unscored == "opacity":
            score = self.map.opacities.detach()
        return score

    def map_keyframe(
        self, kf_idx: int, own: tuple[torch.Tensor, torch.Tensor, torch.Tensor] | None = None
    ) -> tuple[int, dict[str, float | None] | None]:
        """Optimise the map over the keyframe window; the iterations run (none after the first
        keyframe with ``mapping_schedule=first``), and ``own_fit`` of the map as it is left when the last
        thing done was to score it (None otherwise), so the keyframe row need not render it again.
        ``own`` is the new keyframe as observed (rgb [H, W, 3], depth [H, W], w2c [4, 4]), which
        ``slam.mapping_fit_psnr_db`` scores between its extra steps."""
        cfg = self.cfg
        if cfg.mapping_schedule == "first" and kf_idx > 0:
            return 0, None
        # the newest keyframes first; older ones keep the views of the early drive from being
        # overwritten by later close-ups (see mapping_window); drawn from the keyframes held (slam.keyframes.window)
        window = self.keyframes[::-1][: cfg.mapping_window or len(self.keyframes)]
        if self.residency is not None:  # a view whose part of the map is on disk would pull the live map into it
            residency = self.residency
            window = [kf for kf in window if residency.resident(kf.kf)]

        def pick(it: int) -> Keyframe:
            if cfg.mapping_draw == "uniform":
                return self.rng.choice(window)
            return window[0] if it % 2 == 0 or len(window) == 1 else self.rng.choice(window[1:])

        n = cfg.mapping_iters
        self._optimize(kf_idx, n, pick)
        if cfg.mapping_fit_psnr_db is None or own is None:
            return n, None
        while n < cfg.mapping_fit_max_iters:
            with torch.no_grad():
                fit = own_fit(self.renderer.render(self.map, own[2]).color, own[0], own[1])
            psnr = fit["kf_psnr_depth_db"]
            if psnr is None or psnr >= cfg.mapping_fit_psnr_db:  # no pixel with depth: nothing to reach
                return n, fit
            step = min(cfg.mapping_fit_step, cfg.mapping_fit_max_iters - n)
            self._optimize(kf_idx, step, pick, start=n)  # the same run of iterations, continued
            n += step
        return n, None  # at the cap: the map changed since it was last scored

    def refine(self, iters: int, on_step: Callable[[], None] | None = None) -> None:
        """Optimise the finished map over every keyframe, sampled uniformly.

        During the drive a keyframe gets most of its iterations while it is the newest, so the
        views of the early drive end up fitted less well than the last ones. MonoGS ends with the
        same kind of pass (its "colour refinement"); no Gaussian is added or pruned here.
        ``on_step`` is called after each iteration (progress display).
        """
        if iters <= 0 or not self.keyframes:
            return

        def pick(it: int) -> Keyframe:
            if it and on_step is not None:
                on_step()  # iteration it-1 is done
            return self.rng.choice(self.keyframes)  # those held (slam.keyframes.window)

        self._optimize(self.keyframes.n_made - 1, iters, pick, lr_final=self.cfg.refine_lr_final)
        if on_step is not None:
            on_step()

    def _optimize(
        self, kf_idx: int, iters: int, pick: Callable[[int], Keyframe], lr_final: float = 1.0, start: int = 0
    ) -> None:
        """Adam on the map parameters against L1 colour + lambda_d L1 depth of the picked keyframes; every rate
        decayed exponentially to ``lr_final`` x its value by the last iteration, and restored afterwards.
        ``start`` > 0 continues a run of iterations (numbered from it, Adam's moments kept)."""
        cfg = self.cfg
        for p in self.map.params.values():
            p.requires_grad_(True)
        opt = self.map.optimizer
        if cfg.mapping_fresh_optimizer and start == 0:
            opt.state.clear()
        base = [g["lr"] for g in opt.param_groups]
        decay = lr_final ** (1.0 / max(1, iters - 1))  # per iteration, as tracking_lr_final in tracking
        try:
            for it in range(start, start + iters):
                for g, lr in zip(opt.param_groups, base, strict=True):
                    g["lr"] = lr * decay ** (it - start)  # decay 1: the rate itself
                kf = pick(it)
                out = self.renderer.render(self.map, kf.w2c, training=True, iteration=it)
                if self.map_grad2d and out.means2d.requires_grad:
                    out.means2d.retain_grad()
                rgb, depth = kf.images()  # float32, read back from disk with residency=disk
                color = (out.color - rgb).abs().mean()
                if cfg.lambda_ssim_map > 0:
                    color = (1 - cfg.lambda_ssim_map) * color + cfg.lambda_ssim_map * dssim(
                        out.color, rgb, self.fused_ssim
                    )
                loss = color + cfg.lambda_depth_map * depth_l1(out, depth, cfg.depth_loss_max_m, cfg.depth_normalized)
                extra = self.strategy.mapping_loss(MappingContext(kf_idx, it, self.map, self.map.state, True))
                if extra is not None:
                    loss = loss + extra
                if not loss.requires_grad:  # no live Gaussian in the view (slam.residency): nothing to step
                    continue
                opt.zero_grad(set_to_none=True)
                loss.backward()
                if self.map_grad2d and out.means2d.grad is not None:
                    seen = (out.radius_px > 0).float()  # [N]
                    self.map.state["_map_grad2d_sum"] += out.means2d.grad.detach().norm(dim=-1) * seen
                    self.map.state["_map_grad2d_n"] += seen
                opt.step()
            opt.zero_grad(set_to_none=True)
        finally:
            for g, lr in zip(opt.param_groups, base, strict=True):
                g["lr"] = lr


def _py_rng_state(rng: random.Random) -> list:
    """``random.Random`` state as plain values and one tensor (what ``torch.load(weights_only=True)`` reads)."""
    version, internal, gauss = rng.getstate()
    return [version, torch.tensor(internal, dtype=torch.int64), gauss]  # 625 words < 2**32


def _py_rng_from(state: list) -> tuple:
    return (state[0], tuple(state[1].tolist()), state[2])
