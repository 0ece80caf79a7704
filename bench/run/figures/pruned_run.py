"""``viz.pruning=true``: what a strategy removed, at a few keyframes of one run.

At keyframes ``every``, ``2 every``, ... the prune's inputs and outputs are kept in
``pruned_kfNNN.npz`` (the keyframe image, the render before and after the prune, the pruned
Gaussians' projected centres, their world positions and their coverage C_i), and ``draw_all`` turns each into
``pruned_kfNNN.png`` once the run is over. The report reads the npz files to put strategies side
by side on one keyframe (``bench.report.figures.pruned.plot_pruned``). The extra render per shown keyframe
runs inside the SLAM loop, so a run with viz on is not one to take FPS or peak memory from.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import cast

import numpy as np
import torch
from matplotlib.colors import LogNorm
from matplotlib.figure import Figure

from bench.slam.raster import RasterOutput

PRUNED_GLOB = "pruned_kf*.npz"
CMAP = "viridis"


def _u8(image: torch.Tensor) -> np.ndarray:
    """[H, W, 3] float in [0, 1] -> uint8 (the pictures need no more, and the npz stays small)."""
    return (image.detach().clamp(0, 1) * 255.0 + 0.5).to(torch.uint8).cpu().numpy()


def unproject(uv: torch.Tensor, z: torch.Tensor, w2c: torch.Tensor, K: torch.Tensor) -> torch.Tensor:
    """World points [P, 3] m whose pinhole projection (``bench.slam.raster.project``) at ``w2c`` [4, 4] and ``K``
    [3, 3] is ``uv`` [P, 2] px at camera depth ``z`` [P] m: a pruned Gaussian's centre, for the 3D viewer."""
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    cam = torch.stack([(uv[:, 0] - cx) * z / fx, (uv[:, 1] - cy) * z / fy, z], -1)  # [P, 3] camera frame
    R, t = w2c[:3, :3], w2c[:3, 3]
    return (cam - t) @ R  # R^T (cam - t), row by row


def caption_psnr_db(a: np.ndarray, b: np.ndarray) -> float:
    """PSNR of two uint8 images, for the figure's captions (the run's metrics use torchmetrics)."""
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2)) / 255.0**2
    return math.inf if mse == 0 else -10.0 * math.log10(mse)


class PruneViz:
    """The ``System.on_prune`` hook: records keyframes ``k > 0`` with ``k % every == 0``."""

    def __init__(self, system, out_dir: Path, every: int, label: str) -> None:
        self.system, self.out_dir, self.every, self.label = system, Path(out_dir), every, label
        self.written: list[Path] = []

    @torch.no_grad()
    def __call__(self, kf_idx: int, w2c: torch.Tensor, before: RasterOutput, keep: torch.Tensor | None) -> None:
        system = self.system
        # keyframe prunes only (prune.every=frame also prunes between keyframes, with the next index)
        if kf_idx == 0 or kf_idx % self.every or kf_idx != system.keyframes.n_made - 1:
            return
        kf = system.keyframes[-1]  # the newest: keyframe kf_idx
        after = system.render(w2c).color  # [H, W, 3], the map is pruned by now
        pruned = torch.zeros_like(before.depths, dtype=torch.bool) if keep is None else ~keep  # [N before]
        uv = before.means2d[pruned]  # [P, 2] px
        inside = (before.depths[pruned] > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < system.W) & (uv[:, 1] >= 0)
        inside &= uv[:, 1] < system.H
        coverage = before.coverage[pruned] if before.coverage is not None else torch.ones(len(uv))  # [P]
        path = self.out_dir / f"pruned_kf{kf_idx:03d}.npz"
        np.savez_compressed(
            path,
            image=_u8(kf.rgb),
            before=_u8(before.color),
            after=_u8(after),
            uv=uv[inside].cpu().numpy().astype(np.float32),
            # [Q, 3] m, row for row with uv: the same Gaussians' centres in the world (python -m bench.view)
            xyz=unproject(uv[inside], before.depths[pruned][inside], w2c, system.K).cpu().numpy().astype(np.float32),
            coverage=coverage[inside].cpu().numpy().astype(np.float32),
            n_pruned=int(pruned.sum()),
            n_before=int(len(pruned)),
            kf=kf_idx,
            frame=kf.index,
            label=self.label,
        )
        self.written.append(path)

    def draw_all(self) -> list[Path]:
        """``pruned_kfNNN.png`` beside each npz this run wrote."""
        return [draw(p, p.with_suffix(".png")) for p in self.written]


def read(path: Path) -> dict:
    with np.load(path) as data:
        return {k: data[k] for k in data.files}


def coverage_norm(values: list[np.ndarray]) -> LogNorm:
    """One log scale for C_i over several pictures (C_i spans orders of magnitude)."""
    positive = np.concatenate([v[v > 0] for v in values] or [np.ones(1)])
    positive = positive if positive.size else np.ones(1)
    lo, hi = np.percentile(positive, [1, 99]) if positive.size > 1 else (positive[0], positive[0] * 10)
    return LogNorm(vmin=max(float(lo), 1e-6), vmax=max(float(hi), float(lo) * 10, 1e-5))


def draw_centres(ax, record: dict, norm: LogNorm, size: float = 3.0):
    """The keyframe in grey with the pruned centres on it, coloured by C_i; returns the scatter."""
    ax.imshow(record["image"].mean(axis=2), cmap="gray", vmin=0, vmax=255)
    uv, c = record["uv"], np.maximum(record["coverage"], cast(float, norm.vmin))  # coverage_norm sets vmin
    order = np.argsort(c)  # the largest C_i on top
    points = ax.scatter(uv[order, 0], uv[order, 1], c=c[order], s=size, cmap=CMAP, norm=norm, linewidths=0)
    h, w = record["image"].shape[:2]
    ax.set_xlim(-0.5, w - 0.5)
    ax.set_ylim(h - 0.5, -0.5)
    return points


def draw(npz: Path, png: Path) -> Path:
    """One keyframe: the image, the render before and after the prune, and what was pruned."""
    r = read(npz)
    h, w = r["image"].shape[:2]
    fig = Figure(figsize=(10.0, 2 * 4.6 * h / w + 0.8), layout="constrained")
    axes = fig.subplots(2, 2)
    before_db, after_db = caption_psnr_db(r["before"], r["image"]), caption_psnr_db(r["after"], r["image"])
    panels = (
        ("keyframe image", r["image"]),
        (f"render before the prune ({before_db:.2f} dB)", r["before"]),
        (f"render after the prune ({after_db:.2f} dB)", r["after"]),
    )
    for ax, (title, image) in zip(axes.ravel(), panels, strict=False):
        ax.imshow(image)
        ax.set_title(title, fontsize="small")
        ax.set_axis_off()
    norm = coverage_norm([r["coverage"]])
    ax = axes[1, 1]
    points = draw_centres(ax, r, norm)
    ax.set_title(f"centres of the {int(r['n_pruned']):,} pruned Gaussians", fontsize="small")
    ax.set_axis_off()
    fig.colorbar(points, ax=ax, label="coverage $C_i$ [px]", shrink=0.9)
    fig.suptitle(
        f"{r['label']}: keyframe {int(r['kf'])} (frame {int(r['frame'])}), pruned {int(r['n_pruned']):,} "
        f"of {int(r['n_before']):,} Gaussians; PSNR against the keyframe",
        fontsize="medium",
    )
    fig.savefig(png, dpi=110)
    return png
