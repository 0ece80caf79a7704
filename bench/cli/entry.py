"""The thin CLI over ``bench.run.lifecycle`` (``pocketbench`` and ``python -m bench``): Hydra composes the
config, known errors print one line.

The configs ship inside the package (``bench/conf``) and Hydra reads them as ``pkg://bench.conf``,
so a wheel install finds them as an editable one does.

Before Hydra takes over, ``precheck`` composes a single run's config itself and validates it
(``bench.run.validate``), so a bad setting ends in one ``error:`` line and exit 2 before Hydra creates
a run dir; Hydra's own answers (a multi-line listing for an unknown option, a four-line message for
an unknown key) are turned into that line too. In a sweep each job is checked where it runs and a
bad one is recorded ``failed`` (``hydra_plugins/pocketbench_sweeper``) while the sweep goes on.
"""

from __future__ import annotations

import logging
import sys
import time
import traceback
import warnings
from pathlib import Path
from typing import TYPE_CHECKING

import hydra
from hydra.core.hydra_config import HydraConfig
from hydra.types import RunMode
from omegaconf import DictConfig

from bench.cli.argv import (
    check_output_dirs,
    check_overrides,
    check_study,
    composition_error,
    shared_refusal,
    split_args,
)
from bench.cli.help import register_resolvers
from bench.conf import CONF_DIR
from bench.errors import BenchError, ConfigError, failed
from bench.run.config import compose, register_configs
from bench.sweep.summary import run_table

if TYPE_CHECKING:
    from bench.run.validate import ValidatedRun

CONF_PKG = "bench.conf"
# Hydra finds plugins (our sweeper) only in the hydra_plugins namespace package. An editable
# install made before that folder existed does not map it, so the checkout root joins the path
# (last, so installed packages win).
_ROOT = Path(__file__).resolve().parents[2]
if (_ROOT / "hydra_plugins").is_dir() and str(_ROOT) not in sys.path:
    sys.path.append(str(_ROOT))
log = logging.getLogger("bench")
EXIT_CONFIG = 2  # a known error: bad setting, bad input, failed run
# conf/hydra/launcher/submitit_local.yaml shares its name with the plugin's schema (the command is
# hydra/launcher=submitit_local either way); Hydra 1.3 still validates it against that schema and
# warns, at length, that it will stop doing so.
warnings.filterwarnings("ignore", message=r"(?s).*is validated against ConfigStore schema with the same name")


def precheck(argv: list[str]) -> ValidatedRun | None:
    """Everything that can be refused before Hydra runs anything: one ``BenchError`` line.

    Returns the run a single-run command line builds (``bench.run.validate.ValidatedRun``), for ``bench.run.lifecycle``
    to use rather than build again; None for a sweep (each job is validated where it runs).
    """
    parts = split_args(argv)
    if parts is None:
        return None
    multirun, job, hyd = parts
    check_output_dirs(multirun, job, hyd)
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from hydra.errors import HydraException
    from omegaconf.errors import OmegaConfBaseException

    check_study(job)
    swept = job
    try:
        if multirun:  # what Hydra composes before any job: the command line without its sweeps
            parsed = OverridesParser.create().parse_overrides(job)
            job = [o.input_line for o in parsed if not o.is_sweep_override() and o.input_line is not None]
        cfg = compose(job)
    except (HydraException, OmegaConfBaseException, AssertionError) as exc:  # AssertionError: OmegaConf's, on null
        raise ConfigError(composition_error(exc, job)) from None
    if multirun:
        shared_refusal(job, swept, hyd)
        return None  # each job is validated where it runs (our sweeper, bench.run.lifecycle) and recorded if bad
    from bench.run.lifecycle import resolve_device
    from bench.run.validate import validate

    built = validate(cfg)
    resolve_device(built.config.device)  # a single run runs here: this machine must have the device
    return built


@hydra.main(version_base="1.3", config_path=f"pkg://{CONF_PKG}", config_name="config")
def _hydra_main(cfg: DictConfig) -> None:
    from bench.run.lifecycle import run
    from bench.run.signals import Interrupted

    hc = HydraConfig.get()
    multirun = hc.mode == RunMode.MULTIRUN
    t0 = time.perf_counter()
    built = _PRECHECKED.pop() if _PRECHECKED else None  # a single run's config, built by precheck
    try:
        result = run(cfg, out_dir=cfg.out_dir or hc.runtime.output_dir, built=built)
    except Interrupted as exc:  # recorded as interrupted; a stopped sweep stops too
        print(f"error: {exc}", file=sys.stderr)
        sys.exit(exc.exit_code)
    except BenchError as exc:  # a config error before the run dir exists
        print(f"error: {exc}", file=sys.stderr)
        if multirun:
            _record(hc, "failed", hc.runtime.output_dir, {}, time.perf_counter() - t0)
            return
        sys.exit(EXIT_CONFIG)
    except Exception as exc:  # a bug: its traceback stays; in a sweep the job is recorded failed and the sweep goes on
        if not multirun:
            raise
        traceback.print_exc()
        reason = f"{type(exc).__name__}: {exc}".splitlines()[0]
        print(f"error: job {hc.job.num} raised {reason} (a bug; traceback above); the sweep goes on", file=sys.stderr)
        _record(hc, "failed", cfg.out_dir or hc.runtime.output_dir, {}, time.perf_counter() - t0)
        return
    wall_s = None if result.skipped else time.perf_counter() - t0
    if result.status == "failed":
        print(f"error: {result.error}", file=sys.stderr)
        if not multirun:
            sys.exit(EXIT_CONFIG)
        _record(hc, "failed", result.out_dir, result.metrics, wall_s)
        return
    word = "skipped (completed)" if result.skipped else result.status
    reason = f" ({result.error})" if result.error else ""
    print(f"[{word}] {result.out_dir}" + reason)
    if multirun:
        # a resumed run shows its stored status, marked, in the sweep table
        status = f"{result.status} (resumed)" if result.skipped else result.status
        _record(hc, status, result.out_dir, result.metrics, wall_s)
    else:
        print(run_table(result.status, result.out_dir, result.metrics, wall_s))


def _record(hc, status: str, out_dir: object, metrics: dict, wall_s: float | None) -> None:
    """One finished sweep run into the sweep's job record, and the sweep progress line.

    A job refused before any work leaves a previous run's record in its dir (``record_refusal``); its row
    then says so (``failed (keeps its ok run)``), so that the summary of a rerun refused for a passing
    reason does not read as if the runs in those dirs had failed."""
    from bench.run.record import KEPT, read_record
    from bench.sweep.plan import job_name
    from bench.sweep.summary import record_job

    stored = read_record(Path(str(out_dir))) if status == "failed" else None
    if stored is not None and stored.get("status") in KEPT:
        status = f"failed (keeps its {stored['status']} run)"
    job = {
        "num": hc.job.num,
        "name": job_name(list(hc.overrides.task)),
        "status": status,
        "dir": str(out_dir),
        "metrics": dict(metrics),
        "wall_s": wall_s,
    }
    print(record_job(hc.sweep.dir, job), file=sys.stderr, flush=True)


# the schemas bench/conf/*.yaml build on, and a strategy/NAME entry for each plugin that ships no YAML,
# before Hydra composes anything; here, so launcher workers (joblib, submitit) that import this module see them
register_configs()
# what precheck built for the single run Hydra is about to start (bench.run.lifecycle checks it is the same config)
_PRECHECKED: list[ValidatedRun] = []


def main() -> int:
    if sys.argv[1:2] == ["view"]:  # a subcommand, not a run: the viewer (bench.viewer), never imported by a run
        from bench.viewer.cli import main as view

        return view(sys.argv[2:])
    try:
        check_overrides(sys.argv[1:])
        built = precheck(sys.argv[1:])
    except BenchError as exc:
        return failed(exc, EXIT_CONFIG)
    _PRECHECKED[:] = [built] if built is not None else []
    register_resolvers()
    _hydra_main()
    return 0


__all__ = ["CONF_DIR", "check_overrides", "compose", "main", "precheck"]
