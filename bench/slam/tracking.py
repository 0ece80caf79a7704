"""Tracking one frame: its pose, from a start refined on SE(3).

The start is the constant-velocity prediction, refined by sparse flow + PnP on the previous frame's
depth by default (``bench.slam.frontend``); Adam then refines a twist increment against L1 colour +
lambda_d L1 depth on confidently mapped pixels. The last tracking iteration also yields the
per-Gaussian gradient norm g_i that pruning strategies use."""

from __future__ import annotations

import torch

from bench.errors import TrackingLost
from bench.slam.frontend import relative_motion
from bench.slam.raster import RasterOutput
from bench.slam.se3 import inverse, se3_exp
from bench.slam.strategy import TrackingContext
from bench.slam.system_state import SystemState


class Tracking(SystemState):
    """The tracking half of ``System`` (mixed into it): reads and updates its map, poses and frontend state."""

    def initial_pose(self) -> torch.Tensor:
        """Guess for the next frame's world-to-camera pose [4, 4].

        The constant-velocity prediction, refined by sparse flow + PnP when ``tracking_init`` is
        ``flow_pnp`` and enough corners survive (see ``bench/slam/frontend.py`` for why).
        """
        prev = self.poses[-1]
        velocity = prev @ inverse(self.poses[-2]) if len(self.poses) >= 2 else torch.eye(4, device=prev.device)
        if self._gray is not None:
            if self._prev_obs is not None:
                K = self.K.double().cpu().numpy()
                prior = velocity.double().cpu().numpy()
                inliers: list = []
                rel, _ = relative_motion(
                    self._prev_obs[0],
                    self._gray,
                    self._prev_obs[1],
                    K,
                    self._flow_cfg,
                    prior,
                    rng=self._ransac_rng,
                    inliers_out=inliers if self.cfg.feature_weight else None,
                )
                if rel is not None:
                    if inliers:
                        c2w_prev = inverse(prev).double()
                        pts = torch.as_tensor(inliers[0], device=prev.device) @ c2w_prev[:3, :3].T + c2w_prev[:3, 3]
                        self._features = (
                            pts.float(),
                            torch.as_tensor(inliers[1], dtype=torch.float32, device=prev.device),
                        )
                    self.init_source.append("flow_pnp")
                    return torch.as_tensor(rel, dtype=prev.dtype, device=prev.device) @ prev
        self.init_source.append("velocity")
        return velocity @ prev

    def _track(
        self, frame_index: int, rgb: torch.Tensor, depth: torch.Tensor, init: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, float]:
        cfg = self.cfg
        iters = cfg.tracking_iters if len(self.poses) >= 2 else cfg.tracking_iters_first
        self._features = None
        init = self.initial_pose() if init is None else init
        features = self._features
        xi = torch.zeros(6, device=self.device, requires_grad=True)
        opt = torch.optim.Adam([{"params": [xi], "lr": 1.0}])
        gamma = cfg.tracking_lr_final ** (1.0 / max(1, iters - 1))
        sched = torch.optim.lr_scheduler.ExponentialLR(opt, gamma)
        scale = torch.tensor([cfg.tracking_lr_trans] * 3 + [cfg.tracking_lr_rot] * 3, device=self.device)
        params = list(self.map.params.values())
        for p in params:
            p.requires_grad_(False)
        loss_val = float("inf")
        out = mask = None
        mean2d_grads = self.prune.grad_source == "means2d_all"
        if mean2d_grads:
            g2d_sum = torch.zeros(len(self.map), device=self.device)  # [N] sum of ||dL/d mean2d|| over iterations
            g2d_n = torch.zeros(len(self.map), device=self.device)  # [N] iterations that rendered the Gaussian
        for it in range(iters):
            last = it == iters - 1
            if last and not mean2d_grads:
                for p in params:
                    p.requires_grad_(True)
            w2c = se3_exp(xi * scale) @ init
            out = self.render(w2c, stats=last)
            if mean2d_grads and out.means2d.requires_grad:
                out.means2d.retain_grad()
            if mask is None or cfg.tracking_mask == "current":
                mask = out.alpha.detach() > cfg.silhouette_min
                if cfg.tracking_depth_outlier > 0:
                    mask &= self._depth_inliers(out, depth, mask)
            loss, color_l1, depth_l1 = self._tracking_loss(out, rgb, depth, mask)
            if features is not None and loss.requires_grad:
                loss = loss + cfg.feature_weight * self._reprojection_px(features, w2c)
            if not loss.requires_grad:  # no Gaussian projects into the image: nothing to track against
                raise TrackingLost(f"tracking lost at frame {frame_index}: no Gaussian of the map is in view")
            opt.zero_grad(set_to_none=True)
            loss.backward()
            if mean2d_grads and out.means2d.grad is not None:
                seen = (out.radius_px > 0).float()  # [N]
                g2d_sum += out.means2d.grad.norm(dim=-1) * seen
                g2d_n += seen
            if last:
                loss_val = float(loss.detach())  # read once: the final iterate's loss is the one reported
                if mean2d_grads:
                    self._on_tracked(frame_index, out, g2d_sum / g2d_n.clamp_min(1), g2d_sum, g2d_n)
                else:
                    grad_norm = self._gaussian_grad_norm()
                    self._on_tracked(frame_index, out, grad_norm, grad_norm, torch.ones_like(grad_norm))
                for p in params:
                    p.grad = None
            else:
                opt.step()
                sched.step()
        w2c = w2c.detach()  # the final iterate: the decayed step size makes it the converged one
        if not torch.isfinite(w2c).all():
            raise TrackingLost(f"tracking lost at frame {frame_index}: pose is not finite")
        assert out is not None  # the loop ran: tracking_iters and tracking_iters_first are >= 1
        sil_frac = float((out.alpha.detach() > cfg.silhouette_min).float().mean())
        self.track_log.append((frame_index, float(color_l1), sil_frac, float(depth_l1)))
        self.lost.check(frame_index, float(color_l1), sil_frac, float(depth_l1))
        return w2c, loss_val

    def _reprojection_px(self, features: tuple[torch.Tensor, torch.Tensor], w2c: torch.Tensor) -> torch.Tensor:
        """Mean L1 reprojection error (px) of the frontend's inlier corners at pose ``w2c`` [4, 4]."""
        pts, uv = features  # [M, 3] world, [M, 2] px
        cam = pts @ w2c[:3, :3].T + w2c[:3, 3]  # [M, 3]
        z = cam[:, 2:].clamp_min(1e-3)
        fx, fy, cx, cy = self.K[0, 0], self.K[1, 1], self.K[0, 2], self.K[1, 2]
        proj = torch.cat([fx * cam[:, :1] / z + cx, fy * cam[:, 1:2] / z + cy], 1)  # [M, 2]
        return (proj - uv).abs().sum(-1).mean()

    def _depth_inliers(self, out: RasterOutput, depth: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        """[H, W] bool: pixels whose depth error is within ``tracking_depth_outlier`` x the median error of the
        tracked pixels with depth, and pixels without depth. SplaTAM's ``ignore_outlier_depth_loss``
        (``scripts/splatam.py`` ``get_loss``: ``depth_error < 10 * depth_error.median()``) takes the median
        over the whole image and drops pixels without depth from both terms; this one takes it over the
        pixels tracking uses, which a sky without depth would otherwise pull towards zero."""
        err = (self._depth(out).detach() - depth).abs()  # [H, W]
        has = mask & (depth > 0)
        if not has.any():
            return torch.ones_like(mask)
        return (err <= self.cfg.tracking_depth_outlier * err[has].median()) | (depth <= 0)

    def _tracking_loss(self, out: RasterOutput, rgb: torch.Tensor, depth: torch.Tensor, mask: torch.Tensor):
        """L1 colour + lambda_d L1 depth, averaged over ``mask`` [H, W]."""
        n = mask.sum().clamp_min(1)
        color_l1 = ((out.color - rgb).abs().sum(-1) * mask).sum() / (3 * n)
        depth_l1 = self._depth_l1(out, depth, mask)
        return color_l1 + self.cfg.lambda_depth_track * depth_l1, color_l1.detach(), depth_l1.detach()

    def _depth_l1(self, out: RasterOutput, depth: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
        """Mean L1 depth error over valid pixels nearer than ``depth_loss_max_m`` (within ``mask``)."""
        dmask = (depth > 0) & (depth < self.cfg.depth_loss_max_m)
        if mask is not None:
            dmask &= mask
        return ((self._depth(out) - depth).abs() * dmask).sum() / dmask.sum().clamp_min(1)

    def _depth(self, out: RasterOutput) -> torch.Tensor:
        if self.cfg.depth_normalized:
            return out.depth / out.alpha.clamp_min(1e-3)
        return out.depth

    def _gaussian_grad_norm(self) -> torch.Tensor:
        sq = torch.zeros(len(self.map), device=self.device)
        for p in self.map.params.values():
            if p.grad is not None:
                sq += p.grad.reshape(len(self.map), -1).pow(2).sum(1)
        return sq.sqrt()  # [N]

    def _on_tracked(
        self, frame_index: int, out: RasterOutput, grad_norm: torch.Tensor, grad_sum: torch.Tensor, grad_n: torch.Tensor
    ) -> None:
        """``grad_norm`` [N]: this frame's g_i, as strategies see it; ``grad_sum`` / ``grad_n`` [N]: what
        the core's accumulator (read by pocket's tile budgets as the mean) adds for this frame."""
        st = self.map.state
        st["_track_grad_sum"] += grad_sum
        st["_track_grad_n"] += grad_n
        self.strategy.on_tracking_step(
            TrackingContext(frame_index, self.keyframes.n_made, self.map, st, out, grad_norm)
        )
