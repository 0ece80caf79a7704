"""Does the flow + PnP start keep the scale on its own? Frame-to-frame motion from ``bench.slam.frontend``.

For each pair of consecutive frames, the motion flow + PnP finds on the previous frame's depth (no map, no
refinement, no prior) against the ground-truth motion: prints the estimated metres over the true metres summed
over the sequence, the median per-step ratio, the median inlier count, and the per-step ratios.

    python profiling/pnp_scale.py dataset=kitti dataset.root=../shared/data/kitti seq=04 threads=1
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.cli.entry import compose  # noqa: E402
from bench.run.config import to_run_config  # noqa: E402
from bench.run.setup import open_seq  # noqa: E402
from bench.slam.frontend import relative_motion, to_gray_u8  # noqa: E402


def main(overrides: list[str]) -> None:
    cfg = to_run_config(compose(overrides))
    seq = open_seq(cfg)
    K = seq.K.double().numpy()
    rows = []  # (true m, estimated m or nan, inliers) per step
    prev = seq[0]
    for i in range(1, len(seq)):
        cur = seq[i]
        depth = prev.depth_m.numpy()
        depth = np.where((depth > 0) & (depth < cfg.slam.max_depth_m), depth, 0.0)  # as System.observe keeps it
        rel, n = relative_motion(
            to_gray_u8(prev.rgb), to_gray_u8(cur.rgb), depth, K, cfg.slam.flow_pnp, None, np.random.default_rng(0)
        )
        true = np.linalg.inv(cur.gt_c2w.double().numpy()) @ prev.gt_c2w.double().numpy()  # [4, 4] prev -> cur
        rows.append((np.linalg.norm(true[:3, 3]), np.linalg.norm(rel[:3, 3]) if rel is not None else np.nan, n))
        prev = cur
    r = np.array(rows)
    print(
        f"{len(seq)} frames at {seq.height}x{seq.width}: "
        f"estimated / true metres {np.nansum(r[:, 1]) / r[:, 0].sum():.4f}, "
        f"median step ratio {np.nanmedian(r[:, 1] / r[:, 0]):.4f}, no guess on {int(np.isnan(r[:, 1]).sum())} steps, "
        f"median inliers {np.median(r[:, 2]):.0f}"
    )
    print("per step:", " ".join(f"{x:.3f}" for x in r[:, 1] / r[:, 0]))


if __name__ == "__main__":
    main(sys.argv[1:])
