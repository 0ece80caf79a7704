"""Which densification rule adds Gaussians at each keyframe, and how much (issue 27: why slam=splatam's map stops
growing on a forward drive).

Runs a drive with the loss checks off and prints, per keyframe before it densifies, the share of pixels with depth
that the silhouette rule and the depth-error rule select, the depth-error threshold (mult x median), and then the
Gaussians added and the map size.

    python profiling/densify_rules.py slam=splatam dataset.n_frames=160 dataset.width=160 dataset.height=96 threads=1
"""

from __future__ import annotations

import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.cli.entry import compose  # noqa: E402
from bench.run.config import to_run_config  # noqa: E402
from bench.run.determinism import repeatable  # noqa: E402
from bench.run.setup import open_seq  # noqa: E402
from bench.slam.mapping import Mapping  # noqa: E402
from bench.slam.strategy import load_strategy  # noqa: E402
from bench.slam.system import System  # noqa: E402


def rule_shares(mapper: Mapping, depth: torch.Tensor, w2c: torch.Tensor) -> str:
    """The shares of valid-depth pixels each rule of ``Mapping.densify`` selects at ``w2c``, as one line."""
    cfg = mapper.cfg
    valid = depth > 0  # [H, W]
    with torch.no_grad():
        out = mapper.renderer.render(mapper.map, w2c)
    err = (out.depth - depth).abs()
    if cfg.densify_err_median == "image":
        med = (err * valid).median()
    else:
        med = err[valid & (out.alpha > cfg.silhouette_min)].median()
    sil = (out.alpha < cfg.densify_silhouette) & valid
    dep = (err > cfg.densify_depth_err_mult * med) & (out.depth > depth) & valid
    n = int(valid.sum())
    line = (
        f"sil<{cfg.densify_silhouette} {float(sil.sum()) / n:.4f} depth_rule {float(dep.sum()) / n:.4f} "
        f"depth_thr_m {float(cfg.densify_depth_err_mult * med):.2f}"
    )
    if cfg.densify_color_err > 0:
        col = ((out.color - mapper.keyframes[-1].rgb).abs().mean(-1) > cfg.densify_color_err) & valid
        line += f" color_rule {float(col.sum()) / n:.4f}"
    return line


def main(overrides: list[str]) -> None:
    cfg = to_run_config(compose(overrides))
    slam = cfg.slam
    slam.lost_check, slam.lost_min_silhouette_frac = "off", 0.0
    densify = Mapping.densify

    def probed(self: Mapping, rgb: torch.Tensor, depth: torch.Tensor, w2c: torch.Tensor, kf_idx: int) -> int:
        shares = rule_shares(self, depth, w2c) if len(self.map) else "first keyframe"
        added = densify(self, rgb, depth, w2c, kf_idx)
        print(
            f"kf {kf_idx} frame {self.keyframes[-1].index} added {added} n_gaussians {len(self.map)} {shares}",
            flush=True,
        )
        return added

    Mapping.densify = probed  # type: ignore[method-assign]
    with repeatable(cfg.seed, cfg.threads, cfg.determinism, torch.device("cpu")):
        seq = open_seq(cfg)
        system = System(slam, seq.K, seq.height, seq.width, load_strategy("none", None), cfg.prune, torch.device("cpu"))
        for i in range(len(seq)):
            system.step(seq[i])


if __name__ == "__main__":
    main(sys.argv[1:])
