"""After the frame loop (none of it SLAM time): refinement, the memory and time summary, the evaluation
(ATE, path length, PSNR/SSIM/MS-SSIM/LPIPS under ``eval.protocol``) and the run's own figures."""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch

from bench import schema
from bench.measure.progress import Phase
from bench.metrics.image import MS_SSIM_MIN_PX
from bench.run.config import RunConfig
from bench.run.export import MAP_FILE, write_map
from bench.run.outcome import LoopOutcome
from bench.run.rows import FlushedRows
from bench.slam.se3 import inverse
from bench.slam.system import System

if TYPE_CHECKING:
    from bench.run.setup import RunSetup

log = logging.getLogger(__name__)


def finish(
    cfg: RunConfig,
    parts: RunSetup,
    drive: LoopOutcome,
    out: Path,
    device: torch.device,
    metrics: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """After the loop (none of it SLAM time): refine, summarise memory and time, evaluate, plot.

    A stopped or failed run (``partial``) skips refinement, rendering and the density figure: the
    trajectory metrics over the frames done are what it can still say. Every figure goes into
    ``metrics`` as soon as it is known, so a stop during refinement or the image metrics (minutes at
    full resolution) keeps the frame rate, memory, map size and ATE that were already computed.
    """
    system, timer = parts.system, parts.timer
    partial = drive.status in ("interrupted", "failed")
    n_done = len(drive.timestamps_s)
    metrics = {} if metrics is None else metrics
    metrics.update({"slam_wall_s": round(drive.loop_s, 3), "warmup_s": round(drive.warmup_s, 3)})
    if not partial:  # slam.residency: the whole map is refined, rendered and written, not the live part alone
        system.restore_all()
    warmup = cfg.warmup_frames
    metrics["fps"] = round((n_done - warmup) / drive.loop_s, 4) if drive.loop_s > 0 and n_done > warmup else None
    metrics["fps_slam"] = fps_slam(timer.totals(), n_done)
    # per-phase seconds of the frame loop, warm-up frames included: they sum to about
    # slam_wall_s + warmup_s (less the frame handling outside the phases); refinement is refine_s
    metrics["phase_s"] = {k: round(v, 3) for k, v in timer.totals().items() if k != "refine"}
    metrics["memory_method"] = {
        "cpu_rss": parts.probe.rss_method,
        "torch_live": cfg.memory.torch_live,
        "malloc": parts.malloc,
    }
    metrics.update(schema.memory_summary([*drive.windows, drive.tail], device.type))
    metrics.update(schema.regime_summary(drive.windows, (system.H, system.W), metrics[schema.PEAK_SOURCE_FIELD]))
    metrics["gaussians_final"] = len(system.map)
    metrics["tracking_velocity_starts"] = system.tracking.init_source.count("velocity")
    # churn: did pruning shrink the map, or only feed re-seeding?
    metrics["gaussians_added_total"] = sum(w["n_added"] for w in drive.windows)
    metrics["gaussians_pruned_total"] = sum(w["n_pruned"] for w in drive.windows)
    metrics["prune_candidates_total"] = sum(w["n_candidates"] for w in drive.windows)
    metrics["keep_ratio"] = parts.keys["keep_ratio"]  # as in run.keep_ratio: null when nothing is pruned
    est_c2w = tracked_c2w(system, n_done)  # refinement fits the map only: the poses stay as tracked
    if cfg.slam.refine_iters > 0 and not partial:
        with (
            FlushedRows(
                out / schema.REFINE_CURVE_FILE, schema.REFINE_CURVE_COLUMNS, False, bool(cfg.eval.at_refine_iters)
            ) as rows,
            timer.phase("refine"),
            Phase("refine", cfg.slam.refine_iters, "iteration", cfg.progress) as bar,
        ):
            curve = RefineCurve(cfg, parts, est_c2w, device, rows, bar.update)
            system.mapping.refine(cfg.slam.refine_iters, on_step=curve.step)
        metrics["refine_s"] = round(timer.totals()["refine"] - curve.eval_s, 3)  # the curve's rows are not refinement
    t_eval = time.perf_counter()
    metrics.update(evaluate(cfg, out, parts, est_c2w, drive, device, images=not partial, into=metrics))
    metrics["eval_s"] = round(time.perf_counter() - t_eval, 3)  # ATE, rendering, PSNR/SSIM/LPIPS
    from bench.run.figures.run_memory import memory_timeline

    memory_timeline(out / "memory.png", drive.windows, title=f"{parts.keys['strategy']} on {parts.seq.name}")
    if not partial:
        write_density(out / "density.npz", system)
    write_map(out / MAP_FILE, system.map)
    if parts.viz is not None:
        parts.viz.draw_all()
    return metrics


SLAM_PHASES = ("tracking", "mapping", "pruning", "residency")  # what fps_slam counts


def fps_slam(phase_s: dict[str, float], n_frames: int) -> float | None:
    """Frames per second of tracking and mapping alone, as the paper's released code counts FPS:
    1 / (tracking + mapping seconds per frame). Pruning and residency checks count as mapping (they run in
    the keyframe's mapping step); frame loading, stereo depth and the loop's own bookkeeping do not. Warm-up
    frames count (their phases are in ``phase_s``). None when no SLAM phase ran."""
    slam_s = sum(phase_s.get(k, 0.0) for k in SLAM_PHASES)
    return round(n_frames / slam_s, 4) if slam_s > 0 and n_frames > 0 else None


def tracked_c2w(system: Any, n_done: int) -> list[torch.Tensor]:
    """The first ``n_done`` tracked poses as camera-to-world, in float64 on the CPU, as the metrics read them."""
    return [inverse(p.detach().double().cpu()) for p in system.poses[:n_done]]  # each [4, 4]


@torch.no_grad()
def write_density(path: Path, system: System) -> None:
    """Histogram [H, W] of the final map's projected centres at the last keyframe's pose (paper Fig. 4)."""
    if not system.keyframes:
        return
    kf = system.keyframes[-1]
    out = system.render(kf.w2c)
    m2 = out.means2d  # [N, 2] px
    ok = (out.depths > 0) & (m2[:, 0] >= 0) & (m2[:, 0] < system.W) & (m2[:, 1] >= 0) & (m2[:, 1] < system.H)
    u = m2[ok, 0].long().cpu().numpy()
    v = m2[ok, 1].long().cpu().numpy()
    counts = np.zeros((system.H, system.W), dtype=np.int32)
    np.add.at(counts, (v, u), 1)
    np.savez_compressed(path, counts=counts, image=kf.rgb.cpu().numpy(), frame=kf.index)


def evaluate(
    cfg: RunConfig,
    out: Path,
    parts: RunSetup,
    est_c2w: list[torch.Tensor],
    drive: LoopOutcome,
    device: torch.device,
    images: bool = True,
    write_gt: bool = True,
    into: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """ATE (evo), path-length ratio, PSNR/SSIM/MS-SSIM (torchmetrics), LPIPS when weights exist; none of
    it is SLAM time.

    The image metrics are scored under ``eval.protocol`` (``bench.metrics.protocol``): the whole image,
    or the pixels SplaTAM's valid-depth mask or the released code's silhouette mask keeps.
    ``images=False`` (a stopped or failed run) skips rendering: the trajectory metrics only.
    traj_est.txt is already on disk, appended frame by frame. ``into`` gets the trajectory metrics
    before any frame is rendered, so a stop during the image metrics keeps them.
    """
    from bench.metrics.trajectory import Trajectory, ate, path_length_ratio, rpe, write_tum

    ev = cfg.eval
    res: dict[str, Any] = {
        "ate_rmse_m": None,
        "psnr_db": None,
        "ssim": None,
        "ms_ssim": None,
        "lpips": None,
        "eval_protocol": ev.protocol,
    }
    if not est_c2w:
        return res
    ts = np.asarray(drive.timestamps_s)
    est = Trajectory.from_c2w(ts, torch.stack(est_c2w).numpy())
    if all(g is not None for g in drive.gt_c2w) and len(est_c2w) >= 3:
        gt_world = torch.stack([g.double() for g in drive.gt_c2w if g is not None])  # all are, checked above
        gt_world = inverse(gt_world[0]).expand_as(gt_world) @ gt_world  # first camera = origin, like the estimate
        gt = Trajectory.from_c2w(ts, gt_world.numpy())
        if write_gt:
            write_tum(out / "traj_gt.txt", gt)
        res.update(ate(est, gt, align=ev.ate_align, max_diff_s=ev.max_diff_s))
        res["ate_first_frame"], res["ate_last_frame"] = 0, len(est_c2w) - 1  # inclusive, tracked-frame positions
        res["path_length_m"] = round(float(np.linalg.norm(np.diff(gt.positions_m, axis=0), axis=1).sum()), 4)
        ratio = path_length_ratio(est, gt, max_diff_s=ev.max_diff_s)
        res["path_length_ratio"] = None if ratio is None else round(ratio, 5)
        if ev.rpe:
            res.update(rpe(est, gt, align=ev.ate_align, max_diff_s=ev.max_diff_s))
    if into is not None:
        into.update(res)
    if not images:
        return res
    res.update(image_metrics(cfg, parts, est_c2w, device))
    if min(parts.seq.height, parts.seq.width) < MS_SSIM_MIN_PX:
        log.info(
            "ms_ssim: n/a: %dx%d px images are smaller than the %d px MS-SSIM needs on a side",
            parts.seq.height,
            parts.seq.width,
            MS_SSIM_MIN_PX,
        )
    return res


class RefineCurve:
    """The final refinement's curve (``eval.at_refine_iters``): after each listed iteration, the image metrics of
    the map as it is then, one flushed ``refine_curve.csv`` row each.

    Rendering reads the map under ``no_grad`` and draws no random number, so the refinement's iterations, and the
    map it ends with, are the ones a run without the curve makes (``tests/test_refine_curve.py``). The rows' time
    is kept apart (``eval_s``) and taken out of ``refine_s``."""

    def __init__(
        self,
        cfg: RunConfig,
        parts: RunSetup,
        est_c2w: list[torch.Tensor],
        device: torch.device,
        rows: FlushedRows,
        tick: Callable[[], None],
    ) -> None:
        self.cfg, self.parts, self.est_c2w, self.device, self.rows, self.tick = cfg, parts, est_c2w, device, rows, tick
        self.at = set(cfg.eval.at_refine_iters)
        self.done, self.eval_s, self.t0 = 0, 0.0, time.perf_counter()

    def step(self) -> None:
        """Called once an iteration is done (``Mapping.refine``'s ``on_step``)."""
        self.tick()
        self.done += 1
        if self.done not in self.at:
            return
        t = time.perf_counter()
        res = image_metrics(self.cfg, self.parts, self.est_c2w, self.device)
        eval_s = time.perf_counter() - t
        row = {k: res.get(k) for k in schema.ROW_IMAGE_COLUMNS}
        row.update(
            refine_iters=self.done,
            refine_s=round(t - self.t0 - self.eval_s, 3),
            eval_s=round(eval_s, 3),
        )
        self.eval_s += eval_s
        self.rows.writerow(row)


def image_metrics(cfg: RunConfig, parts: RunSetup, est_c2w: list[torch.Tensor], device: torch.device) -> dict[str, Any]:
    """PSNR/SSIM/MS-SSIM/LPIPS of the map as it is, under ``eval.protocol``, at every ``eval.every``-th tracked pose."""
    from bench.metrics.lpips import LPIPS
    from bench.metrics.protocol import frame_metrics, mean_metrics, protocol_mask

    ev = cfg.eval
    res: dict[str, Any] = {}
    idx = list(range(0, len(est_c2w), max(1, ev.every)))
    near_m, far_m = eval_depth_range(cfg.dataset)
    lp = parts.lpips or (LPIPS.from_weights(ev.lpips_weights) if ev.lpips else None)
    on = device if ev.device == "run" else torch.device("cpu")  # eval.device: where the metrics are computed
    lp = lp.to(on) if lp is not None else None
    frames = []
    with Phase("evaluate", len(idx), "frame", cfg.progress) as bar:
        with torch.no_grad():
            for i in idx:
                w2c = inverse(est_c2w[i]).float().to(device)
                render = parts.system.render(w2c)
                frame = parts.seq[i]
                depth_m = None if frame.depth_m is None else frame.depth_m.to(on)
                mask = protocol_mask(ev.protocol, depth_m, render.alpha.to(on), near_m, far_m)  # [H, W] or None
                frames.append(frame_metrics(ev.protocol, render.color.clamp(0, 1).to(on), frame.rgb.to(on), mask, lp))
                bar.update(1)
    img = mean_metrics(frames)
    img.pop("num_frames", None)  # that count is res["eval_frames"]; metrics["num_frames"] is frames tracked
    mask_frac = img.pop("mask_frac", None)
    res.update({k: _finite_or_none(v) if isinstance(v, float) else v for k, v in img.items()})
    if ev.protocol != "full":
        res["eval_mask_frac"] = None if mask_frac is None else round(mask_frac, 5)
        if ev.protocol == "splatam":
            res["eval_depth_range_m"] = [near_m, far_m]
    res["eval_frames"] = len(idx)
    return res


def eval_depth_range(dataset: Any) -> tuple[float, float | None]:
    """The dataset's ``eval_depth_near_m`` / ``eval_depth_far_m`` (a plugin's plain dict may lack them)."""
    get = dataset.get if isinstance(dataset, dict) else lambda k, d: getattr(dataset, k, d)
    return float(get("eval_depth_near_m", 0.0)), get("eval_depth_far_m", None)


def _finite_or_none(x: float | None) -> float | None:
    return None if x is None or not math.isfinite(x) else float(x)
