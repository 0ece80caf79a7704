"""Pruning at revisits on a real sequence: where the camera comes back, and what each strategy pruned there.

A frame is a *revisit* when its ground-truth camera is within ``--radius`` m of, and looks within
``--angle`` degrees of, a camera at least ``--gap`` frames earlier. The revisit spans are found from the
sequence's own poses (no SLAM), then a report folder's ``keyframes.csv`` is summed over keyframes inside
and outside them per run: candidates, redundant candidates (max blending weight <= 0.05 at the pruning
pose), pruned, Gaussians seeded, and the map's count before and after each span.

    python profiling/revisit_pruning.py reports/real_long \\
        dataset=sevenscenes dataset.root=../shared/data/sevenscenes seq=seq

(written for reports/real_long/, issue 43; any recorded dataset with ground truth works).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pandas as pd


def revisit_mask(c2w: np.ndarray, radius_m: float, angle_deg: float, gap: int) -> tuple[np.ndarray, np.ndarray]:
    """(mask [N] of revisit frames, index [N] of the first earlier frame each revisits, -1 = none)."""
    t, z = c2w[:, :3, 3], c2w[:, :3, 2]  # camera centres, viewing directions (camera +z)
    cos = np.cos(np.radians(angle_deg))
    mask, source = np.zeros(len(c2w), bool), np.full(len(c2w), -1)
    for i in range(gap, len(c2w)):
        j = np.arange(i - gap + 1)
        close = (np.linalg.norm(t[j] - t[i], axis=1) < radius_m) & (z[j] @ z[i] > cos)
        if close.any():
            mask[i], source[i] = True, j[close][0]
    return mask, source


def spans(mask: np.ndarray, min_len: int = 5) -> list[tuple[int, int]]:
    """Runs of True in ``mask`` at least ``min_len`` long, as inclusive (first, last)."""
    out, start = [], None
    for i, m in enumerate([*mask, False]):
        if m and start is None:
            start = i
        elif not m and start is not None:
            if i - start >= min_len:
                out.append((start, i - 1))
            start = None
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("report", type=Path, help="a report folder holding keyframes.csv and runs.csv")
    ap.add_argument("overrides", nargs="+", help="the dataset overrides of the runs (dataset=... seq=...)")
    ap.add_argument("--radius", type=float, default=0.25, help="m (default 0.25)")
    ap.add_argument("--angle", type=float, default=30.0, help="degrees (default 30)")
    ap.add_argument("--gap", type=int, default=150, help="frames (default 150: 5 s at 30 Hz)")
    args = ap.parse_args()

    from bench.run.config import compose, to_run_config
    from bench.run.setup import open_seq

    seq = open_seq(to_run_config(compose(list(args.overrides))))
    mask, source = revisit_mask(seq.gt_poses.numpy(), args.radius, args.angle, args.gap)
    found = spans(mask)
    print(
        f"{seq.name}: {int(mask.sum())} of {len(mask)} frames revisit (within {args.radius} m and "
        f"{args.angle:g} deg of a frame >= {args.gap} earlier); spans of >= 5 frames:"
    )
    for a, b in found:
        print(f"  frames {a}-{b}, first revisiting frame {source[a]}")

    kf = pd.read_csv(args.report / "keyframes.csv")
    runs = pd.read_csv(args.report / "runs.csv")[["path", "strategy", "slam_preset", "seed"]]
    kf = kf.merge(runs, on="path", how="left")  # each keyframe row names its run dir
    key = ["strategy", "slam_preset", "seed"]
    inside = np.zeros(len(kf), bool)
    for a, b in found:
        inside |= kf["frame"].between(a, b).to_numpy()
    kf["where"] = np.where(inside, "revisit", "elsewhere")
    cols = ["n_candidates", "n_redundant", "n_pruned", "n_pruned_redundant", "n_added"]
    summary = kf.groupby([*key, "where"])[cols].sum()
    summary.insert(0, "keyframes", kf.groupby([*key, "where"]).size())
    pd.set_option("display.width", 200)
    print("\nkeyframes inside / outside the revisit spans, summed:")
    print(summary.to_string())
    print("\nGaussians at the keyframe before each span and at its last keyframe:")
    for group, rows in kf.groupby(key):
        parts = []
        for a, b in found:
            before = rows[rows["frame"] < a].tail(1)["n_gaussians"]
            end = rows[rows["frame"] <= b].tail(1)["n_gaussians"]
            if len(before) and len(end):
                parts.append(f"{a}-{b}: {int(before.iloc[0]):,} -> {int(end.iloc[0]):,}")
        print(f"  {group}: " + "; ".join(parts))


if __name__ == "__main__":
    main()
