"""Where a map's decibels go: one run's fit taken apart, cause by cause.

Drives the SLAM system of a config over its frames (the same ``System`` a run builds, seeded the
same way) and prints:

- per keyframe, its own render right after its mapping: PSNR over the whole image, over the pixels
  with observed depth and over those without (the ``kf_psnr_*`` columns of ``keyframes.csv``), and
  the whole-image PSNR of the depth-masked images (SplaTAM's evaluation: masked pixels count as perfect);
- the convergence curve of the first keyframe: PSNR against mapping iteration (``--curve``);
- from the final map at the estimated poses: keyframes against the frames between them, each split
  into pixels with and without depth, and the dB a per-frame affine brightness (least squares
  ``a * render + b`` over the pixels with depth) would add: what exposure changes cost;
- a table that gives each cause its dB.

    python profiling/fit_diagnosis.py                                   # KITTI 06 shared frames, 1/2, 20 frames
    python profiling/fit_diagnosis.py --frames 51 --overrides "slam=faithful"
    python profiling/fit_diagnosis.py --overrides "seq=04" --curve 100,300,1000
    python profiling/fit_diagnosis.py --gt-poses      # mapped at the dataset's poses: what tracking error costs
    python profiling/fit_diagnosis.py --defaults "dataset=synthetic" --overrides "dataset.depth_noise_rel=0.05"

Defaults: ``dataset=kitti dataset.root=<shared>/data/kitti seq=06`` (1/2 resolution), ``threads=2``.
"""

from __future__ import annotations

import argparse
import math
import shlex
import sys
import time
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # measure the checkout this file sits in, not whichever one is pip-installed
SHARED_KITTI = ROOT.parent / "shared" / "data" / "kitti"  # ../shared beside the checkout
DEFAULT = f"dataset=kitti dataset.root={SHARED_KITTI} seq=06 threads=2"


def psnr(sq: torch.Tensor, sel: torch.Tensor | None = None) -> float:
    """``region_psnr_db`` with NaN for an empty region, so region means skip it."""
    from bench.metrics.image import region_psnr_db

    value = region_psnr_db(sq, sel)
    return math.nan if value is None else value


def affine_gain_db(pred: torch.Tensor, target: torch.Tensor, sel: torch.Tensor) -> float:
    """dB added over ``sel`` by the best ``a * pred + b`` per frame (least squares over ``sel``)."""
    p, t = pred[sel].double().reshape(-1), target[sel].double().reshape(-1)
    if p.numel() < 2:
        return math.nan
    A = torch.stack([p, torch.ones_like(p)], 1)
    coef = torch.linalg.lstsq(A, t[:, None]).solution[:, 0]
    before = float((p - t).pow(2).mean())
    after = float((A @ coef - t).pow(2).mean())
    return 10.0 * math.log10(before / after) if after > 0 else math.inf


def map_color(system, w2c: torch.Tensor, params: list[torch.Tensor]) -> torch.Tensor:
    """[H, W, 3] colour of ``params`` (means, log-scales, quats, opacities, colours: the map's, altered) at
    ``w2c``, rendered with the system's camera and settings, as ``System.render`` renders the map."""
    from bench.slam.raster import drawn_log_scales, rasterize

    cfg = system.cfg
    means, log_scales, *rest = params
    out = rasterize(
        means,
        drawn_log_scales(log_scales, cfg.isotropic),
        *rest,
        w2c,
        system.K,
        system.W,
        system.H,
        depth_far_m=cfg.depth_far_m,
        backend=cfg.raster_backend,
        antialiased=cfg.raster_antialias,
    )
    return out.color


def realigned_psnr(system, w2c: torch.Tensor, rgb: torch.Tensor, has: torch.Tensor, iters: int) -> float:
    """PSNR over ``has`` of the final map at ``w2c`` after re-aligning the pose alone to it (Adam on a twist,
    L1 colour over ``has``, the map frozen): what of a keyframe's drop is misalignment between views."""
    from bench.slam.se3 import se3_exp

    g = system.map
    params = [t.detach() for t in (g.means, g.log_scales, g.quats, g.opacities, g.colors)]
    xi = torch.zeros(6, requires_grad=True)
    opt = torch.optim.Adam([xi], lr=1e-3)  # about a millimetre and 0.06 degrees a step
    sel = has.float()[..., None]
    for _ in range(iters):
        loss = ((map_color(system, se3_exp(xi) @ w2c, params) - rgb).abs() * sel).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
    with torch.no_grad():
        sq = (map_color(system, se3_exp(xi) @ w2c, params).clamp(0, 1) - rgb).pow(2).mean(-1)
    return psnr(sq, has)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--defaults", default=DEFAULT, help=f"Hydra overrides first (default: {DEFAULT})")
    ap.add_argument("--overrides", default="", help="Hydra overrides after the defaults")
    ap.add_argument("--frames", type=int, default=20, help="frames to drive (max_frames)")
    ap.add_argument("--curve", default="50,100,200,500", help="mapping iterations at which keyframe 0 is scored")
    ap.add_argument(
        "--gt-poses",
        action="store_true",
        help="map at the dataset's ground-truth poses instead of tracking: what pose error costs the fit",
    )
    ap.add_argument(
        "--realign",
        type=int,
        default=0,
        help="Adam steps re-aligning each keyframe's pose to the final map before it is scored again (0: off)",
    )
    args = ap.parse_args()

    from bench.cli.entry import compose
    from bench.run.determinism import repeatable
    from bench.run.setup import open_seq
    from bench.run.validate import validate
    from bench.slam.system import System

    overrides = [*shlex.split(args.defaults), *shlex.split(args.overrides)]
    built = validate(compose(overrides))
    cfg = built.config
    seq = open_seq(cfg)
    n = min(len(seq), args.frames)
    device = torch.device("cpu")
    curve_at = sorted(int(c) for c in args.curve.split(",") if c.strip())
    print(
        f"# fit diagnosis: {seq.name} {seq.width}x{seq.height}, {n} frames, preset {cfg.slam.name}, "
        f"{'ground-truth poses, ' if args.gt_poses else ''}overrides: {' '.join(overrides)}"
    )

    # convergence curve: keyframe 0 alone, mapped for the largest count, scored along the way
    with repeatable(cfg.seed, cfg.threads, cfg.determinism, device):
        import dataclasses

        slam = dataclasses.replace(cfg.slam, mapping_iters=max(curve_at))
        system = System(slam, seq.K, seq.height, seq.width, built.strategy, cfg.prune, device)
        frame0 = seq[0]
        rgb0, depth0 = system.observe(frame0)
        curve: list[tuple[int, float, float, float]] = []
        step = system.map.optimizer.step
        count = [0]
        eye = torch.eye(4)

        def counted_step(*a, **k):
            res = step(*a, **k)
            count[0] += 1
            if count[0] in curve_at:
                with torch.no_grad():
                    sq = (system.render(eye).color.clamp(0, 1) - rgb0).pow(2).mean(-1)
                has = depth0 > 0
                curve.append((count[0], psnr(sq), psnr(sq, has), time.perf_counter() - t0))
            return res

        system.map.optimizer.step = counted_step
        t0 = time.perf_counter()
        system.step(frame0)

    # the run itself
    with repeatable(cfg.seed, cfg.threads, cfg.determinism, device):
        system = System(cfg.slam, seq.K, seq.height, seq.width, built.strategy, cfg.prune, device)
        if args.gt_poses:
            c2w0 = seq[0].gt_c2w
            if c2w0 is None:
                raise SystemExit(f"--gt-poses: expected ground-truth poses in {seq.name}, found none")

            def gt_track(index: int, rgb: torch.Tensor, depth: torch.Tensor, *_poses) -> tuple[torch.Tensor, float]:
                c2w = seq[index].gt_c2w
                assert c2w is not None and c2w0 is not None
                return (torch.linalg.inv(c2w) @ c2w0).float().to(device), 0.0  # [4, 4] w2c, world = frame 0

            system.tracking.track = gt_track  # type: ignore[method-assign]
        kf_rows = []
        t0 = time.perf_counter()
        for i in range(n):
            frame = seq[i]
            res = system.step(frame)
            if res.is_keyframe:
                d = res.diag
                masked = d["kf_psnr_depth_db"] - 10 * math.log10(d["kf_depth_frac"]) if d["kf_depth_frac"] else math.nan
                kf_rows.append(
                    (
                        res.keyframe_index,
                        i,
                        d["kf_psnr_db"],
                        d["kf_psnr_depth_db"],
                        d["kf_psnr_nodepth_db"],
                        masked,
                        len(system.map),
                    )
                )
        wall = time.perf_counter() - t0
        system.mapping.refine(cfg.slam.refine_iters)  # as a run does before it evaluates (0 = none)
        stats = {"kf": [], "between": []}
        final_kf: dict[int, tuple[float, float]] = {}  # keyframe frame -> final map, its own Gaussians' share
        kf_of_frame = {r[1]: r[0] for r in kf_rows}
        realigned: dict[int, float] = {}  # keyframe frame -> final map at the re-aligned pose (--realign)
        with torch.no_grad():
            kf_frames = {kf.index for kf in system.keyframes}
            for i, w2c in enumerate(system.poses):
                frame = seq[i]
                rgb, depth = system.observe(frame)
                pred = system.render(w2c).color.clamp(0, 1)
                sq = (pred - rgb).pow(2).mean(-1)
                has = depth > 0
                frac = float(has.float().mean())
                if i in kf_of_frame:
                    # the final map without the Gaussians born after this keyframe: the parameters they left
                    # alone or moved, apart from what later seeds paint over this view
                    g = system.map
                    older = (g.birth_kf <= kf_of_frame[i]).to(g.opacities.dtype)
                    color = map_color(system, w2c, [g.means, g.log_scales, g.quats, g.opacities * older, g.colors])
                    sq_old = (color.clamp(0, 1) - rgb).pow(2).mean(-1)
                    final_kf[i] = (psnr(sq, has), psnr(sq_old, has))
                    if args.realign:
                        with torch.enable_grad():
                            realigned[i] = realigned_psnr(system, w2c, rgb, has, args.realign)
                row = (
                    psnr(sq),
                    psnr(sq, has),
                    psnr(sq, ~has),
                    psnr(sq, has) - 10 * math.log10(max(frac, 1e-9)),
                    affine_gain_db(pred, rgb, has),
                )
                stats["kf" if frame.index in kf_frames else "between"].append(row)

    print(f"\nrun: {n} frames in {wall:.1f} s (SLAM loop, fit diagnostics included), {len(system.map)} Gaussians")
    print("\n## each keyframe right after its mapping (PSNR dB)\n")
    print(
        "| kf | frame | whole image | with depth | without depth | depth-masked (SplaTAM) | Gaussians "
        "| final map, with depth | final map, Gaussians born by this kf, with depth "
        "| final map, pose re-aligned, with depth |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in kf_rows:
        fin, old = final_kf.get(r[1], (math.nan, math.nan))
        print(
            f"| {r[0]} | {r[1]} | {r[2]:.2f} | {r[3]:.2f} | "
            f"{'-' if r[4] is None else f'{r[4]:.2f}'} | {r[5]:.2f} | {r[6]} | {fin:.2f} | {old:.2f} "
            f"| {realigned.get(r[1], math.nan):.2f} |"
        )
    print("\n## keyframe 0 against mapping iterations (alone, before any other frame)\n")
    print("| iterations | whole image dB | with depth dB | s |")
    print("|---|---|---|---|")
    for it, full, dep, s in curve:
        print(f"| {it} | {full:.2f} | {dep:.2f} | {s:.1f} |")

    def mean(rows: list, k: int) -> float:
        vals = [r[k] for r in rows if math.isfinite(r[k])]
        return sum(vals) / len(vals) if vals else math.nan

    print("\n## final map at the estimated poses (mean PSNR dB per frame)\n")
    print("| frames | n | whole image | with depth | without depth | depth-masked | + affine brightness (with depth) |")
    print("|---|---|---|---|---|---|---|")
    for name, rows in (
        ("keyframes", stats["kf"]),
        ("between keyframes", stats["between"]),
        ("all", stats["kf"] + stats["between"]),
    ):
        if rows:
            print(
                f"| {name} | {len(rows)} | {mean(rows, 0):.2f} | {mean(rows, 1):.2f} | {mean(rows, 2):.2f} | "
                f"{mean(rows, 3):.2f} | +{mean(rows, 4):.2f} |"
            )

    all_rows = stats["kf"] + stats["between"]
    own_dep = sum(r[3] for r in kf_rows) / len(kf_rows)
    curve_gain = curve[-1][2] - next((c[2] for c in curve if c[0] >= cfg.slam.mapping_iters), curve[0][2])
    print("\n## each cause's dB (the whole-image PSNR of all frames is the starting point)\n")
    print("| cause | dB | read as |")
    print("|---|---|---|")
    print(
        f"| pixels without depth | {mean(all_rows, 1) - mean(all_rows, 0):+.2f} | with-depth PSNR minus whole-image |"
    )
    print(
        f"| protocol (SplaTAM's depth mask) | {mean(all_rows, 3) - mean(all_rows, 0):+.2f} | "
        "masked whole-image PSNR minus whole-image |"
    )
    print(
        f"| frames between keyframes | {mean(stats['between'], 1) - mean(stats['kf'], 1):+.2f} | "
        "with depth, between minus keyframes (final map) |"
    )
    print(
        f"| later mapping (keyframes revisited) | {mean(stats['kf'], 1) - own_dep:+.2f} | "
        "with depth, keyframes in the final map minus right after their own mapping |"
    )
    fin_rows = [v for v in final_kf.values() if all(math.isfinite(x) for x in v)]
    if fin_rows:
        later_seeds = sum(f - o for f, o in fin_rows) / len(fin_rows)
        print(
            f"| ... of which later seeds | {later_seeds:+.2f} | with depth, keyframes in the final map minus the "
            "same without the Gaussians born after them |"
        )
    if realigned:
        gain = sum(realigned[f] - final_kf[f][0] for f in realigned) / len(realigned)
        print(
            f"| ... recovered by re-aligning the pose | {gain:+.2f} | with depth, keyframes in the final map at a pose "
            f"re-aligned to it ({args.realign} steps) minus at their own |"
        )
    print(
        f"| iterations (keyframe 0 to {curve_at[-1]}) | {curve_gain:+.2f} | with depth, at {curve_at[-1]} "
        f"iterations minus at the preset's {cfg.slam.mapping_iters} |"
    )
    print(f"| exposure (affine per frame) | {mean(all_rows, 4):+.2f} | with depth, best affine brightness |")


if __name__ == "__main__":
    main()
