"""How later mapping changes what keyframe 0 shows: the fit diagnosis's "later mapping" cause, isolated.

Maps a sequence's first 13 frames from ground-truth poses (tracking bypassed, so no pose error enters)
and after every keyframe prints keyframe 0's PSNR over its pixels with depth, rendered from the whole
map, from the Gaussians keyframe 0 seeded as they are now, and from those as they were right after its
own mapping. Where the first falls as later keyframes are mapped while the third stays, the views
disagree (stereo depth, exposure, motion) and mapping trades
keyframe 0's fit for the newer one's.

    python profiling/keyframe_drift.py dataset=kitti dataset.root=../shared/data/kitti seq=06
    python profiling/keyframe_drift.py                       # the synthetic default
"""

from __future__ import annotations

import sys
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # measure the checkout this file sits in


def main() -> None:
    from bench.cli.entry import compose
    from bench.metrics.image import region_psnr_db
    from bench.run.determinism import repeatable
    from bench.run.setup import open_seq
    from bench.run.validate import validate
    from bench.slam.raster import drawn_log_scales, rasterize
    from bench.slam.se3 import inverse
    from bench.slam.system import System

    built = validate(compose(["threads=1", *sys.argv[1:]]))
    cfg = built.config
    seq = open_seq(cfg)
    device = torch.device("cpu")
    frames = [seq[i] for i in range(min(13, len(seq)))]
    first = torch.linalg.inv(frames[0].gt_c2w.double())
    gt = [inverse((first @ f.gt_c2w.double()).float()) for f in frames]  # [4, 4] w2c, frame 0 at the origin
    with repeatable(cfg.seed, cfg.threads, cfg.determinism, device):
        s = System(cfg.slam, seq.K, seq.height, seq.width, built.strategy, cfg.prune, device)
        s.tracking.track = lambda idx, rgb, depth, poses, init=None: (gt[idx], 0.0)
        rgb0, depth0 = s.observe(frames[0])
        has = depth0 > 0

        def psnr_kf0(params: dict[str, torch.Tensor], sel: torch.Tensor | None = None) -> float:
            m = torch.ones(len(params["means"]), dtype=torch.bool) if sel is None else sel
            with torch.no_grad():
                out = rasterize(
                    params["means"][m],
                    drawn_log_scales(params["log_scales"][m], cfg.slam.isotropic),
                    params["quats"][m],
                    torch.sigmoid(params["opacity_logits"][m]),
                    params["colors"][m],
                    gt[0],
                    s.K,
                    s.W,
                    s.H,
                    depth_far_m=cfg.slam.depth_far_m,
                    backend=cfg.slam.raster_backend,
                    antialiased=cfg.slam.raster_antialias,
                )
            return region_psnr_db((out.color.clamp(0, 1) - rgb0).pow(2).mean(-1), has)

        print(
            f"# {seq.name} {seq.width}x{seq.height}, preset {cfg.slam.name}, ground-truth poses; keyframe 0's "
            "PSNR dB over its pixels with depth"
        )
        print(
            "| after keyframe | frame | whole map | keyframe 0's Gaussians now | as after its own mapping | Gaussians |"
        )
        print("|---|---|---|---|---|---|")
        snap = None
        for k, frame in enumerate(frames):
            r = s.step(frame)
            if not r.is_keyframe:
                continue
            now = {name: p.detach() for name, p in s.map.params.items()}
            if snap is None:
                snap = {name: p.clone() for name, p in now.items()}
            born0 = s.map.birth_kf == 0
            print(
                f"| {r.keyframe_index} | {k} | {psnr_kf0(now):.2f} | {psnr_kf0(now, born0):.2f} | "
                f"{psnr_kf0(snap):.2f} | {len(s.map)} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
