"""The camera of one run and how the system renders a map through it: ``Renderer``.

Tracking, mapping, the prune diagnostics and ``System`` itself render through the one ``Renderer``;
the map is an argument, not something the renderer holds, because ``System.whole_map`` renders a
copy of the map in place of the live one."""

from __future__ import annotations

import torch

from bench.slam.config import SlamConfig
from bench.slam.gaussians import GaussianMap
from bench.slam.keyframes import KeyframeStore
from bench.slam.raster import RasterOutput, drawn_log_scales, rasterize
from bench.slam.se3 import inverse
from bench.slam.strategy import MappingContext, Strategy


class Renderer:
    """The intrinsics ``K`` [3, 3] and image size (``H``, ``W`` px) of a run, its pixel grid, and the
    render settings of ``cfg``; the strategy's render mask applies (it reads the keyframe count)."""

    def __init__(
        self,
        cfg: SlamConfig,
        K: torch.Tensor,
        height: int,
        width: int,
        strategy: Strategy,
        keyframes: KeyframeStore,
        device: torch.device,
    ) -> None:
        self.cfg, self.strategy, self.keyframes = cfg, strategy, keyframes
        self.K = K.to(device=device, dtype=torch.float32)  # [3, 3]
        self.H, self.W = height, width
        ys, xs = torch.meshgrid(torch.arange(height, device=device), torch.arange(width, device=device), indexing="ij")
        self.pix = torch.stack([xs, ys], -1).float()  # [H, W, 2] each pixel's (x, y)

    def render(
        self,
        g: GaussianMap,
        w2c: torch.Tensor,
        stats: bool = False,
        training: bool = False,
        iteration: int = 0,
        extra: frozenset[str] = frozenset(),
    ) -> RasterOutput:
        """The map ``g`` seen from world-to-camera ``w2c`` [4, 4]."""
        op = g.opacities
        mask = self.strategy.render_mask(MappingContext(self.keyframes.n_made, iteration, g, g.state, training))
        if mask is not None:
            op = op * mask
        return rasterize(
            g.means,
            drawn_log_scales(g.log_scales, self.cfg.isotropic),
            g.quats,
            op,
            g.colors,
            w2c,
            self.K,
            self.W,
            self.H,
            stats=stats,
            depth_far_m=self.cfg.depth_far_m,
            backend=self.cfg.raster_backend,
            extra=extra,
            antialiased=self.cfg.raster_antialias,
            gsplat_stats=self.cfg.gsplat_stats,
        )

    def unproject(self, sel: torch.Tensor, depth: torch.Tensor, w2c: torch.Tensor) -> torch.Tensor:
        """World points [M, 3] of the pixels ``sel`` [H, W] bool at their ``depth`` [H, W] (m), seen from ``w2c``."""
        z = depth[sel]  # [M]
        uv = self.pix[sel]  # [M, 2]
        fx, fy, cx, cy = self.K[0, 0], self.K[1, 1], self.K[0, 2], self.K[1, 2]
        p_cam = torch.stack([(uv[:, 0] - cx) / fx * z, (uv[:, 1] - cy) / fy * z, z], -1)
        c2w = inverse(w2c)
        return p_cam @ c2w[:3, :3].T + c2w[:3, 3]
