"""``run(cfg) -> RunResult``: one SLAM run wired end to end, writing its run directory.

The composed Hydra config is validated and converted once (``bench.run.validate.validate``, which also
builds the strategy and a given LPIPS model; the CLI's own check hands its result over); everything
below receives dataclasses. A run reads as its data flows: ``bench.run.setup.build`` makes the SLAM
system around the opened sequence, ``bench.run.loop.run_frames`` feeds it the frames and writes one
``keyframes.csv`` row per keyframe window, ``bench.run.evaluation.finish`` refines, summarises memory,
evaluates and plots. Its keys come from ``bench.run.identity``.

Everything a run learns is written as it goes: ``keyframes.csv`` rows are flushed per keyframe
window and ``metrics.json`` is replaced atomically (``bench.run.record.RunRecord``, its one writer),
so an interrupted or lost run keeps what it computed. A known failure (``BenchError``) becomes status
``failed`` with its one-line message; ``TrackingLost`` becomes status ``lost`` and is still evaluated
on the frames tracked.
"""

from __future__ import annotations

import contextlib
import errno
import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

import torch
from omegaconf import DictConfig, OmegaConf

from bench import schema
from bench.conf import config_files
from bench.config.settings import plain
from bench.datasets import FrameSequence
from bench.errors import BenchError, ConfigError
from bench.fileio import link_message, planted_links
from bench.run import checkpoint as ckpt
from bench.run import evaluation, job_outputs, loop, provenance
from bench.run.config import RunConfig
from bench.run.determinism import repeatable
from bench.run.export import MAP_FILE
from bench.run.figures.pruned_run import PruneViz
from bench.run.identity import run_keys
from bench.run.lock import run_dir_lock
from bench.run.loop import TRAJ_EST, flushed_rows
from bench.run.record import RunRecord, promote, read_record, record_refusal, write_text
from bench.run.resume import redo_reason
from bench.run.setup import build, describe, open_seq, restore
from bench.run.signals import (
    Interrupted,
    Preemption,
    deferred_signals,
    held_preemption,
    raise_on_signals,
    signal_behind,
)
from bench.run.validate import ValidatedRun, validate
from bench.rundir import is_leftover, owner

log = logging.getLogger(__name__)


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


def run(cfg: DictConfig | RunConfig, out_dir: str | Path | None = None, built: ValidatedRun | None = None) -> RunResult:
    """Run one (strategy, dataset, seq, seed) combination and write its run directory.

    Order matters: the config is validated and the data opened before anything is written, so a
    refused run leaves no half-made dir; a stored run is skipped only when config, code version
    and input files all match (``bench.run.resume``); once running, SIGINT/SIGTERM end the run as
    ``interrupted`` with what the frames done allow (then ``Interrupted`` is re-raised).
    ``built``: what ``bench.run.validate.validate`` made of this same config already (the CLI's check
    before Hydra starts), used as it is; a config that differs from it is validated again.
    """
    if isinstance(cfg, RunConfig):
        cfg = cast(DictConfig, OmegaConf.structured(cfg))  # a dataclass instance makes a DictConfig
    out = Path(out_dir or cfg.out_dir or ".").resolve()
    try:
        if built is None or built.tree != {k: v for k, v in plain(cfg).items() if k != "hydra"}:
            built = validate(cfg)
    except ConfigError as exc:  # in a sweep the job is recorded; a single run was refused by the CLI already
        make_out_dir(out)
        with run_dir_lock(out):
            _refuse_links(out)
            return _refused(out, str(exc), run_keys(cfg), task_cfg=cfg)
    make_out_dir(out)
    with run_dir_lock(out):  # one writer per run dir, for the run's whole life: a live one refuses this one
        _refuse_links(out)
        return _run_locked(cfg, out, built)


# files a run writes at the top of its dir: a directory in one's place is refused before any work
RUN_FILES = (schema.METRICS_FILE, "config.yaml", TRAJ_EST, schema.KEYFRAMES_FILE, MAP_FILE)


def _refuse_links(out: Path) -> None:
    """A symlink in the run dir (``keyframes.csv`` -> a file elsewhere) is refused before anything is written:
    the run would write through it (``bench.fileio``); so is a directory where a run file goes."""
    links = planted_links(out)
    if links:
        more = f" (and {len(links) - 1} more)" if len(links) > 1 else ""
        raise ConfigError(link_message(links[0]) + more)
    in_the_way = [name for name in RUN_FILES if (out / name).is_dir()]
    if in_the_way:
        raise ConfigError(f"run dir {out}: expected {in_the_way[0]} to be a file or nothing, found a directory")


def _run_locked(cfg: DictConfig, out: Path, built: ValidatedRun) -> RunResult:
    """``run`` past validation, with ``out`` made and its lock held: open the inputs, decide where the run
    starts (skip, resume or redo), open its record, drive it, close the record, hand a stop on."""
    stored = _previous(out)
    opened = _open_inputs(cfg, out, built)
    if isinstance(opened, RunResult):  # refused before any work
        return opened
    device, seq, keys = opened
    plan = _plan_start(built.config, out, stored, keys)
    if isinstance(plan, RunResult):  # the same finished run is there already
        return plan
    out, final, start = plan
    record = _open_record(cfg, built.config, out, final, keys, start)
    status, error, metrics, stop, preempt = _drive(built, out, device, record, seq, start)
    out, status, error = _close_record(record, out, final, status, error, metrics)
    if stop is not None:
        _hand_on(stop, preempt, out, metrics, error)
    return RunResult(status, out, metrics, error)


def _open_inputs(
    cfg: DictConfig, out: Path, built: ValidatedRun
) -> RunResult | tuple[torch.device, FrameSequence, dict[str, Any]]:
    """The device, the opened sequence and the run's keys (its input files fingerprinted), or the refusal
    of a run whose device, checkpoint paths or data are unusable before any work."""
    conf = built.config  # below here only dataclasses travel
    keys = run_keys(conf, built.tree)
    try:
        device = resolve_device(conf.device)
        ckpt.check_files(out)
        seq = open_seq(conf)  # the loaders draw from their own seeded generators, not the global ones
    except BenchError as exc:  # bad data found before any work
        return _refused(out, str(exc), keys, OmegaConf.to_yaml(cfg, resolve=True), cfg)
    keys = run_keys(conf, built.tree, seq)
    missing = [name for name, digest in keys["inputs"].items() if digest == "missing"]
    if missing:  # the fingerprint found them gone: refuse now, not at the frame that reads one
        more = f" and {len(missing) - 1} more" if len(missing) > 1 else ""
        return _refused(
            out,
            f"input files: expected every file the dataset lists, found {missing[0]} missing{more}",
            keys,
            OmegaConf.to_yaml(cfg, resolve=True),
            cfg,
        )
    return device, seq, keys


def _plan_start(
    conf: RunConfig, out: Path, stored: dict[str, Any] | None, keys: dict[str, Any]
) -> RunResult | tuple[Path, Path, dict[str, Any] | None]:
    """Where this run works and starts: ``(out, final, start)``, with ``out`` the staging dir of a redo of a
    finished run (``final`` the run dir) and ``start`` the checkpoint a resumed run starts from (None: frame
    0); or the stored result, skipped, when resume finds the same finished run."""
    start: dict[str, Any] | None = None
    level = logging.INFO  # of the redo line: a warning when a checkpoint was there but unusable
    final = out  # the run dir; a redo of a finished run works in its staging dir until it finishes
    reason = redo_reason(stored, keys) if conf.resume else None  # None with resume: the same finished run
    if conf.resume and reason is None and stored is not None:
        log.info("skipping %s: completed results of the same config, code and inputs exist", out)
        return RunResult(stored["status"], out, stored.get("metrics", {}), stored.get("error"), skipped=True)
    if stored is not None and stored.get("status") in schema.FINISHED:
        out = out / schema.REDO_DIR
        make_out_dir(out)
        staged = _previous(out)  # a redo stopped earlier: its checkpoint lets this one resume
        if conf.resume and staged is not None and redo_reason(staged, keys) is None:
            promote(out, final)  # a redo that finished but was stopped while moving in
            return RunResult(staged["status"], final, staged.get("metrics", {}), staged.get("error"), skipped=True)
        stored = staged or stored
    if conf.resume:
        if stored is not None and stored.get("status") == "interrupted" and ckpt.exists(out):
            start, why = ckpt.find(out, keys, flushed_rows(out))
            if start is None:
                reason, level = f"its checkpoint was not used: {why}; starting over from frame 0", logging.WARNING
        if start is not None:
            log.info("resuming %s from frame %d (checkpoint of keyframe %d)", out, start["frame"], start["keyframe"])
        elif stored is not None:
            log.log(level, "redoing %s: %s", final, reason)
    return out, final, start


def _open_record(
    cfg: DictConfig, conf: RunConfig, out: Path, final: Path, keys: dict[str, Any], start: dict[str, Any] | None
) -> RunRecord:
    """The ``running`` record, saved, with Hydra's job files and ``config.yaml`` beside it; the rows a
    resumed run's checkpoint did not count cut off, and a fresh run's leftovers (trajectory, checkpoints) gone."""
    record = RunRecord(
        out / schema.METRICS_FILE,
        {
            "status": "running",
            "error": None,
            "run": keys,
            "determinism": {},
            "metrics": {},
            "provenance": {},
            "owner": owner(),
        },
    )
    job_outputs.keep(final, cfg, out)
    write_text(out / "config.yaml", OmegaConf.to_yaml(cfg, resolve=True))
    record["checkpoint"] = {
        "every": conf.checkpoint.every,
        "written": 0,
        "mib_last": None,
        "write_s_total": 0.0,
        "resumed_from_frames": [],
    }
    if start is None:
        (out / TRAJ_EST).unlink(missing_ok=True)
    else:  # rows written after the checkpoint go; the loop appends from there
        ckpt.truncate_rows(out / TRAJ_EST, 1, start["rows"]["traj"])
        ckpt.truncate_rows(out / schema.KEYFRAMES_FILE, 1, start["rows"]["keyframes"])
        if (out / schema.MILESTONES_FILE).exists():
            ckpt.truncate_rows(out / schema.MILESTONES_FILE, 1, start["rows"].get("milestones", 0))
        record["checkpoint"] = {
            **start["stats"],
            "every": conf.checkpoint.every,
            "resumed_from_frames": [*start["stats"]["resumed_from_frames"], start["frame"]],
        }
    record.save()
    if start is None:
        ckpt.remove(out)  # a previous run's checkpoints: the record they belonged to is replaced now
    return record


def _drive(
    built: ValidatedRun,
    out: Path,
    device: torch.device,
    record: RunRecord,
    seq: FrameSequence,
    start: dict[str, Any] | None,
) -> tuple[str, str | None, dict[str, Any], Interrupted | None, Preemption]:
    """The run under its signal handlers and determinism settings: ``(status, error, metrics, stop, preempt)``,
    a known failure or a stop turned into its status; an unexpected error is recorded and raised again."""
    conf = built.config
    stop: Interrupted | None = None
    preempt = Preemption()
    try:
        with (
            raise_on_signals(),
            held_preemption() as preempt,
            repeatable(conf.seed, conf.threads, conf.determinism, device) as det,
        ):
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
        behind = signal_behind(exc)  # a stop that a C extension reported as its own error
        failed_write = write_failure(exc, out)
        if behind is None and failed_write is None:
            record.close(status="failed", error=f"{type(exc).__name__}: {exc}".splitlines()[0])
            raise
        if behind is None:  # a full disk, a dir made read-only: the run's own files cannot be written
            status, error, metrics = "failed", str(failed_write), record["metrics"]
        else:
            n_done = record["metrics"].get("num_frames", 0)
            status, error, metrics, stop = "interrupted", f"{behind} after {n_done} frames", record["metrics"], behind
    return status, error, metrics, stop, preempt


def _close_record(
    record: RunRecord, out: Path, final: Path, status: str, error: str | None, metrics: dict[str, Any]
) -> tuple[Path, str, str | None]:
    """The record closed with the run's status; a finished redo moved over the run it redid. Returns
    ``(out, status, error)``: the run dir the result is in, and a status and error that say so when the
    record itself could not be written."""
    with deferred_signals():  # a second Ctrl-C must not cut the record in half
        try:
            record.close(status=status, error=error, metrics=metrics)
            if status != "interrupted":
                ckpt.remove(out)  # finished (or failed on its data): a rerun never resumes it
                if out != final and status in schema.FINISHED:
                    promote(out, final)  # only a redo that finishes replaces the finished record
                    out = final
        except OSError as exc:  # the record itself cannot be written (the same full disk or read-only dir)
            if write_failure(exc, out) is None:
                raise
            status, error = "failed", f"{error or status}; {write_failure(exc, out)} (metrics.json not updated)"
    return out, status, error


def _hand_on(stop: Interrupted, preempt: Preemption, out: Path, metrics: dict[str, Any], error: str | None) -> None:
    """Raise the stop that ended the run, its record written; a preemption first goes to the launcher's handler."""
    if preempt.signum is not None and preempt.signum == stop.signum:
        log.warning(
            "%s: preempted after %d frames; checkpoint written, the launcher requeues the job",
            out,
            metrics.get("num_frames", 0),
        )
        preempt.hand_over()  # the launcher's own handler (submitit: requeue, then exit)
    raise Interrupted(stop.signum, f"{error}; partial results in {out}")


# the file system refusing a run's writes: full, read-only, no permission, too big, a directory in a file's place
WRITE_ERRNOS = (errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM, errno.EFBIG, errno.EISDIR)


def write_failure(exc: BaseException, out: Path) -> BenchError | None:
    """A file system refusing the run's writes (``WRITE_ERRNOS``: full, read-only, no permission) as one line;
    None for any other error (a bug, which keeps its traceback)."""
    if not isinstance(exc, OSError) or exc.errno not in WRITE_ERRNOS:
        return None
    where = exc.filename if exc.filename else "its files"
    return BenchError(f"run dir {out}: expected to write {where}, found: {exc.strerror or exc}")


def _refused(
    out: Path, error: str, keys: dict[str, Any], config_yaml: str | None = None, task_cfg: DictConfig | None = None
) -> RunResult:
    """A run refused before any work: recorded ``failed``, unless ``out`` holds a previous run's
    record to keep (finished, resumable or live), which a refusal for a passing reason (data briefly
    unreachable, no CUDA on this node) must not replace."""
    kept = record_refusal(out, error, keys, config_yaml, task_cfg)
    if kept is not None:
        error = f"{error} (nothing written: {out} keeps its {kept} record)"
    return RunResult("failed", out, {}, error)


def _config_files() -> dict[str, str] | None:
    """The file each group choice came from (a user's ./conf or the package), when Hydra composed the run."""
    from hydra.core.hydra_config import HydraConfig

    return config_files(HydraConfig.get().runtime.choices) if HydraConfig.initialized() else None


def _previous(out: Path) -> dict[str, Any] | None:
    """The metrics.json a previous run left here; a ``running`` one whose process died is marked interrupted."""
    path = out / schema.METRICS_FILE
    stored = read_record(out)
    if stored is None:
        return None
    if is_leftover(stored):
        who = stored.get("owner") or {}
        frames = (stored.get("metrics") or {}).get("num_frames", 0)
        stored = RunRecord(path, stored)
        stored.close(
            status="interrupted", error=f"killed: process {who.get('pid')} stopped while running, after {frames} frames"
        )
        log.warning(
            "%s: the previous run was killed while running (pid %s); recorded as interrupted", out, who.get("pid")
        )
    return stored


def _execute(
    built: ValidatedRun,
    out: Path,
    device: torch.device,
    record: RunRecord,
    seq: FrameSequence,
    start: dict[str, Any] | None = None,
    preempt: Preemption | None = None,
):
    t_start = time.perf_counter()
    cfg = built.config
    parts = build(cfg, device, seq, built, out)
    parts.keys = record["run"]
    parts.system.use_run_dir(out)  # slam.residency's files; a resumed run's come back from its checkpoint
    if cfg.viz.pruning:
        parts.viz = parts.system.on_prune = PruneViz(parts.system, out, cfg.viz.every, describe(parts.keys))
    metrics: dict[str, Any] = {"num_frames": 0, "num_keyframes": 0}
    record["metrics"] = metrics
    if start is not None:
        restore(parts, start)
        if parts.viz is not None:  # the stopped run's pictures up to the checkpoint are this run's too
            parts.viz.written = [p for p in sorted(out.glob("pruned_kf*.npz")) if _kf_of(p) <= start["keyframe"]]
    drive = loop.run_frames(cfg, parts, out, record, start, preempt)
    with deferred_signals() if drive.stop is not None else contextlib.nullcontext():
        evaluation.finish(cfg, parts, drive, out, device, metrics)
        parts.system.keyframes.close()  # the on-disk keyframe store: a resume writes it again from the sequence
        metrics["wall_s"] = round(time.perf_counter() - t_start, 3)  # the whole run: loading to figures
    return drive.status, drive.error, metrics, drive.stop


def _kf_of(path: Path) -> int:
    """The keyframe a ``pruned_kfNNN.npz`` belongs to (-1 for a name not of that form)."""
    digits = path.stem.removeprefix("pruned_kf")
    return int(digits) if digits.isdigit() else -1
