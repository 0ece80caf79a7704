"""``run(cfg) -> RunResult``: one SLAM run wired end to end, writing its run directory.

Everything a run learns is written as it goes: ``keyframes.csv`` rows are flushed per keyframe
window and ``metrics.json`` is replaced atomically, so an interrupted or lost run keeps what
it computed. A known failure (``BenchError``) becomes status ``failed`` with its one-line
message; ``TrackingLost`` becomes status ``lost`` and is still evaluated on the frames tracked.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import logging
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from omegaconf import DictConfig, OmegaConf

from bench import provenance
from bench.datasets import canonical_seq, open_sequence
from bench.determinism import repeatable
from bench.errors import BenchError, ConfigError, TrackingLost
from bench.measure import MemoryProbe, PhaseTimer
from bench.progress import Phase
from bench.record import record_failed, write_json
from bench.slam.se3 import inverse
from bench.slam.system import SlamConfig, System
from bench.strategy import PruneConfig, load_strategy
from bench.validate import validate

log = logging.getLogger(__name__)

KEYFRAME_COLUMNS = [
    "kf",
    "frame",
    "n_gaussians",
    "n_masked",
    "n_added",
    "n_pruned",
    "n_candidates",
    "state_bytes",
    "state_mib",
    "cpu_rss_peak_mib",
    "torch_live_peak_mib",
    "cuda_alloc_peak_mib",
    "cuda_reserved_peak_mib",
    "track_s",
    "map_s",
    "prune_s",
]
MIB = 1024.0 * 1024.0
# keys that change how a run is shown or stored, not what it computes
_NOT_HASHED = ("progress", "out_dir", "resume")


@dataclass
class RunResult:
    status: str  # ok | lost | failed
    out_dir: Path
    metrics: dict[str, Any] = field(default_factory=dict)
    error: str | None = None
    skipped: bool = False  # resume found completed results for the same config hash


def resolve_device(name: str) -> torch.device:
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name.startswith("cuda") and not torch.cuda.is_available():
        raise ConfigError(f"device '{name}' requested but cuda is not available; use device=cpu or device=auto")
    if name != "cpu" and not name.startswith("cuda"):
        raise ConfigError(f"device must be auto, cpu or cuda[:N], got '{name}'")
    return torch.device(name)


def run_keys(cfg: DictConfig) -> dict[str, Any]:
    strategy = cfg.get("strategy")
    name = strategy.name if strategy else "none"
    return {
        "strategy": name,
        "dataset": cfg.dataset.name,
        "seq": _seq_name(cfg),
        "seed": int(cfg.seed),
        # meaningless without pruning, so null for `none` however it was chosen (implicit or +strategy=none)
        "keep_ratio": None if name == "none" else float(cfg.prune.keep_ratio),
        "slam_preset": str(cfg.slam.get("name", "default")),  # runs of different presets never pool
    }


def _seq_name(cfg: DictConfig) -> str | None:
    seq = cfg.get("seq")
    if seq is None:
        seq = cfg.dataset.get("seq")
    if seq is None:
        seq = cfg.dataset.get("default_seq", cfg.dataset.get("seed"))
    return canonical_seq(str(cfg.dataset.name), seq)


def _hashable(cfg: DictConfig) -> dict[str, Any]:
    plain = OmegaConf.to_container(cfg, resolve=True)
    return {k: v for k, v in plain.items() if k not in _NOT_HASHED}


def _finite_or_none(x: float | None) -> float | None:
    return None if x is None or not math.isfinite(x) else float(x)


def completed(out_dir: Path, cfg_hash: str) -> dict[str, Any] | None:
    """The stored metrics if ``out_dir`` holds a finished run (ok or lost) of the same config."""
    path = out_dir / "metrics.json"
    try:
        stored = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError):
        return None
    if stored.get("status") in ("ok", "lost") and stored.get("run", {}).get("config_hash") == cfg_hash:
        return stored
    return None


def make_out_dir(out: Path) -> None:
    """Create the run dir; a path that cannot be a writable dir is one ``ConfigError`` line."""
    try:
        out.mkdir(parents=True, exist_ok=True)
        probe = out / ".write_test"
        probe.touch()
        probe.unlink()
    except FileExistsError:
        raise ConfigError(f"output dir: expected a directory at {out}, found a file in the way") from None
    except NotADirectoryError:
        raise ConfigError(f"output dir: expected a directory at {out}, found a file on its path") from None
    except OSError as exc:
        raise ConfigError(f"output dir: expected a writable directory at {out}, found: {exc.strerror or exc}") from None


def _keys_best_effort(cfg: DictConfig) -> dict[str, Any]:
    """Run keys of a config that failed validation: whatever of them is readable."""
    try:
        return run_keys(cfg)
    except Exception:  # the bad value is one of the keys (seed=abc): record the rest as given
        strategy = cfg.get("strategy")
        return {"strategy": strategy.get("name") if strategy else "none", "dataset": cfg.dataset.get("name"),
                "seq": None if cfg.get("seq") is None else str(cfg.get("seq")), "seed": None, "keep_ratio": None}


def _section(cfg: DictConfig, key: str, cls: type) -> dict[str, Any]:
    """``cfg.<key>`` as plain keyword arguments for dataclass ``cls``; unknown keys are a ConfigError."""
    raw = OmegaConf.to_container(cfg[key], resolve=True)
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(raw) - names)
    if unknown:
        raise ConfigError(f"{key} has no setting {', '.join(unknown)}; expected one of: {', '.join(sorted(names))}")
    return raw


def slam_config(cfg: DictConfig) -> SlamConfig:
    return SlamConfig(**{**_section(cfg, "slam", SlamConfig), "seed": int(cfg.seed)})


def prune_config(cfg: DictConfig) -> PruneConfig:
    return PruneConfig(**_section(cfg, "prune", PruneConfig))


def run(cfg: DictConfig, out_dir: str | Path | None = None) -> RunResult:
    """Run one (strategy, dataset, seq, seed) combination and write its run directory."""
    out = Path(out_dir or cfg.get("out_dir") or ".").resolve()
    try:
        validate(cfg)
    except ConfigError as exc:  # in a sweep the job is recorded; a single run was refused by the CLI already
        make_out_dir(out)
        record_failed(out, str(exc), _keys_best_effort(cfg))
        return RunResult("failed", out, {}, str(exc))
    make_out_dir(out)
    cfg_hash = provenance.config_hash(_hashable(cfg))
    keys = {**run_keys(cfg), "config_hash": cfg_hash}
    if cfg.get("resume", True):
        stored = completed(out, cfg_hash)
        if stored is not None:
            log.info("skipping %s: completed results with config hash %s exist", out, cfg_hash)
            return RunResult(stored["status"], out, stored.get("metrics", {}), stored.get("error"), skipped=True)
    (out / "config.yaml").write_text(OmegaConf.to_yaml(cfg, resolve=True))
    record: dict[str, Any] = {
        "status": "running", "error": None, "run": keys, "determinism": {}, "metrics": {}, "provenance": {},
    }  # fmt: skip
    write_json(out / "metrics.json", record)
    try:
        device = resolve_device(str(cfg.device))
        with repeatable(int(cfg.seed), cfg.get("threads"), str(cfg.get("determinism", "strict")), device) as det:
            record["determinism"] = det
            record["provenance"] = provenance.collect(device)  # after the thread count is set
            status, error, metrics = _execute(cfg, out, device, record)
    except BenchError as exc:
        status, error, metrics = "failed", str(exc), record["metrics"]
    except Exception as exc:  # unexpected: record it so the sweep goes on, then re-raise for the traceback
        record.update(status="failed", error=f"{type(exc).__name__}: {exc}".splitlines()[0])
        write_json(out / "metrics.json", record)
        raise
    record.update(status=status, error=error, metrics=metrics)
    write_json(out / "metrics.json", record)
    return RunResult(status, out, metrics, error)


def _execute(cfg: DictConfig, out: Path, device: torch.device, record: dict[str, Any]):
    t_start = time.perf_counter()
    strategy_cfg = cfg.get("strategy")
    name = strategy_cfg.name if strategy_cfg else "none"
    params = (
        OmegaConf.to_container(strategy_cfg.params, resolve=True) if strategy_cfg and "params" in strategy_cfg else {}
    )
    strategy = load_strategy(name, params or {})
    ds_cfg = OmegaConf.to_container(cfg.dataset, resolve=True)
    if cfg.get("seq") is not None:
        ds_cfg["seq"] = str(cfg.seq)
    seq = open_sequence(cfg.dataset.name, ds_cfg)
    n_frames = len(seq)
    if cfg.get("max_frames"):
        n_frames = min(n_frames, int(cfg.max_frames))
    if n_frames < 2:
        raise ConfigError(f"a run needs at least 2 frames, the sequence has {n_frames}")

    timer = PhaseTimer(device)
    probe = MemoryProbe(device, torch_live=bool(cfg.memory.torch_live))
    system = System(
        slam_config(cfg), seq.K, seq.height, seq.width, strategy, prune_config(cfg), device, timer=timer
    )
    metrics: dict[str, Any] = {"num_frames": 0, "num_keyframes": 0}
    record["metrics"] = metrics
    timestamps, gt_c2w = [], []
    windows: list[dict[str, Any]] = []
    status, error = "ok", None
    show = bool(cfg.get("progress", True))
    bar = Phase("frames", n_frames, "frame", show)
    warmup = int(cfg.get("warmup_frames", 1))
    t_loop = t_warmup = 0.0
    between = {"n_pruned": 0, "n_candidates": 0, "prune_s": 0.0}  # prune.every=frame: frames since the last keyframe
    probe.start_window()
    with open(out / "keyframes.csv", "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=KEYFRAME_COLUMNS)
        writer.writeheader()
        fh.flush()
        try:
            for i in range(n_frames):
                frame = seq[i]  # loading is not SLAM time
                if device.type == "cuda":
                    torch.cuda.synchronize(device)
                t0 = time.perf_counter()
                res = system.process(frame)
                if device.type == "cuda":
                    torch.cuda.synchronize(device)
                if i >= warmup:
                    t_loop += time.perf_counter() - t0
                else:
                    t_warmup += time.perf_counter() - t0
                timestamps.append(frame.timestamp_s)
                gt_c2w.append(frame.gt_c2w)
                metrics["num_frames"] = i + 1
                if not res.is_keyframe:
                    between = {k: v + getattr(res, k) for k, v in between.items()}
                else:
                    mem = probe.end_window()
                    state_bytes = system.map.state_bytes()
                    row = {
                        "kf": res.keyframe_index,
                        "frame": frame.index,
                        "n_gaussians": len(system.map),
                        "n_masked": strategy.masked_count(system.map, system.map.state),
                        "n_added": res.n_added,
                        "n_pruned": res.n_pruned + between["n_pruned"],
                        "n_candidates": res.n_candidates + between["n_candidates"],
                        "state_bytes": state_bytes,
                        "state_mib": round(state_bytes / MIB, 4),
                        **{k: _round(v) for k, v in mem.items()},
                        "track_s": round(res.track_s, 4),
                        "map_s": round(res.map_s, 4),
                        "prune_s": round(res.prune_s + between["prune_s"], 4),
                    }
                    between = dict.fromkeys(between, 0)
                    writer.writerow(row)
                    fh.flush()
                    windows.append(row)
                    metrics["num_keyframes"] = len(windows)
                    probe.start_window()
                bar.update(1, gaussians=len(system.map), fps=f"{(i + 1 - warmup) / max(t_loop, 1e-9):.2f}")
        except TrackingLost as exc:
            status, error = "lost", str(exc)
            bar.close(note=f"lost: {exc}")
            log.warning("%s", exc)
        finally:
            bar.close()
            probe.close()
    n_done = metrics["num_frames"]
    metrics["slam_wall_s"] = round(t_loop, 3)
    metrics["warmup_s"] = round(t_warmup, 3)  # the first frame(s), left out of slam_wall_s and fps
    if system.cfg.refine_iters > 0:  # after the loop: not SLAM time, not in fps
        with timer.phase("refine"), Phase("refine", system.cfg.refine_iters, "iteration", show) as refine_bar:
            system.refine(system.cfg.refine_iters, on_step=refine_bar.update)
        metrics["refine_s"] = round(timer.totals()["refine"], 3)
    metrics["fps"] = round((n_done - warmup) / t_loop, 4) if t_loop > 0 and n_done > warmup else None
    # per-phase seconds of the frame loop, warm-up frames included: they sum to about
    # slam_wall_s + warmup_s (less the frame handling outside the phases); refinement is refine_s
    metrics["phase_s"] = {k: round(v, 3) for k, v in timer.totals().items() if k != "refine"}
    metrics["memory_method"] = {"cpu_rss": probe.rss_method, "torch_live": bool(cfg.memory.torch_live)}
    metrics.update(_memory_summary(windows, device))
    metrics["gaussians_final"] = len(system.map)
    # churn: did pruning shrink the map, or only feed re-seeding?
    metrics["gaussians_added_total"] = sum(w["n_added"] for w in windows)
    metrics["gaussians_pruned_total"] = sum(w["n_pruned"] for w in windows)
    metrics["prune_candidates_total"] = sum(w["n_candidates"] for w in windows)
    metrics["keep_ratio"] = run_keys(cfg)["keep_ratio"]  # as in run.keep_ratio: null when nothing is pruned
    est_c2w = [inverse(p.detach().double().cpu()) for p in system.poses[:n_done]]
    t_eval = time.perf_counter()
    metrics.update(_evaluate(cfg, out, seq, system, est_c2w, timestamps, gt_c2w, device))
    metrics["eval_s"] = round(time.perf_counter() - t_eval, 3)  # ATE, rendering, PSNR/SSIM/LPIPS
    from bench.plots import memory_timeline, write_density

    memory_timeline(out / "memory.png", windows, title=f"{run_keys(cfg)['strategy']} on {seq.name}")
    write_density(out / "density.npz", system, est_c2w, seq)
    metrics["wall_s"] = round(time.perf_counter() - t_start, 3)  # the whole run: loading to figures
    return status, error, metrics


def _round(v: float | None) -> float | None:
    return None if v is None else round(float(v), 3)


def _memory_summary(windows: list[dict[str, Any]], device: torch.device) -> dict[str, Any]:
    def peak(key: str) -> float | None:
        vals = [w[key] for w in windows if w.get(key) is not None]
        return max(vals) if vals else None

    summary = {
        "gaussians_peak": peak("n_gaussians") or 0,
        "state_peak_mib": peak("state_mib"),
        "cpu_rss_peak_mib": peak("cpu_rss_peak_mib"),
        "torch_live_peak_mib": peak("torch_live_peak_mib"),
        "cuda_alloc_peak_mib": peak("cuda_alloc_peak_mib"),
        "cuda_reserved_peak_mib": peak("cuda_reserved_peak_mib"),
    }
    # The headline figure: what the device must hold at once (the paper reads the CUDA allocator peak).
    if device.type == "cuda":
        summary["peak_mem_mib"], summary["peak_mem_source"] = summary["cuda_alloc_peak_mib"], "cuda_alloc"
    elif summary["torch_live_peak_mib"] is not None:
        summary["peak_mem_mib"], summary["peak_mem_source"] = summary["torch_live_peak_mib"], "torch_live"
    else:
        summary["peak_mem_mib"], summary["peak_mem_source"] = summary["cpu_rss_peak_mib"], "cpu_rss"
    return summary


def _evaluate(
    cfg: DictConfig,
    out: Path,
    seq,
    system: System,
    est_c2w: list[torch.Tensor],
    timestamps: list[float],
    gt_c2w: list[torch.Tensor | None],
    device: torch.device,
) -> dict[str, Any]:
    """ATE (evo), PSNR/SSIM (torchmetrics), LPIPS when weights exist; none of it is SLAM time."""
    from bench.metrics.image import image_metrics
    from bench.metrics.lpips import LPIPS
    from bench.metrics.trajectory import Trajectory, ate, rpe, write_tum

    ev = cfg.eval
    res: dict[str, Any] = {"ate_rmse_m": None, "psnr_db": None, "ssim": None, "lpips": None}
    if not est_c2w:
        return res
    ts = np.asarray(timestamps)
    est = Trajectory.from_c2w(ts, torch.stack(est_c2w).numpy())
    write_tum(out / "traj_est.txt", est)
    if all(g is not None for g in gt_c2w) and len(est_c2w) >= 3:
        gt_world = torch.stack([g.double() for g in gt_c2w])
        gt_world = inverse(gt_world[0]).expand_as(gt_world) @ gt_world  # first camera = origin, like the estimate
        gt = Trajectory.from_c2w(ts, gt_world.numpy())
        write_tum(out / "traj_gt.txt", gt)
        res.update(ate(est, gt, align=str(ev.ate_align), max_diff_s=float(ev.max_diff_s)))
        res["ate_first_frame"], res["ate_last_frame"] = 0, len(est_c2w) - 1  # inclusive, tracked-frame positions
        res["path_length_m"] = round(float(np.linalg.norm(np.diff(gt.positions_m, axis=0), axis=1).sum()), 4)
        if ev.get("rpe"):
            res.update(rpe(est, gt, align=str(ev.ate_align), max_diff_s=float(ev.max_diff_s)))
    every = max(1, int(ev.every))
    idx = list(range(0, len(est_c2w), every))
    preds, targets = [], []
    with Phase("evaluate", len(idx), "frame", bool(cfg.get("progress", True))) as bar:
        with torch.no_grad():
            for i in idx:
                w2c = inverse(est_c2w[i]).float().to(device)
                preds.append(system.render(w2c).color.clamp(0, 1).cpu())
                targets.append(seq[i].rgb)
                bar.update(1)
        lp = LPIPS.from_weights(ev.get("lpips_weights"), device=device) if ev.get("lpips", True) else None
        img = image_metrics(preds, targets, lpips=lp)
    img.pop("num_frames", None)  # that count is res["eval_frames"]; metrics["num_frames"] is frames tracked
    res.update({k: _finite_or_none(v) if isinstance(v, float) else v for k, v in img.items()})
    res["eval_frames"] = len(idx)
    return res
