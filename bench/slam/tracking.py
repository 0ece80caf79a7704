"""Tracking one frame: its pose, from a start refined on SE(3).

The start is the constant-velocity prediction, refined by sparse flow + PnP on the previous frame's
depth by default (``bench.slam.frontend``); Adam then refines a twist increment against L1 colour +
lambda_d L1 depth on confidently mapped pixels. The last tracking iteration also yields the
per-Gaussian gradient norm g_i that pruning strategies use."""

from __future__ import annotations

from typing import Any, cast

import numpy as np
import torch

from bench.errors import TrackingLost
from bench.slam.config import SlamConfig
from bench.slam.frontend import relative_motion, to_gray_u8
from bench.slam.gaussians import GaussianMap
from bench.slam.keyframes import KeyframeStore
from bench.slam.losses import depth_l1, rendered_depth
from bench.slam.lost import LostDetector
from bench.slam.raster import RasterOutput
from bench.slam.renderer import Renderer
from bench.slam.se3 import inverse, se3_exp
from bench.slam.strategy import Strategy, TrackingContext


class Tracking:
    """The tracking part of ``System``: the pose of each frame against its map, with the front-end's state
    between frames, what each tracked frame's residuals were (``track_log``) and the ``LostDetector``
    that judges them. The pose history itself is ``System.poses``, passed in per frame."""

    def __init__(
        self,
        cfg: SlamConfig,
        gaussians: GaussianMap,
        keyframes: KeyframeStore,
        renderer: Renderer,
        strategy: Strategy,
        grad_source: str,
        device: torch.device,
    ) -> None:
        """``grad_source``: ``slam.prune.grad_source``, what the per-Gaussian gradient strategies read is taken from."""
        self.cfg, self.map, self.keyframes, self.renderer = cfg, gaussians, keyframes, renderer
        self.strategy, self.grad_source, self.device = strategy, grad_source, device
        self.lost = LostDetector(cfg)
        self.ransac_rng = np.random.default_rng([cfg.seed, 2])  # RANSAC sample order (flow + PnP)
        self.gray: np.ndarray | None = None  # [H, W] uint8 of the frame being processed (flow_pnp)
        self.prev_obs: tuple | None = None  # (gray [H, W] uint8, depth [H, W] float) of the last frame
        self.init_source: list[str] = []  # per tracked frame: "flow_pnp" or "velocity"
        # the frame being tracked: flow + PnP's inlier corners, world points [M, 3] and pixels [M, 2]
        self.features: tuple[torch.Tensor, torch.Tensor] | None = None
        # per tracked frame, what the loss detector reads: (frame, colour L1 on confident pixels,
        # fraction of confident pixels, depth L1 in m on confident pixels with depth); a few floats per frame
        self.track_log: list[tuple[int, float, float, float]] = []

    def state_dict(self) -> dict[str, Any]:
        """The front-end's and the lost detector's state, the RANSAC generator and ``track_log``, under the keys
        ``System.state_dict`` has always written them."""
        prev = None if self.prev_obs is None else [torch.from_numpy(a) for a in self.prev_obs]  # gray, depth
        return {
            "bad_frames": self.lost.bad_frames,
            "depth_recent": torch.tensor(self.lost.depth_recent, dtype=torch.float64),  # [<= lost_baseline_frames]
            "init_source": ",".join(self.init_source),
            "prev_obs": prev,
            "ransac_rng": cast(dict[str, Any], self.ransac_rng.bit_generator.state),  # str and int: loads as weights
            "track_log": torch.tensor(self.track_log, dtype=torch.float64).reshape(-1, 4),  # [F, 4]
        }

    def load_state_dict(self, sd: dict[str, Any]) -> None:
        self.lost.bad_frames = sd["bad_frames"]
        self.lost.depth_recent = sd["depth_recent"].tolist()
        self.init_source = sd["init_source"].split(",") if sd["init_source"] else []
        prev = sd["prev_obs"]
        self.prev_obs = None if prev is None else (prev[0].numpy(), prev[1].numpy())
        self.ransac_rng.bit_generator.state = sd["ransac_rng"]
        self.track_log = [(int(f), c, s, d) for f, c, s, d in sd["track_log"].tolist()]

    def begin_frame(self, rgb: torch.Tensor) -> None:
        """A new frame ``rgb`` [H, W, 3]: its grey image for the flow front-end (``tracking_init=flow_pnp``)."""
        self.gray = to_gray_u8(rgb) if self.cfg.tracking_init == "flow_pnp" else None  # [H, W] uint8

    def end_frame(self, depth: torch.Tensor) -> None:
        """The frame is done: it becomes the previous observation of the next one (``tracking_init=flow_pnp``)."""
        if self.cfg.tracking_init == "flow_pnp":
            self.prev_obs = (self.gray, depth.cpu().numpy())

    def initial_pose(self, poses: list[torch.Tensor]) -> torch.Tensor:
        """Guess for the next frame's world-to-camera pose [4, 4], from the poses so far (``poses``, w2c each).

        The constant-velocity prediction, refined by sparse flow + PnP when ``tracking_init`` is
        ``flow_pnp`` and enough corners survive (see ``bench/slam/frontend.py`` for why).
        """
        prev = poses[-1]
        velocity = prev @ inverse(poses[-2]) if len(poses) >= 2 else torch.eye(4, device=prev.device)
        if self.gray is not None:
            if self.prev_obs is not None:
                K = self.renderer.K.double().cpu().numpy()
                prior = velocity.double().cpu().numpy()
                inliers: list = []
                rel, _ = relative_motion(
                    self.prev_obs[0],
                    self.gray,
                    self.prev_obs[1],
                    K,
                    self.cfg.flow_pnp,
                    prior,
                    rng=self.ransac_rng,
                    inliers_out=inliers if self.cfg.feature_weight else None,
                )
                if rel is not None:
                    if inliers:
                        c2w_prev = inverse(prev).double()
                        pts = torch.as_tensor(inliers[0], device=prev.device) @ c2w_prev[:3, :3].T + c2w_prev[:3, 3]
                        self.features = (
                            pts.float(),
                            torch.as_tensor(inliers[1], dtype=torch.float32, device=prev.device),
                        )
                    self.init_source.append("flow_pnp")
                    return torch.as_tensor(rel, dtype=prev.dtype, device=prev.device) @ prev
        self.init_source.append("velocity")
        return velocity @ prev

    def track(
        self,
        frame_index: int,
        rgb: torch.Tensor,
        depth: torch.Tensor,
        poses: list[torch.Tensor],
        init: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, float]:
        """(w2c [4, 4], the final loss) of frame ``frame_index`` (``rgb`` [H, W, 3], ``depth`` [H, W]) after the
        ``poses`` so far, from ``init`` or ``initial_pose``; ``TrackingLost`` when it cannot be tracked."""
        cfg = self.cfg
        iters = cfg.tracking_iters if len(poses) >= 2 else cfg.tracking_iters_first
        self.features = None
        init = self.initial_pose(poses) if init is None else init
        features = self.features
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
        mean2d_grads = self.grad_source == "means2d_all"
        if mean2d_grads:
            g2d_sum = torch.zeros(len(self.map), device=self.device)  # [N] sum of ||dL/d mean2d|| over iterations
            g2d_n = torch.zeros(len(self.map), device=self.device)  # [N] iterations that rendered the Gaussian
        for it in range(iters):
            last = it == iters - 1
            if last and not mean2d_grads:
                for p in params:
                    p.requires_grad_(True)
            w2c = se3_exp(xi * scale) @ init
            out = self.renderer.render(self.map, w2c, stats=last)
            if mean2d_grads and out.means2d.requires_grad:
                out.means2d.retain_grad()
            if mask is None or cfg.tracking_mask == "current":
                mask = out.alpha.detach() > cfg.silhouette_min
                if cfg.tracking_depth_outlier > 0:
                    mask &= self._depth_inliers(out, depth, mask)
            loss, color_l1, depth_l1_m = self._tracking_loss(out, rgb, depth, mask)
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
        self.track_log.append((frame_index, float(color_l1), sil_frac, float(depth_l1_m)))
        self.lost.check(frame_index, float(color_l1), sil_frac, float(depth_l1_m))
        return w2c, loss_val

    def _reprojection_px(self, features: tuple[torch.Tensor, torch.Tensor], w2c: torch.Tensor) -> torch.Tensor:
        """Mean L1 reprojection error (px) of the frontend's inlier corners at pose ``w2c`` [4, 4]."""
        pts, uv = features  # [M, 3] world, [M, 2] px
        cam = pts @ w2c[:3, :3].T + w2c[:3, 3]  # [M, 3]
        z = cam[:, 2:].clamp_min(1e-3)
        K = self.renderer.K
        fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
        proj = torch.cat([fx * cam[:, :1] / z + cx, fy * cam[:, 1:2] / z + cy], 1)  # [M, 2]
        return (proj - uv).abs().sum(-1).mean()

    def _depth_inliers(self, out: RasterOutput, depth: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        """[H, W] bool: pixels whose depth error is within ``tracking_depth_outlier`` x the median error of the
        tracked pixels with depth, and pixels without depth. SplaTAM's ``ignore_outlier_depth_loss``
        (``scripts/splatam.py`` ``get_loss``: ``depth_error < 10 * depth_error.median()``) takes the median
        over the whole image and drops pixels without depth from both terms; this one takes it over the
        pixels tracking uses, which a sky without depth would otherwise pull towards zero."""
        err = (rendered_depth(out, self.cfg.depth_normalized).detach() - depth).abs()  # [H, W]
        has = mask & (depth > 0)
        if not has.any():
            return torch.ones_like(mask)
        return (err <= self.cfg.tracking_depth_outlier * err[has].median()) | (depth <= 0)

    def _tracking_loss(self, out: RasterOutput, rgb: torch.Tensor, depth: torch.Tensor, mask: torch.Tensor):
        """L1 colour + lambda_d L1 depth, averaged over ``mask`` [H, W]."""
        n = mask.sum().clamp_min(1)
        color_l1 = ((out.color - rgb).abs().sum(-1) * mask).sum() / (3 * n)
        depth_l1_m = depth_l1(out, depth, self.cfg.depth_loss_max_m, self.cfg.depth_normalized, mask)
        return color_l1 + self.cfg.lambda_depth_track * depth_l1_m, color_l1.detach(), depth_l1_m.detach()

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
