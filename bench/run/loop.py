"""The frame loop: every frame fed to the SLAM system, one flushed ``keyframes.csv`` row per keyframe
window and one flushed ``traj_est.txt`` line per frame, so a stopped run keeps what it tracked.

Checkpoints are written from here (``bench.run.checkpoint``), after a keyframe's prune.
"""

from __future__ import annotations

import json
import logging
import time
from pathlib import Path
from typing import Any

import torch

from bench import schema
from bench.errors import BenchError, TrackingLost
from bench.measure.progress import Phase
from bench.metrics.trajectory import TumAppender, window_path_ratios
from bench.run import checkpoint as ckpt
from bench.run.config import RunConfig
from bench.run.evaluation import evaluate, tracked_c2w
from bench.run.export import save_snapshot
from bench.run.outcome import LoopOutcome
from bench.run.record import RunRecord
from bench.run.rows import FlushedRows
from bench.run.setup import RunSetup, inner_strategy
from bench.run.signals import Interrupted, Preemption, signal_behind
from bench.slam.se3 import inverse
from bench.slam.system import FrameResult

log = logging.getLogger(__name__)

TRAJ_EST = "traj_est.txt"


def flushed_rows(out: Path) -> dict[str, int]:
    """Data rows on disk in the files a checkpoint counts (each has one header line)."""
    return {
        "traj": ckpt.data_rows(out / TRAJ_EST, 1),
        "keyframes": ckpt.data_rows(out / schema.KEYFRAMES_FILE, 1),
        "milestones": ckpt.data_rows(out / schema.MILESTONES_FILE, 1),
    }


def run_frames(
    cfg: RunConfig,
    parts: RunSetup,
    out: Path,
    record: RunRecord,
    start: dict[str, Any] | None = None,
    preempt: Preemption | None = None,
) -> LoopOutcome:
    """Feed every frame to the system; one flushed keyframes.csv row per keyframe window and one
    flushed traj_est.txt line per frame, so a stopped run keeps what it tracked.

    ``start``: a checkpoint to continue from (its frames and rows are already done and on disk).
    ``preempt``: a held preemption signal ends the loop at the next frame boundary, with a checkpoint.
    """
    system, device = parts.system, parts.system.device
    metrics = record["metrics"]
    drive = LoopOutcome()
    warmup = cfg.warmup_frames
    bar = Phase("frames", parts.n_frames, "frame", cfg.progress)
    # prune.every=frame: what the frames since the last keyframe pruned
    between: dict[str, Any] = dict.fromkeys(
        ("n_pruned", "n_candidates", "prune_s", "diag_s", *schema.PRUNE_COUNT_COLUMNS), 0
    )
    first = 0
    if start is not None:
        between, first = _resume(drive, start, metrics, bar)
    parts.probe.start_window()
    with (
        FlushedRows(out / schema.KEYFRAMES_FILE, schema.KEYFRAME_COLUMNS, start is not None) as keyframes,
        TumAppender(out / TRAJ_EST, append=start is not None) as traj,
        FlushedRows(
            out / schema.MILESTONES_FILE, schema.MILESTONE_COLUMNS, start is not None, bool(cfg.eval.at_frames)
        ) as milestones,
    ):
        try:
            for i in range(first, parts.n_frames):
                frame = parts.seq[i]  # loading is not SLAM time
                _sync(device)
                t0 = time.perf_counter()
                res = system.step(frame)
                _sync(device)
                if i >= warmup:
                    drive.loop_s += time.perf_counter() - t0
                else:
                    drive.warmup_s += time.perf_counter() - t0
                traj.append(frame.timestamp_s, inverse(res.w2c.detach().double().cpu()).numpy())
                drive.timestamps_s.append(frame.timestamp_s)
                drive.gt_c2w.append(frame.gt_c2w)
                metrics["num_frames"] = i + 1
                if not res.is_keyframe:
                    between = {
                        k: v + (getattr(res, k) if hasattr(res, k) else res.diag.get(k, 0)) for k, v in between.items()
                    }
                else:
                    row = keyframe_row(parts, res, frame.index, between)
                    row.update(path_window(system, drive, drive.windows[-1]["frame"] if drive.windows else i))
                    between = dict.fromkeys(between, 0)
                    keyframes.writerow(row)
                    drive.windows.append(row)
                if i + 1 in cfg.eval.at_frames:  # before the checkpoint, which counts its row
                    with parts.probe.paused():
                        milestones.writerow(milestone_row(cfg, parts, drive, out))
                if res.is_keyframe:
                    assert res.keyframe_index is not None  # System.step sets it with is_keyframe
                    _close_window(cfg, parts, drive, out, record, between, res.keyframe_index)
                bar.update(1, gaussians=len(system.map), fps=f"{(i + 1 - warmup) / max(drive.loop_s, 1e-9):.2f}")
                if preempt is not None and preempt.signum is not None:  # held since it came: stop here, resumable
                    write_checkpoint(cfg, parts, drive, out, record, between)
                    record.save()
                    raise Interrupted(preempt.signum)
        except TrackingLost as exc:
            drive.status, drive.error = "lost", str(exc)
            bar.close(note=f"lost: {exc}")
            log.warning("%s", exc)
        except (Interrupted, SystemError, RuntimeError) as exc:  # stopped: the frames done are still a result
            stop = signal_behind(exc)
            if stop is None:
                raise
            drive.status, drive.error, drive.stop = "interrupted", f"{stop} after {metrics['num_frames']} frames", stop
        except BenchError as exc:  # bad data mid-run (a corrupt frame): keep the partial record, failed
            drive.status, drive.error = "failed", f"{exc} (after {metrics['num_frames']} frames)"
        finally:
            bar.close()
            # the frames after the last keyframe form a window no keyframes.csv row closes: their peaks count too
            drive.tail = {**parts.probe.end_window(), "n_gaussians": len(system.map)}
            parts.probe.close()
    return drive


def _resume(
    drive: LoopOutcome, start: dict[str, Any], metrics: dict[str, Any], bar: Phase
) -> tuple[dict[str, Any], int]:
    """A checkpoint's loop state put back into ``drive``, ``metrics`` and the progress bar; returns what the
    frames since the last keyframe pruned, and the first frame still to run."""
    done = json.loads(start["drive"]["json"])  # floats round-trip json exactly
    drive.timestamps_s = start["drive"]["timestamps_s"].tolist()
    drive.gt_c2w = list(start["drive"]["gt_c2w"])
    drive.windows, drive.loop_s, drive.warmup_s = done["windows"], done["loop_s"], done["warmup_s"]
    first = start["frame"]
    metrics.update(num_frames=first, num_keyframes=len(drive.windows))
    bar.update(first)
    return done["between"], first


def _close_window(
    cfg: RunConfig,
    parts: RunSetup,
    drive: LoopOutcome,
    out: Path,
    record: RunRecord,
    between: dict[str, Any],
    keyframe: int,
) -> None:
    """After keyframe ``keyframe``'s row: its map snapshot (``save_maps=every_keyframe``), a checkpoint every
    ``checkpoint.every`` keyframes, the record saved, and the next memory window opened."""
    if cfg.save_maps == "every_keyframe":
        save_snapshot(out, keyframe, parts.system.map)
    record["metrics"]["num_keyframes"] = len(drive.windows)
    every = cfg.checkpoint.every
    if every and (keyframe + 1) % every == 0:
        write_checkpoint(cfg, parts, drive, out, record, between)
    record.save()  # still running; counts so far, for a later reader
    parts.probe.start_window()


def write_checkpoint(
    cfg: RunConfig, parts: RunSetup, drive: LoopOutcome, out: Path, record: RunRecord, between: dict[str, Any]
) -> None:
    """The loop's whole state after the frames done so far (see ``bench.run.checkpoint``); its cost goes into
    metrics.json's ``checkpoint`` block, outside the SLAM time and the metrics a resume must repeat."""
    stats = record["checkpoint"]
    n_done = len(drive.timestamps_s)
    payload = {
        "key": {k: record["run"][k] for k in ("config_hash", "code_version", "inputs")},
        "frame": n_done,
        "keyframe": drive.windows[-1]["kf"] if drive.windows else -1,
        "system": parts.system.state_dict(),
        "strategy": dict(vars(inner_strategy(parts.strategy))),
        # per-frame lists as one tensor, rows as one json string: torch.save pays per object
        "drive": {"timestamps_s": torch.tensor(drive.timestamps_s, dtype=torch.float64),
                  "gt_c2w": _stack_all(drive.gt_c2w),
                  "json": json.dumps({"windows": drive.windows, "loop_s": drive.loop_s, "warmup_s": drive.warmup_s,
                                      "between": between, "phase_s": parts.timer.totals(),
                                      "phase_n": parts.timer.counts()})},
        "rng": ckpt.global_rng_state(),
        "rows": {"traj": n_done, "keyframes": len(drive.windows),
                 "milestones": sum(1 for n in cfg.eval.at_frames if n <= n_done)},
        "stats": {**stats, "written": stats["written"] + 1},  # as they will be once this one is on disk
    }  # fmt: skip
    cost = ckpt.save(out, payload, cfg.checkpoint.keep)
    stats.update(
        written=stats["written"] + 1, mib_last=cost.mib, write_s_total=round(stats["write_s_total"] + cost.write_s, 4)
    )
    log.debug(
        "%s: checkpoint at frame %d (keyframe %d): %.3f MiB in %.4f s",
        out,
        n_done,
        payload["keyframe"],
        cost.mib,
        cost.write_s,
    )


def _stack_all(mats: list[torch.Tensor | None]) -> torch.Tensor | list[torch.Tensor | None]:
    """[F, 4, 4] when every frame has one, else the list as it is (frames without ground truth)."""
    present = [m for m in mats if m is not None]
    return torch.stack(present) if mats and len(present) == len(mats) else mats


@torch.no_grad()
def milestone_row(cfg: RunConfig, parts: RunSetup, drive: LoopOutcome, out: Path) -> dict[str, Any]:
    """The map and trajectory so far, scored as if the drive ended here (``eval.at_frames``)."""
    t0 = time.perf_counter()
    system = parts.system
    n_done = len(drive.timestamps_s)
    est_c2w = tracked_c2w(system, n_done)
    with system.whole_map():  # what map residency holds on disk is scored too, as at the end of a run
        res = evaluate(cfg, out, parts, est_c2w, drive, system.device, write_gt=False)
    mem = schema.memory_summary(drive.windows, system.device.type)
    row = {k: res.get(k) for k in ("path_length_m", "path_length_ratio", "ate_rmse_m", *schema.ROW_IMAGE_COLUMNS)}
    row.update(
        frames=n_done,
        n_gaussians=len(system.map),
        n_evicted=system.n_evicted(),
        peak_mem_mib=mem[schema.PEAK_FIELD],
        state_mib=round(system.map.state_bytes() / schema.MIB, 4),
    )
    row["eval_s"] = round(time.perf_counter() - t0, 3)
    return row


def keyframe_row(parts: RunSetup, res: FrameResult, frame_index: int, between: dict[str, Any]) -> dict[str, Any]:
    """One keyframes.csv row: closes the memory window the keyframe ends; ``between`` holds the
    pruning of the frames since the previous keyframe (``prune.every=frame``)."""
    mem = parts.probe.end_window()
    live_mib = parts.probe.live_mib()
    system = parts.system
    state_bytes = system.map.state_bytes()
    diag = res.diag
    return {
        "kf": res.keyframe_index,
        "frame": frame_index,
        "n_gaussians": len(system.map),
        "n_masked": parts.strategy.masked_count(system.map, system.map.state),
        "n_added": res.n_added,
        **{k: res.diag.get(k, 0) for k in schema.DENSIFY_COUNT_COLUMNS},
        "n_pruned": res.n_pruned + between["n_pruned"],
        "n_candidates": res.n_candidates + between["n_candidates"],
        "n_evicted": system.n_evicted(),
        "n_restored": res.n_restored,
        "n_kf_held": len(system.keyframes),
        "state_bytes": state_bytes,
        "state_mib": round(state_bytes / schema.MIB, 4),
        **{k: _round(v) for k, v in mem.items()},
        "track_s": round(res.track_s, 4),
        "map_s": round(res.map_s, 4),
        "prune_s": round(res.prune_s + between["prune_s"], 4),
        **memory_parts(
            mem, live_mib, diag.get("state_map_bytes", state_bytes), state_bytes, system.keyframe_store_bytes()
        ),
        **disk_parts(system.disk_bytes()),
        **{k: _round(diag.get(k)) for k in schema.PRUNE_QUARTILE_COLUMNS},
        **{k: diag.get(k, 0) + between[k] for k in schema.PRUNE_COUNT_COLUMNS},
        **{k: diag.get(k) for k in schema.SCORE_VIEW_COLUMNS},
        "diag_s": round(res.diag_s + between["diag_s"], 4),
        **{k: _round(diag.get(k)) for k in schema.FIT_COLUMNS},
        "kf_map_iters": diag.get("kf_map_iters"),
    }


def path_window(system: Any, drive: LoopOutcome, start: int) -> dict[str, float | None]:
    """keyframes.csv's path columns for the window from tracked frame ``start`` to the last one tracked:
    null without ground truth for every frame so far."""
    n_done = len(drive.gt_c2w)
    if any(g is None for g in drive.gt_c2w):
        return dict.fromkeys(schema.PATH_WINDOW_COLUMNS)
    est = torch.stack(tracked_c2w(system, n_done))[:, :3, 3].numpy()  # [F, 3] m
    gt = torch.stack([g.double().cpu() for g in drive.gt_c2w if g is not None])[:, :3, 3].numpy()  # [F, 3] m
    got = window_path_ratios(est, gt, start)
    return {k: None if v is None else round(v, 5) for k, v in got.items()}


def memory_parts(
    mem: dict[str, float | None],
    live_mib: float | None,
    state_map_bytes: int,
    state_end_bytes: int,
    keyframe_bytes: int,
) -> dict[str, float | None]:
    """The window's headline peak split into parts that add up to it (keyframes.csv ``mem_*``).

    The Gaussian state at its largest (after densification, mid-mapping) and the keyframe store are
    exact byte counts. What else stays live is measured at the window's end, when every work buffer
    is gone: live bytes minus the state and the keyframes then. The work buffers at the peak are
    what the peak holds beyond those three. Null where the device has no live-byte count.
    """
    peak = next(
        (
            mem.get(c)
            for c in (schema.PEAK_SOURCES["cuda_alloc"], schema.PEAK_SOURCES["torch_live"])
            if mem.get(c) is not None
        ),
        None,
    )
    if peak is None or live_mib is None:
        return dict.fromkeys(schema.MEMORY_PART_COLUMNS)
    state, kfs = state_map_bytes / schema.MIB, keyframe_bytes / schema.MIB
    other = live_mib - state_end_bytes / schema.MIB - kfs
    return {
        "mem_state_mib": _round(state),
        "mem_keyframes_mib": _round(kfs),
        "mem_other_mib": _round(other),
        "mem_work_mib": _round(peak - state - kfs - other),
    }


def disk_parts(disk_bytes: dict[str, int]) -> dict[str, float]:
    """Files the run holds on disk at the window's end, by part (keyframes.csv ``disk_*``): exact bytes in
    MiB to the byte (6 decimals), so the parts add up to the total."""
    state, kfs = disk_bytes["state"], disk_bytes["keyframes"]
    return {
        "disk_state_mib": round(state / schema.MIB, 6),
        "disk_keyframes_mib": round(kfs / schema.MIB, 6),
        "disk_total_mib": round((state + kfs) / schema.MIB, 6),
    }


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def _round(v: float | None) -> float | None:
    return None if v is None else round(float(v), 3)
