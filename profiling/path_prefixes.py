"""Where a run loses scale: its path ratio over every prefix, read from the run directories.

For each run dir (traj_est.txt and traj_gt.txt, as a finished run leaves them) prints the ATE
(metrics.json), the whole path's ratio, the lowest and highest ratio over every prefix of at least
``--min-frames`` frames (the issue 65 target: within 3% of 1), the ratio at a few prefix lengths,
and the step ratio (estimated over true metres) in consecutive blocks of ``--block`` frames, so a
drift shows where it starts. Unaligned, frames paired by position, as keyframes.csv's path columns.

    python profiling/path_prefixes.py RUN_DIR [RUN_DIR ...] [--min-frames=20] [--block=10] [--out=PATH.csv]

``--out`` also writes one row per run dir, with its commit and the settings that set it apart
(its config.yaml's slam.feature_weight, dataset.stride, and the tracking learning rates).
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.metrics.trajectory import distance_along, read_tum  # noqa: E402


def prefix_ratios(est_m: np.ndarray, gt_m: np.ndarray) -> np.ndarray:
    """[N] estimated / true metres from the first frame to each frame (nan where the true path is 0)."""
    e, g = distance_along(est_m), distance_along(gt_m)
    return np.divide(e, g, out=np.full(len(g), np.nan), where=g > 0)


def summary(run: Path, min_frames: int, block: int) -> dict:
    est = read_tum(run / "traj_est.txt").positions_m  # [N, 3]
    gt = read_tum(run / "traj_gt.txt").positions_m  # [N, 3]
    n = min(len(est), len(gt))
    est, gt = est[:n], gt[:n]
    pre = prefix_ratios(est, gt)
    tail = pre[min_frames - 1 :]  # prefixes of at least min_frames frames
    e, g = distance_along(est), distance_along(gt)
    blocks = [
        round(float((e[min(b + block, n - 1)] - e[b]) / (g[min(b + block, n - 1)] - g[b])), 3)
        for b in range(0, n - 1, block)
        if g[min(b + block, n - 1)] > g[b]
    ]
    record = json.loads((run / "metrics.json").read_text()) if (run / "metrics.json").exists() else {}
    m = record.get("metrics", {})
    return {
        "run": run.name,
        "commit": (record.get("provenance", {}).get("git_commit") or "")[:7],
        "git_dirty": record.get("provenance", {}).get("git_dirty"),
        "frames": n,
        "ate_m": m.get("ate_rmse_m"),
        "ratio": round(float(pre[-1]), 4),
        f"min_ratio_{min_frames}+": round(float(np.nanmin(tail)), 4) if len(tail) else None,
        f"max_ratio_{min_frames}+": round(float(np.nanmax(tail)), 4) if len(tail) else None,
        "at_10_20_30_40": [round(float(pre[k - 1]), 3) for k in (10, 20, 30, 40) if k <= n],
        f"blocks_of_{block}": blocks,
        "true_m": round(float(g[-1]), 2),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="+", type=Path)
    ap.add_argument("--min-frames", type=int, default=20)
    ap.add_argument("--block", type=int, default=10)
    ap.add_argument("--out", type=Path, help="also write the rows to this csv")
    args = ap.parse_args()
    rows = []
    for run in args.runs:
        row = summary(run, args.min_frames, args.block)
        print(json.dumps(row))
        rows.append({**row, **settings(run)})
    if args.out is not None:
        with open(args.out, "w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=list(rows[0]))
            w.writeheader()
            for row in rows:
                w.writerow({k: " ".join(map(str, v)) if isinstance(v, list) else v for k, v in row.items()})


def settings(run: Path) -> dict:
    """The run's settings this script's tables compare (from its config.yaml)."""
    from omegaconf import OmegaConf

    cfg = OmegaConf.load(run / "config.yaml")
    return {
        "seq": str(cfg.get("seq")),
        "stride": cfg.dataset.get("stride"),
        "slam_preset": cfg.slam.get("name"),
        "feature_weight": cfg.slam.get("feature_weight"),
        "tracking_lr_trans": cfg.slam.get("tracking_lr_trans"),
    }


if __name__ == "__main__":
    main()
