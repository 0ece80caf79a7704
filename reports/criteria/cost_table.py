"""The criteria's cost per prune from runs' keyframes.csv: python reports/criteria/cost_table.py RUN_DIR...

Per run (one strategy): the mean over keyframes of ``prune_s - diag_s`` (the prune itself: the core's
pruning render, the strategy's scoring renders and its keep rule, the removal; the diagnostics left out),
its share of the keyframe's time (track_s + map_s + prune_s - diag_s), the same for the last keyframe
(the most views held), and the views the last prune scored (n_score_views).
"""

from __future__ import annotations

import csv
import json
import sys
from pathlib import Path


def row(run: Path) -> str:
    kfs = list(csv.DictReader((run / "keyframes.csv").open()))[1:]  # keyframe 0 prunes nothing: left out
    strategy = json.loads((run / "metrics.json").read_text())["run"]["strategy"]

    def cost(r: dict) -> tuple[float, float]:
        p = float(r["prune_s"]) - float(r["diag_s"])
        return p * 1e3, p / (float(r["track_s"]) + float(r["map_s"]) + p)

    ms = [cost(r) for r in kfs]
    mean_ms = sum(m for m, _ in ms) / len(ms)
    mean_share = sum(s for _, s in ms) / len(ms)
    last_ms, last_share = ms[-1]
    views = kfs[-1]["n_score_views"] or "0"
    return (
        f"| {strategy} | {len(kfs)} | {mean_ms:.0f} | {100 * mean_share:.1f} % | {last_ms:.0f} | "
        f"{100 * last_share:.1f} % | {views} |"
    )


if __name__ == "__main__":
    print(
        "| strategy | prunes | prune ms (mean) | share of keyframe time (mean) | prune ms (last kf) "
        "| share (last kf) | views scored (last kf) |"
    )
    print("|---|---|---|---|---|---|---|")
    for arg in sys.argv[1:]:
        print(row(Path(arg)))
