"""What a prune saw and did, and how well mapping fitted its keyframe: the diagnostic columns of ``keyframes.csv``."""

from __future__ import annotations

import numpy as np
import torch

from bench.metrics.image import region_psnr_db
from bench.schema import PRUNE_QUARTILE_COLUMNS
from bench.slam.config import SlamConfig
from bench.slam.gaussians import GaussianMap
from bench.slam.raster import RasterOutput
from bench.slam.renderer import Renderer

REDUNDANT_WEIGHT = 0.05  # a candidate whose blending weight never exceeds this is redundant (reports/fidelity)


def own_fit(color: torch.Tensor, rgb: torch.Tensor, depth: torch.Tensor) -> dict[str, float | None]:
    """A keyframe's render ``color`` [H, W, 3] against its image ``rgb`` [H, W, 3]: PSNR over the whole image,
    over the pixels with observed ``depth`` [H, W] (which a map seeds) and over those without (which only
    neighbouring Gaussians can cover), and the share with depth. The split says where a map's decibels are
    lost; ``slam.mapping_fit_psnr_db`` reads the same figure, so a keyframe row shows what mapping stopped at."""
    sq = (color.clamp(0, 1) - rgb).pow(2).mean(-1)  # [H, W]
    has_depth = depth > 0  # [H, W]
    return {
        "kf_psnr_db": region_psnr_db(sq),
        "kf_psnr_depth_db": region_psnr_db(sq, has_depth),
        "kf_psnr_nodepth_db": region_psnr_db(sq, ~has_depth),
        "kf_depth_frac": float(has_depth.float().mean()),
    }


class PruneDiagnostics:
    """The diagnostics part of ``System``: read-only renders of its map, and the pixels its prunes opened
    (held until the next densification counts the seeds that land there)."""

    def __init__(self, cfg: SlamConfig, gaussians: GaussianMap, renderer: Renderer) -> None:
        self.cfg, self.map, self.renderer = cfg, gaussians, renderer
        # world points [M, 3] (numpy, so they stay out of the measured torch memory) of the pixels the
        # prunes since the last densification opened: the next densification counts seeds landing there
        self.holes: list[np.ndarray] = []

    def state_dict(self) -> dict[str, torch.Tensor]:
        """The opened pixels' world points awaiting the next densification [M, 3] (``System.state_dict``)."""
        return {"holes": torch.from_numpy(np.concatenate(self.holes) if self.holes else np.zeros((0, 3)))}

    def load_state_dict(self, sd: dict) -> None:
        holes = sd["holes"].numpy()
        self.holes = [holes] if len(holes) else []

    @torch.no_grad()
    def fit(self, diag: dict, rgb: torch.Tensor, depth: torch.Tensor, w2c: torch.Tensor) -> None:
        """How well mapping fitted the keyframe it just mapped (``own_fit`` of its own render)."""
        diag.update(own_fit(self.renderer.render(self.map, w2c).color, rgb, depth))

    @torch.no_grad()
    def record(
        self,
        diag: dict,
        out: RasterOutput,
        candidates: torch.Tensor,
        keep: torch.Tensor | None,
        n_removed: int,
        w2c: torch.Tensor,
        depth: torch.Tensor,
    ) -> None:
        """What this prune saw and did, at the pruning pose: the candidates' C_i and max blending
        weight quartiles, the redundant candidates (weight never above REDUNDANT_WEIGHT in this view)
        and how many of them were pruned, and the pixels the prune pushed below the densification
        threshold (holes). Costs one extra render, only when something was removed."""
        assert out.coverage is not None and out.max_weight is not None  # ``out`` is a stats=True render
        cand_cov = out.coverage[candidates].float()  # [C]
        cand_w = out.max_weight[candidates].float()  # [C]
        q = torch.tensor([0.25, 0.5, 0.75], device=cand_cov.device)
        cov_q = torch.quantile(cand_cov, q).tolist() if cand_cov.numel() else [None] * 3
        w_q = torch.quantile(cand_w, q).tolist() if cand_w.numel() else [None] * 3
        diag.update(zip(PRUNE_QUARTILE_COLUMNS, [*cov_q, *w_q], strict=True))
        redundant = candidates & (out.max_weight <= REDUNDANT_WEIGHT)  # [N] before removal
        diag["n_redundant"] = diag.get("n_redundant", 0) + int(redundant.sum())
        pruned_redundant = 0 if keep is None else int((redundant & ~keep).sum())
        diag["n_pruned_redundant"] = diag.get("n_pruned_redundant", 0) + pruned_redundant
        holes = 0
        if n_removed:
            after = self.renderer.render(self.map, w2c)
            thr = self.cfg.densify_silhouette
            opened = (out.alpha >= thr) & (after.alpha < thr)  # [H, W]
            holes = int(opened.sum())
            sel = opened & (depth > 0)
            if sel.any():
                self.holes.append(self.renderer.unproject(sel, depth, w2c).cpu().numpy().astype(np.float64))
        diag["n_hole_px"] = diag.get("n_hole_px", 0) + holes

    def count_in_holes(self, sel: torch.Tensor, depth: torch.Tensor, w2c: torch.Tensor) -> int:
        """Seeds (``sel`` [H, W]) in pixels the prunes since the last densification opened.

        The opened pixels' surface points (from their frames' observed depth) are projected into
        this keyframe; a point counts where it is the visible surface (within 5% of this frame's
        depth) and marks its pixel and the 8 around it (projected points of another view leave gaps).
        """
        if not self.holes:
            return 0
        pts = np.concatenate(self.holes)  # [M, 3] world
        self.holes = []
        w = w2c.double().cpu().numpy()
        cam = pts @ w[:3, :3].T + w[:3, 3]
        K = self.renderer.K.double().cpu().numpy()
        H, W = self.renderer.H, self.renderer.W
        z = cam[:, 2]
        front = z > 1e-6
        u = np.round(K[0, 0] * cam[front, 0] / z[front] + K[0, 2]).astype(np.int64)
        v = np.round(K[1, 1] * cam[front, 1] / z[front] + K[1, 2]).astype(np.int64)
        z = z[front]
        inside = (u >= 0) & (u < W) & (v >= 0) & (v < H)
        u, v, z = u[inside], v[inside], z[inside]
        d = depth.cpu().numpy()
        seen = np.abs(d[v, u] - z) < 0.05 * z
        mask = np.zeros((H + 2, W + 2), dtype=np.bool_)
        for dy in (0, 1, 2):
            for dx in (0, 1, 2):
                mask[v[seen] + dy, u[seen] + dx] = True
        opened = mask[1:-1, 1:-1]
        return int((sel.cpu().numpy() & opened).sum())
