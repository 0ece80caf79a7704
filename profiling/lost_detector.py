"""Is a run declared lost because its pose is lost? The loss detector against the ground-truth pose error.

Drives a synthetic sequence with the loss checks off, and prints per frame what the detectors read
(the colour L1 and the depth L1 on confidently mapped pixels, the depth check's threshold from its
baseline of recent frames, the fraction of confident pixels) beside the ground-truth
error of the tracked pose (translation, m, with the first frame anchored as the system anchors it;
no alignment). Then, at a few frames, it re-tracks from a pose kicked sideways by a metre against
the same map, to show what both residuals read on a real loss. Frames where either check would fire
(``slam.lost_check=color``: residual above ``slam.lost_residual``; ``depth``: depth residual above its
threshold; for ``lost_patience`` frames) are marked.

    python profiling/lost_detector.py ... --kick-every=5 --out=PATH.csv [--plot=PATH.png]  # CSV rewritten per frame
    python profiling/lost_detector.py --out=PATH.csv --plot=PATH.png   # the figure again from the CSV alone
    python profiling/lost_detector.py --compare=LABEL:PATH.csv,LABEL:PATH.csv --plot=PATH.png  # configs side by side

    python profiling/lost_detector.py slam=splatam dataset.n_frames=200 dataset.width=160 dataset.height=96
"""

from __future__ import annotations

import csv
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.cli.entry import compose  # noqa: E402
from bench.run.config import to_run_config  # noqa: E402
from bench.run.determinism import repeatable  # noqa: E402
from bench.run.setup import open_seq  # noqa: E402
from bench.slam.se3 import inverse  # noqa: E402
from bench.slam.strategy import load_strategy  # noqa: E402
from bench.slam.system import System  # noqa: E402

KICK_M = 1.0


def main(overrides: list[str], out_csv: Path | None = None, kick_every: int = 25) -> None:
    cfg = to_run_config(compose(overrides))
    slam = cfg.slam
    threshold, patience = slam.lost_residual, slam.lost_patience
    # see the whole drive: the depth check keeps its baseline as in a run, but never reaches its patience
    slam.lost_check, slam.lost_patience, slam.lost_min_silhouette_frac = "depth", 10**9, 0.0
    with repeatable(cfg.seed, cfg.threads, cfg.determinism, torch.device("cpu")):
        seq = open_seq(cfg)
        name = cfg.strategy.name if cfg.strategy else "none"
        system = System(
            slam,
            seq.K,
            seq.height,
            seq.width,
            load_strategy(name, cfg.strategy.params if cfg.strategy else None),
            cfg.prune,
            torch.device("cpu"),
        )
        gt0 = None
        rows, bad, bad_depth, bad_both = [], 0, 0, 0
        for i in range(min(len(seq), cfg.max_frames) if cfg.max_frames else len(seq)):
            frame = seq[i]
            kicked = None
            depth_threshold = system.tracking.lost.depth_threshold_m()  # what this frame is judged against
            if i >= 2 and i % kick_every == 0:  # before the real frame: same map, same previous poses
                kicked = kick_residual(system, frame)
            system.step(frame)
            gt = frame.gt_c2w.numpy()
            gt0 = gt if gt0 is None else gt0
            est_c2w = inverse(system.poses[-1].double()).numpy()
            err = float(np.linalg.norm(est_c2w[:3, 3] - (np.linalg.inv(gt0) @ gt)[:3, 3]))
            res, sil, dres = system.tracking.track_log[-1][1:] if i else (0.0, 1.0, 0.0)
            bad = bad + 1 if res > threshold else 0
            bad_depth = bad_depth + 1 if dres > depth_threshold else 0
            bad_both = bad_both + 1 if res > threshold or dres > depth_threshold else 0
            rows.append(
                {
                    "frame": i,
                    "gt_err_m": round(err, 4),
                    "residual": round(res, 4),
                    "depth_residual_m": round(dres, 4),
                    "depth_threshold_m": round(depth_threshold, 4),
                    "sil_frac": round(sil, 4),
                    "would_fire": int(bad >= patience),
                    "would_fire_depth": int(bad_depth >= patience),
                    "would_fire_both": int(bad_both >= patience),
                    "n_gaussians": len(system.map),
                    "kicked_residual": None if kicked is None else round(kicked[0], 4),
                    "kicked_depth_residual_m": None if kicked is None else round(kicked[2], 4),
                    "kicked_moved_m": None if kicked is None else round(kicked[1], 4),
                }
            )
            print(",".join(str(v) for v in rows[-1].values()), flush=True)
            if out_csv:  # rewritten every frame: a stopped run keeps what it saw
                with open(out_csv, "w", newline="") as fh:
                    w = csv.DictWriter(fh, fieldnames=list(rows[0]))
                    w.writeheader()
                    w.writerows(rows)


def kick_residual(system: System, frame) -> tuple[float, float, float]:
    """(colour residual, how far the tracked pose ends from the unkicked start, depth residual m) after tracking
    ``frame`` from the usual start moved sideways by KICK_M; the system's state is left as it was."""
    tracking = system.tracking
    state = (
        list(system.poses),
        list(tracking.init_source),
        tracking.prev_obs,
        len(tracking.track_log),
        tracking.ransac_rng.bit_generator.state,
        {k: v.clone() for k, v in system.map.state.items()},
        list(tracking.lost.depth_recent),
        tracking.lost.bad_frames,
    )
    rgb, depth = frame.rgb, frame.depth_m
    depth = torch.where((depth > 0) & (depth < system.cfg.max_depth_m), depth, torch.zeros_like(depth))
    tracking.gray = None  # the plain constant-velocity start: no front-end to pull it back
    start = tracking.initial_pose(system.poses)
    kick = torch.eye(4)
    kick[0, 3] = KICK_M
    w2c, _ = tracking.track(frame.index, rgb, depth, system.poses, init=kick @ start)
    moved = float((inverse(w2c)[:3, 3] - inverse(start)[:3, 3]).norm())
    residual, depth_residual = tracking.track_log[-1][1], tracking.track_log[-1][3]
    system.poses, tracking.init_source, tracking.prev_obs = state[0], state[1], state[2]
    del tracking.track_log[state[3] :]
    tracking.ransac_rng.bit_generator.state = state[4]
    system.map.state.update(state[5])  # the tracking-gradient accumulators the kicked frame added to
    tracking.lost.depth_recent, tracking.lost.bad_frames = state[6], state[7]  # the depth check's baseline and count
    return residual, moved, depth_residual


def plot(csv_path: Path, png_path: Path, title: str) -> None:
    """The figure of reports/lost_detector from a CSV this script wrote: pose error and map size above, both
    residuals with the depth check's threshold and the kicked frames' readings below."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    with open(csv_path) as fh:
        rows = list(csv.DictReader(fh))

    def col(name: str) -> np.ndarray:
        return np.array([float(r[name]) if r[name] not in ("", "None") else np.nan for r in rows])

    f = col("frame")
    kicked = ~np.isnan(col("kicked_depth_residual_m"))
    fig, (ax0, ax1, ax2) = plt.subplots(3, 1, figsize=(9, 8), sharex=True)
    ax0.plot(f, col("gt_err_m"), "k", label="ground-truth pose error [m] (unaligned)")
    ax0.set_ylabel("pose error [m]")
    ax0b = ax0.twinx()
    ax0b.plot(f, col("n_gaussians") / 1e3, color="tab:green", label="Gaussians [k]")
    ax0b.set_ylabel("Gaussians [k]", color="tab:green")
    ax0.legend(loc="upper left", fontsize=8)
    ax1.plot(f, col("depth_residual_m"), color="tab:blue", label="depth L1 on confident pixels [m] (lost_check=depth)")
    thr = col("depth_threshold_m")
    ax1.plot(f, np.where(np.isfinite(thr), thr, np.nan), "--", color="tab:blue", lw=1, label="its threshold")
    ax1.scatter(
        f[kicked],
        col("kicked_depth_residual_m")[kicked],
        marker="x",
        color="tab:red",
        label="after a 1 m sideways kick",
    )
    ax1.set_ylabel("depth L1 [m]")
    ax1.legend(loc="upper left", fontsize=8)
    ax2.plot(f, col("residual"), color="tab:orange", label="colour L1 on confident pixels (lost_check=color)")
    ax2.axhline(0.25, ls="--", color="tab:orange", lw=1, label="its threshold (lost_residual)")
    ax2.scatter(f[kicked], col("kicked_residual")[kicked], marker="x", color="tab:red", label="after a 1 m kick")
    ax2.set_ylabel("colour L1")
    ax2.set_xlabel("frame")
    ax2.legend(loc="upper left", fontsize=8)
    for ax, name in ((ax0, "would_fire_both"), (ax1, "would_fire_depth"), (ax2, "would_fire")):
        fired = f[col(name) > 0]
        if len(fired):
            ax.axvline(fired[0], color="grey", lw=1)
    ax0.set_title(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(png_path, dpi=110)


def plot_compare(runs: list[tuple[str, Path]], png_path: Path, title: str) -> None:
    """Several CSVs of this script (one config each) on shared axes: what each reads frame by frame, to tell
    which setting keeps a drive tracked. Panels: pose error, depth L1, colour L1, confident share."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = (
        ("gt_err_m", "pose error [m]\n(unaligned)"),
        ("depth_residual_m", "depth L1 [m]\n(confident pixels)"),
        ("residual", "colour L1\n(confident pixels)"),
        ("sil_frac", "confident share\nof pixels"),
    )
    fig, axes = plt.subplots(len(panels), 1, figsize=(9, 9), sharex=True)
    colors = plt.get_cmap("tab10").colors
    for i, (label, path) in enumerate(runs):
        with open(path) as fh:
            rows = list(csv.DictReader(fh))
        f = np.array([int(r["frame"]) for r in rows])
        for ax, (name, _) in zip(axes, panels, strict=True):
            ax.plot(f, [float(r[name]) for r in rows], color=colors[i % len(colors)], lw=1.2, label=label)
    for ax, (_, ylabel) in zip(axes, panels, strict=True):
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3)
    axes[0].set_yscale("log")
    axes[2].axhline(0.25, ls="--", color="grey", lw=1)  # lost_residual
    axes[-1].set_xlabel("frame")
    axes[0].legend(loc="upper left", fontsize=7, ncol=2)
    axes[0].set_title(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(png_path, dpi=110)


if __name__ == "__main__":
    args = sys.argv[1:]
    out = next((Path(a.split("=", 1)[1]) for a in args if a.startswith("--out=")), None)
    every = next((int(a.split("=", 1)[1]) for a in args if a.startswith("--kick-every=")), 25)
    png = next((Path(a.split("=", 1)[1]) for a in args if a.startswith("--plot=")), None)
    overrides = [a for a in args if not a.startswith("--")]
    title = next((a.split("=", 1)[1] for a in args if a.startswith("--title=")), None)
    compare = next((a.split("=", 1)[1] for a in args if a.startswith("--compare=")), None)
    if compare and png:  # --compare=LABEL:CSV,LABEL:CSV --plot=PNG [--title=TEXT]
        pairs = [item.rsplit(":", 1) for item in compare.split(",")]
        plot_compare([(label, Path(p)) for label, p in pairs], png, title or "")
    elif png and out and out.exists() and not overrides:  # only redraw: --out=CSV --plot=PNG [--title=TEXT]
        plot(out, png, title or out.stem)
    else:
        main(overrides, out, every)
        if png and out:
            plot(out, png, title or " ".join(overrides))
