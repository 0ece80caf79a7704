"""``run(cfg) -> RunResult``: one SLAM run wired end to end, writing its run directory.

The composed Hydra config is validated and converted once (``bench.cli.validate.validate``, which also
builds the strategy and a given LPIPS model; the CLI's own check hands its result over); everything
below receives dataclasses. A run reads as its data flows: ``build`` makes the SLAM system around
the opened sequence, ``drive`` feeds it the frames and writes one ``keyframes.csv`` row per keyframe
window, ``finish`` refines, summarises memory, evaluates and plots. Its keys come from ``bench.config.identity``.

Everything a run learns is written as it goes: ``keyframes.csv`` rows are flushed per keyframe
window and ``metrics.json`` is replaced atomically, so an interrupted or lost run keeps what
it computed. A known failure (``BenchError``) becomes status ``failed`` with its one-line
message; ``TrackingLost`` becomes status ``lost`` and is still evaluated on the frames tracked.
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import json
import logging
import math
import os
import signal
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from omegaconf import DictConfig, OmegaConf

from bench import schema
from bench.cli.validate import Built, validate
from bench.conf import config_files
from bench.config.compose import RunConfig
from bench.config.identity import dataset_name, run_keys
from bench.config.settings import plain
from bench.datasets import Sequence, open_sequence
from bench.errors import BenchError, ConfigError, TrackingLost
from bench.measure.memory import MemoryProbe, PhaseTimer
from bench.measure.progress import Phase
from bench.metrics.image import MS_SSIM_MIN_PX
from bench.metrics.trajectory import TumAppender
from bench.report.figures.pruned_run import PruneViz
from bench.run import checkpoint as ckpt
from bench.run import provenance
from bench.run.determinism import repeatable
from bench.run.export import MAP_FILE, save_snapshot, write_map
from bench.run.record import is_leftover, owner, read_record, record_refusal, write_json, write_text
from bench.run.resume import redo_reason
from bench.run.signals import Interrupted, Preemption, deferred_signals, held_preemption, raise_on_signals
from bench.slam.se3 import inverse
from bench.slam.strategy import CheckedStrategy, Strategy
from bench.slam.system import FrameResult, System

log = logging.getLogger(__name__)

TRAJ_EST = "traj_est.txt"

# test-only: "FRAME:SIGNAL" makes a run that started at frame 0 send itself SIGNAL once frame FRAME's
# rows (and checkpoint, if that frame wrote one) are on disk; how the tests stop a run at a known point
TEST_SIGNAL_ENV = "POCKETBENCH_TEST_SIGNAL_AT"


@dataclass
class RunResult:
    status: str  # ok | lost | failed | interrupted
    out_dir: Path
    metrics: dict[str, Any] = field(default_factory=dict)
    error: str | None = None
    skipped: bool = False  # resume found completed results of the same config, code and inputs


def resolve_device(name: str) -> torch.device:
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name.startswith("cuda") and not torch.cuda.is_available():
        raise ConfigError(f"device '{name}': expected cpu or auto on a machine without cuda, found no cuda device")
    if name != "cpu" and not name.startswith("cuda"):
        raise ConfigError(f"device: expected auto, cpu or cuda[:N], found '{name}'")
    return torch.device(name)


def _finite_or_none(x: float | None) -> float | None:
    return None if x is None or not math.isfinite(x) else float(x)


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


def run(cfg: DictConfig | RunConfig, out_dir: str | Path | None = None, built: Built | None = None) -> RunResult:
    """Run one (strategy, dataset, seq, seed) combination and write its run directory.

    Order matters: the config is validated and the data opened before anything is written, so a
    refused run leaves no half-made dir; a stored run is skipped only when config, code version
    and input files all match (``bench.run.resume``); once running, SIGINT/SIGTERM end the run as
    ``interrupted`` with what the frames done allow (then ``Interrupted`` is re-raised).
    ``built``: what ``bench.cli.validate.validate`` made of this same config already (the CLI's check
    before Hydra starts), used as it is; a config that differs from it is validated again.
    """
    if isinstance(cfg, RunConfig):
        cfg = OmegaConf.structured(cfg)
    out = Path(out_dir or cfg.out_dir or ".").resolve()
    metrics_path = out / schema.METRICS_FILE
    try:
        if built is None or built.tree != {k: v for k, v in plain(cfg).items() if k != "hydra"}:
            built = validate(cfg)
    except ConfigError as exc:  # in a sweep the job is recorded; a single run was refused by the CLI already
        make_out_dir(out)
        return _refused(out, str(exc), run_keys(cfg))
    conf = built.config  # below here only dataclasses travel
    make_out_dir(out)
    stored = _previous(out)
    keys = run_keys(conf, built.tree)
    try:
        device = resolve_device(conf.device)
        ckpt.check_files(out)
        seq = open_seq(conf)  # the loaders draw from their own seeded generators, not the global ones
    except BenchError as exc:  # bad data found before any work
        return _refused(out, str(exc), keys, OmegaConf.to_yaml(cfg, resolve=True))
    keys = run_keys(conf, built.tree, seq)
    missing = [name for name, digest in keys["inputs"].items() if digest == "missing"]
    if missing:  # the fingerprint found them gone: refuse now, not at the frame that reads one
        more = f" and {len(missing) - 1} more" if len(missing) > 1 else ""
        return _refused(out, f"input files: expected every file the dataset lists, found {missing[0]} missing{more}",
                        keys, OmegaConf.to_yaml(cfg, resolve=True))
    record: dict[str, Any] = {
        "status": "running", "error": None, "run": keys, "determinism": {}, "metrics": {}, "provenance": {},
        "owner": owner(),
    }  # fmt: skip
    start: dict[str, Any] | None = None  # the checkpoint a resumed run starts from
    level = logging.INFO  # of the redo line: a warning when a checkpoint was there but unusable
    if conf.resume:
        reason = redo_reason(stored, keys)
        if reason is None:
            log.info("skipping %s: completed results of the same config, code and inputs exist", out)
            return RunResult(stored["status"], out, stored.get("metrics", {}), stored.get("error"), skipped=True)
        if stored is not None and stored.get("status") == "interrupted" and ckpt.exists(out):
            start, why = ckpt.find(out, keys, flushed_rows(out))
            if start is None:
                reason, level = f"its checkpoint was not used: {why}; starting over from frame 0", logging.WARNING
        if start is not None:
            log.info("resuming %s from frame %d (checkpoint of keyframe %d)", out, start["frame"], start["keyframe"])
        elif stored is not None:
            log.log(level, "redoing %s: %s", out, reason)
    write_text(out / "config.yaml", OmegaConf.to_yaml(cfg, resolve=True))
    record["checkpoint"] = {"every": conf.checkpoint.every, "written": 0, "mib_last": None, "write_s_total": 0.0,
                            "resumed_from_frames": []}  # fmt: skip
    if start is None:
        (out / TRAJ_EST).unlink(missing_ok=True)
    else:  # rows written after the checkpoint go; the loop appends from there
        ckpt.truncate_rows(out / TRAJ_EST, 1, start["rows"]["traj"])
        ckpt.truncate_rows(out / schema.KEYFRAMES_FILE, 1, start["rows"]["keyframes"])
        if (out / schema.MILESTONES_FILE).exists():
            ckpt.truncate_rows(out / schema.MILESTONES_FILE, 1, start["rows"].get("milestones", 0))
        record["checkpoint"] = {**start["stats"], "every": conf.checkpoint.every,
                                "resumed_from_frames": [*start["stats"]["resumed_from_frames"], start["frame"]]}
    write_json(metrics_path, record)
    if start is None:
        ckpt.remove(out)  # a previous run's checkpoints: the record they belonged to is replaced now
    stop: Interrupted | None = None
    preempt = Preemption()
    try:
        with raise_on_signals(), held_preemption() as preempt, \
                repeatable(conf.seed, conf.threads, conf.determinism, device) as det:
            record["determinism"] = det
            record["provenance"] = provenance.collect(device)  # after the thread count is set
            record["provenance"]["config_files"] = _config_files()
            status, error, metrics, stop = _execute(built, out, device, record, seq, start, preempt)
    except Interrupted as exc:  # outside the frame loop (build, refinement, evaluation): keep what is there
        n_done = record["metrics"].get("num_frames", 0)
        status, error, metrics, stop = "interrupted", f"{exc} after {n_done} frames", record["metrics"], exc
    except BenchError as exc:
        status, error, metrics = "failed", str(exc), record["metrics"]
    except Exception as exc:  # unexpected: record it so the sweep goes on, then re-raise for the traceback
        record.update(status="failed", error=f"{type(exc).__name__}: {exc}".splitlines()[0])
        record.pop("owner")
        write_json(metrics_path, record)
        raise
    with deferred_signals():  # a second Ctrl-C must not cut the record in half
        record.update(status=status, error=error, metrics=metrics)
        record.pop("owner")
        write_json(metrics_path, record)
        if status != "interrupted":
            ckpt.remove(out)  # finished (or failed on its data): a rerun never resumes it
    if stop is not None:
        if preempt.signum is not None and preempt.signum == stop.signum:
            log.warning("%s: preempted after %d frames; checkpoint written, the launcher requeues the job",
                        out, metrics.get("num_frames", 0))
            preempt.hand_over()  # the launcher's own handler (submitit: requeue, then exit)
        raise Interrupted(stop.signum, f"{error}; partial results in {out}")
    return RunResult(status, out, metrics, error)


def _refused(out: Path, error: str, keys: dict[str, Any], config_yaml: str | None = None) -> RunResult:
    """A run refused before any work: recorded ``failed``, unless ``out`` holds a previous run's
    record to keep (finished, resumable or live), which a refusal for a passing reason (data briefly
    unreachable, no CUDA on this node) must not replace."""
    kept = record_refusal(out, error, keys, config_yaml)
    if kept is not None:
        error = f"{error} (nothing written: {out} keeps its {kept} record)"
    return RunResult("failed", out, {}, error)


def _config_files() -> dict[str, str] | None:
    """The file each group choice came from (a user's ./conf or the package), when Hydra composed the run."""
    from hydra.core.hydra_config import HydraConfig

    return config_files(HydraConfig.get().runtime.choices) if HydraConfig.initialized() else None
def flushed_rows(out: Path) -> dict[str, int]:
    """Data rows on disk in the files a checkpoint counts (each has one header line)."""
    return {"traj": ckpt.data_rows(out / TRAJ_EST, 1), "keyframes": ckpt.data_rows(out / schema.KEYFRAMES_FILE, 1),
            "milestones": ckpt.data_rows(out / schema.MILESTONES_FILE, 1)}


def _previous(out: Path) -> dict[str, Any] | None:
    """The metrics.json a previous run left here; a ``running`` one whose process died is marked interrupted."""
    path = out / schema.METRICS_FILE
    stored = read_record(out)
    if stored is None:
        return None
    if is_leftover(stored):
        who = stored.get("owner") or {}
        frames = (stored.get("metrics") or {}).get("num_frames", 0)
        stored.update(status="interrupted",
                      error=f"killed: process {who.get('pid')} stopped while running, after {frames} frames")
        stored.pop("owner")
        write_json(path, stored)
        log.warning("%s: the previous run was killed while running (pid %s); recorded as interrupted",
                    out, who.get("pid"))
    return stored


def _execute(built: Built, out: Path, device: torch.device, record: dict[str, Any], seq: Sequence,
             start: dict[str, Any] | None = None, preempt: Preemption | None = None):
    t_start = time.perf_counter()
    cfg = built.config
    parts = build(cfg, device, seq, built)
    parts.keys = record["run"]
    if cfg.viz.pruning:
        parts.viz = parts.system.on_prune = PruneViz(parts.system, out, cfg.viz.every, describe(parts.keys))
    record["metrics"] = metrics = {"num_frames": 0, "num_keyframes": 0}
    if start is not None:
        restore(parts, start)
        if parts.viz is not None:  # the stopped run's pictures up to the checkpoint are this run's too
            parts.viz.written = [p for p in sorted(out.glob("pruned_kf*.npz")) if _kf_of(p) <= start["keyframe"]]
    drive = drive_frames(cfg, parts, out, record, start, preempt)
    with deferred_signals() if drive.stop is not None else contextlib.nullcontext():
        metrics.update(finish(cfg, parts, drive, out, device))
        metrics["wall_s"] = round(time.perf_counter() - t_start, 3)  # the whole run: loading to figures
    return drive.status, drive.error, metrics, drive.stop


# ---------------------------------------------------------------------------------------------- build


@dataclass
class Parts:
    """What ``build`` makes and the later steps use."""

    seq: Sequence
    n_frames: int  # frames to process (max_frames applied)
    strategy: Strategy
    system: System
    timer: PhaseTimer
    probe: MemoryProbe
    viz: PruneViz | None = None  # viz.pruning
    lpips: Any = None  # what validate loaded from eval.lpips_weights; None: loaded at evaluation if at all
    keys: dict[str, Any] = field(default_factory=dict)  # the run block of metrics.json (bench.config.identity)


def open_seq(cfg: RunConfig) -> Sequence:
    """The run's sequence; opened before the run starts, so its files enter the resume key."""
    dataset = cfg.dataset
    if cfg.seq is not None:
        is_plain = isinstance(dataset, dict)
        dataset = {**dataset, "seq": cfg.seq} if is_plain else dataclasses.replace(dataset, seq=cfg.seq)
    return open_sequence(dataset_name(dataset), dataset)


def build(cfg: RunConfig, device: torch.device, seq: Sequence, built: Built) -> Parts:
    """Make the SLAM system (seeded by ``repeatable``) for the opened sequence, around what validate built."""
    strategy = built.strategy
    n_frames = min(len(seq), cfg.max_frames) if cfg.max_frames else len(seq)
    if n_frames < 2:
        raise ConfigError(f"a run needs at least 2 frames: expected >= 2, found {n_frames}")
    warm_kernels(cfg.slam.raster_backend, device)  # before the memory probe: its buffers are not the run's
    timer = PhaseTimer(device)
    probe = MemoryProbe(device, torch_live=cfg.memory.torch_live)  # before the SLAM state is allocated
    system = System(cfg.slam, seq.K, seq.height, seq.width, strategy, cfg.prune, device, timer=timer)
    return Parts(seq, n_frames, strategy, system, timer, probe, lpips=built.lpips)


_warm: set[str] = set()  # rasterizer backends whose kernels this process has loaded


def warm_kernels(backend: str, device: torch.device) -> None:
    """Load every compiled rasterizer kernel into this process before the timed frame loop.

    Why: numba loads a cached kernel at its first call, and a run calls some kernels first only
    after its warm-up frame (the pose gradient from the second frame, pruning statistics at the
    first prune). The first run of a process (a sweep's first job, a single run) then paid that
    loading inside ``slam_wall_s`` and FPS, and later jobs of the same process did not. Loaded here,
    once per process, every job's loop runs on loaded kernels; the time is in ``wall_s`` only.
    """
    from bench.slam.raster import resolve_backend

    name = resolve_backend(backend, device)
    if name == "fused" and name not in _warm:
        from bench.slam.raster_fused import compile_kernels

        compile_kernels()  # loads each kernel from numba's cache (compiling it there first if absent)
        _warm.add(name)


# ---------------------------------------------------------------------------------------------- drive


@dataclass
class Drive:
    """What the frame loop leaves behind."""

    status: str = "ok"  # ok | lost | interrupted | failed (bad data mid-run)
    error: str | None = None
    stop: Interrupted | None = None  # the signal that ended the loop, re-raised once the record is written
    timestamps_s: list[float] = field(default_factory=list)
    gt_c2w: list[torch.Tensor | None] = field(default_factory=list)
    windows: list[dict[str, Any]] = field(default_factory=list)  # the keyframes.csv rows
    loop_s: float = 0.0  # SLAM wall time after the warm-up frames
    warmup_s: float = 0.0  # the warm-up frames' time, left out of loop_s and fps
    tail: dict[str, Any] = field(default_factory=dict)  # peaks and map size of the frames after the last keyframe


def restore(parts: Parts, start: dict[str, Any]) -> None:
    """Put a checkpoint's state into freshly built parts: the system, the strategy, the global generators."""
    parts.system.load_state_dict(start["system"], lambda i: parts.seq[i])
    vars(_inner(parts.strategy)).update(start["strategy"])
    done = json.loads(start["drive"]["json"])
    parts.timer.restore(done["phase_s"], done["phase_n"])
    ckpt.set_global_rng_state(start["rng"])  # last: nothing after it draws before the next frame


def _kf_of(path: Path) -> int:
    """The keyframe a ``pruned_kfNNN.npz`` belongs to (-1 for a name not of that form)."""
    digits = path.stem.removeprefix("pruned_kf")
    return int(digits) if digits.isdigit() else -1


def _inner(strategy: Strategy) -> Strategy:
    return strategy.inner if isinstance(strategy, CheckedStrategy) else strategy


def write_checkpoint(cfg: RunConfig, parts: Parts, drive: Drive, out: Path, record: dict[str, Any],
                     between: dict[str, Any]) -> None:
    """The loop's whole state after the frames done so far (see ``bench.run.checkpoint``); its cost goes into
    metrics.json's ``checkpoint`` block, outside the SLAM time and the metrics a resume must repeat."""
    stats = record["checkpoint"]
    n_done = len(drive.timestamps_s)
    payload = {
        "key": {k: record["run"][k] for k in ("config_hash", "code_version", "inputs")},
        "frame": n_done,
        "keyframe": drive.windows[-1]["kf"] if drive.windows else -1,
        "system": parts.system.state_dict(),
        "strategy": dict(vars(_inner(parts.strategy))),
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
    stats.update(written=stats["written"] + 1, mib_last=cost.mib,
                 write_s_total=round(stats["write_s_total"] + cost.write_s, 4))
    log.debug("%s: checkpoint at frame %d (keyframe %d): %.3f MiB in %.4f s", out, n_done, payload["keyframe"],
              cost.mib, cost.write_s)


def _stack_all(mats: list[torch.Tensor | None]) -> torch.Tensor | list[torch.Tensor | None]:
    """[F, 4, 4] when every frame has one, else the list as it is (frames without ground truth)."""
    return torch.stack(mats) if mats and all(m is not None for m in mats) else mats


def _test_signal_frame() -> tuple[int, int] | None:
    spec = os.environ.get(TEST_SIGNAL_ENV)
    if not spec:
        return None
    frame, _, name = spec.partition(":")
    return int(frame), int(getattr(signal, "SIG" + (name or "KILL")))


def drive_frames(cfg: RunConfig, parts: Parts, out: Path, record: dict[str, Any],
                 start: dict[str, Any] | None = None, preempt: Preemption | None = None) -> Drive:
    """Feed every frame to the system; one flushed keyframes.csv row per keyframe window and one
    flushed traj_est.txt line per frame, so a stopped run keeps what it tracked.

    ``start``: a checkpoint to continue from (its frames and rows are already done and on disk).
    ``preempt``: a held preemption signal ends the loop at the next frame boundary, with a checkpoint.
    """
    system, device = parts.system, parts.system.device
    metrics = record["metrics"]
    drive = Drive()
    warmup = cfg.warmup_frames
    bar = Phase("frames", parts.n_frames, "frame", cfg.progress)
    # prune.every=frame: what the frames since the last keyframe pruned
    between: dict[str, Any] = dict.fromkeys(
        ("n_pruned", "n_candidates", "prune_s", "diag_s", *schema.PRUNE_COUNT_COLUMNS), 0)
    first = 0
    if start is not None:
        done = json.loads(start["drive"]["json"])  # floats round-trip json exactly
        drive.timestamps_s = start["drive"]["timestamps_s"].tolist()
        drive.gt_c2w = list(start["drive"]["gt_c2w"])
        drive.windows, drive.loop_s, drive.warmup_s = done["windows"], done["loop_s"], done["warmup_s"]
        between = done["between"]
        first = start["frame"]
        metrics.update(num_frames=first, num_keyframes=len(drive.windows))
        bar.update(first)
    test_signal = _test_signal_frame() if start is None else None
    every = cfg.checkpoint.every
    parts.probe.start_window()
    with FlushedRows(out / schema.KEYFRAMES_FILE, schema.KEYFRAME_COLUMNS, start is not None) as keyframes, \
            TumAppender(out / TRAJ_EST, append=start is not None) as traj, \
            FlushedRows(out / schema.MILESTONES_FILE, schema.MILESTONE_COLUMNS, start is not None,
                        bool(cfg.eval.at_frames)) as milestones:
        try:
            for i in range(first, parts.n_frames):
                frame = parts.seq[i]  # loading is not SLAM time
                _sync(device)
                t0 = time.perf_counter()
                res = system.process(frame)
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
                    between = {k: v + (getattr(res, k) if hasattr(res, k) else res.diag.get(k, 0))
                               for k, v in between.items()}
                else:
                    row = keyframe_row(parts, res, frame.index, between)
                    between = dict.fromkeys(between, 0)
                    keyframes.writerow(row)
                    drive.windows.append(row)
                if i + 1 in cfg.eval.at_frames:  # before the checkpoint, which counts its row
                    with parts.probe.paused():
                        milestones.writerow(milestone_row(cfg, parts, drive, out))
                if res.is_keyframe:
                    if cfg.save_maps == "every_keyframe":
                        save_snapshot(out, res.keyframe_index, system.map)
                    metrics["num_keyframes"] = len(drive.windows)
                    if every and (res.keyframe_index + 1) % every == 0:
                        write_checkpoint(cfg, parts, drive, out, record, between)
                    write_json(out / schema.METRICS_FILE, record)  # still running; counts so far, for a later reader
                    parts.probe.start_window()
                bar.update(1, gaussians=len(system.map), fps=f"{(i + 1 - warmup) / max(drive.loop_s, 1e-9):.2f}")
                if test_signal is not None and test_signal[0] == i:
                    os.kill(os.getpid(), test_signal[1])
                if preempt is not None and preempt.signum is not None:  # held since it came: stop here, resumable
                    write_checkpoint(cfg, parts, drive, out, record, between)
                    write_json(out / schema.METRICS_FILE, record)
                    raise Interrupted(preempt.signum)
        except TrackingLost as exc:
            drive.status, drive.error = "lost", str(exc)
            bar.close(note=f"lost: {exc}")
            log.warning("%s", exc)
        except Interrupted as exc:  # stopped: the frames done are still a result, not a method failure
            drive.status, drive.error, drive.stop = "interrupted", f"{exc} after {metrics['num_frames']} frames", exc
        except BenchError as exc:  # bad data mid-run (a corrupt frame): keep the partial record, failed
            drive.status, drive.error = "failed", f"{exc} (after {metrics['num_frames']} frames)"
        finally:
            bar.close()
            # the frames after the last keyframe form a window no keyframes.csv row closes: their peaks count too
            drive.tail = {**parts.probe.end_window(), "n_gaussians": len(system.map)}
            parts.probe.close()
    return drive


class FlushedRows:
    """A csv file written a row at a time and flushed after each (appended to on resume); no file when off."""

    def __init__(self, path: Path, columns: list[str], append: bool, on: bool = True) -> None:
        self.path, self.columns, self.append, self.on = path, columns, append, on
        self._fh: Any = None

    def __enter__(self) -> FlushedRows:
        if self.on:
            self._fh = open(self.path, "a" if self.append else "w", newline="")
            self._writer = csv.DictWriter(self._fh, fieldnames=self.columns)
            if not self.append:
                self._writer.writeheader()
                self._fh.flush()
        elif not self.append:
            self.path.unlink(missing_ok=True)  # a previous run's rows are not this run's
        return self

    def writerow(self, row: dict[str, Any]) -> None:
        self._writer.writerow(row)
        self._fh.flush()

    def __exit__(self, *exc: object) -> None:
        if self._fh is not None:
            self._fh.close()


def tracked_c2w(system: Any, n_done: int) -> list[torch.Tensor]:
    """The first ``n_done`` tracked poses as camera-to-world, in float64 on the CPU, as the metrics read them."""
    return [inverse(p.detach().double().cpu()) for p in system.poses[:n_done]]  # each [4, 4]


@torch.no_grad()
def milestone_row(cfg: RunConfig, parts: Parts, drive: Drive, out: Path) -> dict[str, Any]:
    """The map and trajectory so far, scored as if the drive ended here (``eval.at_frames``)."""
    t0 = time.perf_counter()
    system = parts.system
    n_done = len(drive.timestamps_s)
    est_c2w = tracked_c2w(system, n_done)
    res = _evaluate(cfg, out, parts, est_c2w, drive, system.device, write_gt=False)
    mem = schema.memory_summary(drive.windows, system.device.type)
    row = {k: res.get(k) for k in ("path_length_m", "path_length_ratio", "ate_rmse_m", "psnr_db", "ssim", "ms_ssim",
                                   "lpips", "eval_frames")}
    row.update(frames=n_done, n_gaussians=len(system.map), peak_mem_mib=mem[schema.PEAK_FIELD],
               state_mib=round(system.map.state_bytes() / schema.MIB, 4))
    row["eval_s"] = round(time.perf_counter() - t0, 3)
    return row


def keyframe_row(parts: Parts, res: FrameResult, frame_index: int, between: dict[str, Any]) -> dict[str, Any]:
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
        "n_pruned": res.n_pruned + between["n_pruned"],
        "n_candidates": res.n_candidates + between["n_candidates"],
        "state_bytes": state_bytes,
        "state_mib": round(state_bytes / schema.MIB, 4),
        **{k: _round(v) for k, v in mem.items()},
        "track_s": round(res.track_s, 4),
        "map_s": round(res.map_s, 4),
        "prune_s": round(res.prune_s + between["prune_s"], 4),
        **memory_parts(mem, live_mib, diag.get("state_map_bytes", state_bytes), state_bytes,
                       system.keyframe_store_bytes()),
        **{k: _round(diag.get(k)) for k in schema.PRUNE_QUARTILE_COLUMNS},
        **{k: diag.get(k, 0) + between[k] for k in schema.PRUNE_COUNT_COLUMNS},
        "diag_s": round(res.diag_s + between["diag_s"], 4),
        **{k: _round(diag.get(k)) for k in schema.FIT_COLUMNS},
    }


def memory_parts(mem: dict[str, float | None], live_mib: float | None, state_map_bytes: int, state_end_bytes: int,
                 keyframe_bytes: int) -> dict[str, float | None]:
    """The window's headline peak split into parts that add up to it (keyframes.csv ``mem_*``).

    The Gaussian state at its largest (after densification, mid-mapping) and the keyframe store are
    exact byte counts. What else stays live is measured at the window's end, when every work buffer
    is gone: live bytes minus the state and the keyframes then. The work buffers at the peak are
    what the peak holds beyond those three. Null where the device has no live-byte count.
    """
    peak = next((mem.get(c) for c in (schema.PEAK_SOURCES["cuda_alloc"], schema.PEAK_SOURCES["torch_live"])
                 if mem.get(c) is not None), None)
    if peak is None or live_mib is None:
        return dict.fromkeys(schema.MEMORY_PART_COLUMNS)
    state, kfs = state_map_bytes / schema.MIB, keyframe_bytes / schema.MIB
    other = live_mib - state_end_bytes / schema.MIB - kfs
    return {"mem_state_mib": _round(state), "mem_keyframes_mib": _round(kfs), "mem_other_mib": _round(other),
            "mem_work_mib": _round(peak - state - kfs - other)}


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def _round(v: float | None) -> float | None:
    return None if v is None else round(float(v), 3)


# ---------------------------------------------------------------------------------------------- finish


def finish(cfg: RunConfig, parts: Parts, drive: Drive, out: Path, device: torch.device) -> dict[str, Any]:
    """After the loop (none of it SLAM time): refine, summarise memory and time, evaluate, plot.

    A stopped or failed run (``partial``) skips refinement, rendering and the density figure: the
    trajectory metrics over the frames done are what it can still say.
    """
    system, timer = parts.system, parts.timer
    partial = drive.status in ("interrupted", "failed")
    n_done = len(drive.timestamps_s)
    metrics: dict[str, Any] = {"slam_wall_s": round(drive.loop_s, 3), "warmup_s": round(drive.warmup_s, 3)}
    if cfg.slam.refine_iters > 0 and not partial:
        with timer.phase("refine"), Phase("refine", cfg.slam.refine_iters, "iteration", cfg.progress) as bar:
            system.refine(cfg.slam.refine_iters, on_step=bar.update)
        metrics["refine_s"] = round(timer.totals()["refine"], 3)
    warmup = cfg.warmup_frames
    metrics["fps"] = round((n_done - warmup) / drive.loop_s, 4) if drive.loop_s > 0 and n_done > warmup else None
    # per-phase seconds of the frame loop, warm-up frames included: they sum to about
    # slam_wall_s + warmup_s (less the frame handling outside the phases); refinement is refine_s
    metrics["phase_s"] = {k: round(v, 3) for k, v in timer.totals().items() if k != "refine"}
    metrics["memory_method"] = {"cpu_rss": parts.probe.rss_method, "torch_live": cfg.memory.torch_live}
    metrics.update(schema.memory_summary([*drive.windows, drive.tail], device.type))
    metrics["gaussians_final"] = len(system.map)
    # churn: did pruning shrink the map, or only feed re-seeding?
    metrics["gaussians_added_total"] = sum(w["n_added"] for w in drive.windows)
    metrics["gaussians_pruned_total"] = sum(w["n_pruned"] for w in drive.windows)
    metrics["prune_candidates_total"] = sum(w["n_candidates"] for w in drive.windows)
    metrics["keep_ratio"] = parts.keys["keep_ratio"]  # as in run.keep_ratio: null when nothing is pruned
    est_c2w = tracked_c2w(system, n_done)
    t_eval = time.perf_counter()
    metrics.update(_evaluate(cfg, out, parts, est_c2w, drive, device, images=not partial))
    metrics["eval_s"] = round(time.perf_counter() - t_eval, 3)  # ATE, rendering, PSNR/SSIM/LPIPS
    from bench.report.figures.run_memory import memory_timeline

    memory_timeline(out / "memory.png", drive.windows, title=f"{parts.keys['strategy']} on {parts.seq.name}")
    if not partial:
        write_density(out / "density.npz", system)
    write_map(out / MAP_FILE, system.map)
    if parts.viz is not None:
        parts.viz.draw_all()
    return metrics


def describe(keys: dict[str, Any]) -> str:
    """A run in a figure title: strategy, keep ratio and preset, from its keys (``bench.config.identity.run_keys``)."""
    from bench.report.names import method_name

    ratio = "" if keys["keep_ratio"] is None else f", keep {keys['keep_ratio']:g}"
    return f"{method_name(keys['strategy'])} ({keys['strategy']}{ratio}, slam={keys['slam_preset']})"


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


def _evaluate(
    cfg: RunConfig,
    out: Path,
    parts: Parts,
    est_c2w: list[torch.Tensor],
    drive: Drive,
    device: torch.device,
    images: bool = True,
    write_gt: bool = True,
) -> dict[str, Any]:
    """ATE (evo), path-length ratio, PSNR/SSIM/MS-SSIM (torchmetrics), LPIPS when weights exist; none of
    it is SLAM time.

    The image metrics are scored under ``eval.protocol`` (``bench.metrics.protocol``): the whole image,
    or the pixels SplaTAM's valid-depth mask or the released code's silhouette mask keeps.
    ``images=False`` (a stopped or failed run) skips rendering: the trajectory metrics only.
    traj_est.txt is already on disk, appended frame by frame.
    """
    from bench.metrics.lpips import LPIPS
    from bench.metrics.protocol import frame_metrics, mean_metrics, protocol_mask
    from bench.metrics.trajectory import Trajectory, ate, path_length_ratio, rpe, write_tum

    ev = cfg.eval
    res: dict[str, Any] = {"ate_rmse_m": None, "psnr_db": None, "ssim": None, "ms_ssim": None, "lpips": None,
                           "eval_protocol": ev.protocol}
    if not est_c2w:
        return res
    ts = np.asarray(drive.timestamps_s)
    est = Trajectory.from_c2w(ts, torch.stack(est_c2w).numpy())
    if all(g is not None for g in drive.gt_c2w) and len(est_c2w) >= 3:
        gt_world = torch.stack([g.double() for g in drive.gt_c2w])
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
    if not images:
        return res
    idx = list(range(0, len(est_c2w), max(1, ev.every)))
    near_m, far_m = _eval_depth_range(cfg.dataset)
    lp = parts.lpips or (LPIPS.from_weights(ev.lpips_weights) if ev.lpips else None)
    lp = lp.to(device) if lp is not None else None
    frames = []
    with Phase("evaluate", len(idx), "frame", cfg.progress) as bar:
        with torch.no_grad():
            for i in idx:
                w2c = inverse(est_c2w[i]).float().to(device)
                render = parts.system.render(w2c)
                frame = parts.seq[i]
                mask = protocol_mask(ev.protocol, frame.depth_m, render.alpha.cpu(), near_m, far_m)  # [H, W] or None
                frames.append(frame_metrics(ev.protocol, render.color.clamp(0, 1).cpu(), frame.rgb, mask, lp))
                bar.update(1)
    img = mean_metrics(frames)
    img.pop("num_frames", None)  # that count is res["eval_frames"]; metrics["num_frames"] is frames tracked
    mask_frac = img.pop("mask_frac", None)
    res.update({k: _finite_or_none(v) if isinstance(v, float) else v for k, v in img.items()})
    if ev.protocol != "full":
        res["eval_mask_frac"] = None if mask_frac is None else round(mask_frac, 5)
        if ev.protocol == "splatam":
            res["eval_depth_range_m"] = [near_m, far_m]
    if min(parts.seq.height, parts.seq.width) < MS_SSIM_MIN_PX:
        log.info("ms_ssim: n/a: %dx%d px images are smaller than the %d px MS-SSIM needs on a side",
                 parts.seq.height, parts.seq.width, MS_SSIM_MIN_PX)
    res["eval_frames"] = len(idx)
    return res


def _eval_depth_range(dataset: Any) -> tuple[float, float | None]:
    """The dataset's ``eval_depth_near_m`` / ``eval_depth_far_m`` (a plugin's plain dict may lack them)."""
    get = dataset.get if isinstance(dataset, dict) else lambda k, d: getattr(dataset, k, d)
    return float(get("eval_depth_near_m", 0.0)), get("eval_depth_far_m", None)
