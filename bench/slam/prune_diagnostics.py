"""What a prune saw and did, and how well mapping fitted its keyframe: the diagnostic columns of ``keyframes.csv``."""

from __future__ import annotations

import numpy as np
import torch

from bench.metrics.image import region_psnr_db
from bench.schema import PRUNE_QUARTILE_COLUMNS
from bench.slam.raster import RasterOutput
from bench.slam.se3 import inverse
from bench.slam.system_state import SystemState

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


class PruneDiagnostics(SystemState):
    """The diagnostics half of ``System`` (mixed into it): read-only renders of the system's map."""

    @torch.no_grad()
    def _fit_diagnostics(self, diag: dict, rgb: torch.Tensor, depth: torch.Tensor, w2c: torch.Tensor) -> None:
        """How well mapping fitted the keyframe it just mapped (``own_fit`` of its own render)."""
        diag.update(own_fit(self.render(w2c).color, rgb, depth))

    @torch.no_grad()
    def _prune_diagnostics(
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
            after = self.render(w2c)
            thr = self.cfg.densify_silhouette
            opened = (out.alpha >= thr) & (after.alpha < thr)  # [H, W]
            holes = int(opened.sum())
            sel = opened & (depth > 0)
            if sel.any():
                z = depth[sel]
                uv = self._pix[sel]
                fx, fy, cx, cy = self.K[0, 0], self.K[1, 1], self.K[0, 2], self.K[1, 2]
                p_cam = torch.stack([(uv[:, 0] - cx) / fx * z, (uv[:, 1] - cy) / fy * z, z], -1)
                c2w = inverse(w2c)
                self._holes.append((p_cam @ c2w[:3, :3].T + c2w[:3, 3]).cpu().numpy().astype(np.float64))
        diag["n_hole_px"] = diag.get("n_hole_px", 0) + holes

    def _count_in_holes(self, sel: torch.Tensor, depth: torch.Tensor, w2c: torch.Tensor) -> int:
        """Seeds (``sel`` [H, W]) in pixels the prunes since the last densification opened.

        The opened pixels' surface points (from their frames' observed depth) are projected into
        this keyframe; a point counts where it is the visible surface (within 5% of this frame's
        depth) and marks its pixel and the 8 around it (projected points of another view leave gaps).
        """
        if not self._holes:
            return 0
        pts = np.concatenate(self._holes)  # [M, 3] world
        self._holes = []
        w = w2c.double().cpu().numpy()
        cam = pts @ w[:3, :3].T + w[:3, 3]
        K = self.K.double().cpu().numpy()
        z = cam[:, 2]
        front = z > 1e-6
        u = np.round(K[0, 0] * cam[front, 0] / z[front] + K[0, 2]).astype(np.int64)
        v = np.round(K[1, 1] * cam[front, 1] / z[front] + K[1, 2]).astype(np.int64)
        z = z[front]
        inside = (u >= 0) & (u < self.W) & (v >= 0) & (v < self.H)
        u, v, z = u[inside], v[inside], z[inside]
        d = depth.cpu().numpy()
        seen = np.abs(d[v, u] - z) < 0.05 * z
        mask = np.zeros((self.H + 2, self.W + 2), dtype=np.bool_)
        for dy in (0, 1, 2):
            for dx in (0, 1, 2):
                mask[v[seen] + dy, u[seen] + dx] = True
        opened = mask[1:-1, 1:-1]
        return int((sel.cpu().numpy() & opened).sum())
