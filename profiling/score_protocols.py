"""A finished run scored under every evaluation protocol, from what its run dir keeps.

A run records one ``eval.protocol``; the paper's tables may have come from either masked one. This
renders the run's final map (``map.ply``) at its estimated poses (``traj_est.txt``) on every
``eval.every``-th frame of its own config (``config.yaml``), and scores the same renders under
``full``, ``splatam`` and ``released`` (``bench.metrics.protocol``): PSNR, SSIM and MS-SSIM, and the
share of pixels each mask keeps. No SLAM is rerun. The run's own figures in ``metrics.json`` are
shown beside, as a check that the renders are the run's.

``--per-frame OUT.csv`` also writes each frame's figures: a mean over a drive hides whether its gap
is spread evenly or sits in a stretch of the road (issue 39 asks which).

    python profiling/score_protocols.py RUN_DIR [RUN_DIR ...] [--csv OUT.csv] [--per-frame OUT.csv]
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
from pathlib import Path

import numpy as np
import torch
from omegaconf import OmegaConf

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # score with the checkout this file sits in

PROTOCOLS = ("full", "splatam", "released")


def score_run(run_dir: Path, protocols: tuple[str, ...] = PROTOCOLS, per_frame: list[dict] | None = None) -> list[dict]:
    """The run's mean figures, one row per protocol; each frame's figures appended to ``per_frame``."""
    from bench.metrics.protocol import frame_metrics, mean_metrics, protocol_mask
    from bench.metrics.trajectory import read_tum
    from bench.run.evaluation import eval_depth_range
    from bench.run.export import MAP_FILE, read_ply
    from bench.run.setup import open_seq
    from bench.run.validate import validate
    from bench.slam.raster import drawn_log_scales, rasterize

    built = validate(OmegaConf.load(run_dir / "config.yaml"))
    cfg = built.config
    seq = open_seq(cfg)
    arrays = {k: torch.from_numpy(np.ascontiguousarray(v)) for k, v in read_ply(run_dir / MAP_FILE).items()}
    est = read_tum(run_dir / "traj_est.txt")
    c2w = np.tile(np.eye(4), (len(est), 1, 1))  # [F, 4, 4]
    from evo.core.transformations import quaternion_matrix

    for i, (p, q) in enumerate(zip(est.positions_m, est.quat_wxyz, strict=True)):
        c2w[i] = quaternion_matrix(q)
        c2w[i, :3, 3] = p
    near, far = eval_depth_range(cfg.dataset)  # the dataset's range, as the run's own evaluation reads it
    frames: dict[str, list] = {p: [] for p in protocols}
    log_scales = drawn_log_scales(arrays["log_scales"], cfg.slam.isotropic)  # [N, 3] as System.render draws them
    with torch.no_grad():
        for i in range(0, len(est), max(1, cfg.eval.every)):
            w2c = torch.from_numpy(np.linalg.inv(c2w[i])).float()
            out = rasterize(
                arrays["means"],
                log_scales,
                arrays["quats"],
                torch.sigmoid(arrays["opacity_logits"]),
                arrays["colors"],
                w2c,
                seq.K.float(),
                seq.width,
                seq.height,
                depth_far_m=cfg.slam.depth_far_m,
                backend=cfg.slam.raster_backend,
                antialiased=cfg.slam.raster_antialias,  # as the run rendered
            )
            pred = out.color.clamp(0, 1)
            frame = seq[i]
            for protocol in protocols:
                mask = protocol_mask(protocol, frame.depth_m, out.alpha, near, far)
                scored = frame_metrics(protocol, pred, frame.rgb, mask)
                frames[protocol].append(scored)
                if per_frame is not None:
                    per_frame.append({"run": str(run_dir), "protocol": protocol, "frame": i, **scored})
    stored = json.loads((run_dir / "metrics.json").read_text()).get("metrics", {})
    rows = []
    for protocol in protocols:
        m = mean_metrics(frames[protocol])
        rows.append(
            {
                "run": str(run_dir),
                "protocol": protocol,
                "psnr_db": m.get("psnr_db"),
                "ssim": m.get("ssim"),
                "ms_ssim": m.get("ms_ssim"),
                "mask_frac": m.get("mask_frac"),
                "eval_frames": len(frames[protocol]),
                "stored_protocol": stored.get("eval_protocol", "full"),
                "stored_psnr_db": stored.get("psnr_db"),
            }
        )
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("runs", nargs="+", type=Path)
    ap.add_argument("--csv", type=Path, default=None)
    ap.add_argument("--per-frame", type=Path, default=None, help="also write each frame's figures to this CSV")
    ap.add_argument("--protocols", default=",".join(PROTOCOLS), help="comma-separated subset of " + ",".join(PROTOCOLS))
    args = ap.parse_args()
    protocols = tuple(p for p in args.protocols.split(",") if p)
    if not protocols or set(protocols) - set(PROTOCOLS):
        ap.error(f"--protocols: expected a comma-separated subset of {','.join(PROTOCOLS)}, found {args.protocols!r}")
    per_frame: list[dict] | None = [] if args.per_frame else None
    rows = [row for run in args.runs for row in score_run(run, protocols, per_frame)]

    def fmt(v, spec: str) -> str:
        return "-" if v is None else format(v, spec)

    print("| run | protocol | PSNR dB | SSIM | MS-SSIM | pixels scored | frames | stored (protocol, PSNR) |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(
            f"| {Path(r['run']).name} | {r['protocol']} | {fmt(r['psnr_db'], '.2f')} | {fmt(r['ssim'], '.4f')} | "
            f"{fmt(r['ms_ssim'], '.4f')} | {fmt(r['mask_frac'], '.3f')} | {r['eval_frames']} | "
            f"{r['stored_protocol']}, {fmt(r['stored_psnr_db'], '.2f')} |"
        )
    for path, table in ((args.csv, rows), (args.per_frame, per_frame)):
        if path and table:
            with path.open("w", newline="") as fh:
                w = csv.DictWriter(fh, fieldnames=list(table[0]))
                w.writeheader()
                w.writerows(table)


if __name__ == "__main__":
    main()
