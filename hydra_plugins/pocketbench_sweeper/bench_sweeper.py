"""Hydra's basic sweeper, except that a job whose config cannot be composed is recorded, not fatal.

Why: Hydra composes every job of a batch before launching any and aborts the whole sweep on the
first that fails (with typed configs, ``seed=abc`` fails at composition). Here such a job gets
its run dir with a ``failed`` metrics.json holding the one-line reason, prints that line, and
the other jobs run. Works with any launcher (basic, joblib, submitit): only the batch handed to
the launcher changes.
"""

from __future__ import annotations

import logging
import sys
from collections.abc import Sequence
from typing import Any

# Hydra internal (hydra-core 1.3, hence the <1.4 pin in pyproject.toml): the basic sweeper is not
# public API but is the sweeper this one extends
from hydra._internal.core_plugins.basic_sweeper import BasicSweeper
from hydra.errors import HydraException
from omegaconf import OmegaConf
from omegaconf.errors import OmegaConfBaseException

from bench.errors import BenchError
from bench.run.lock import run_dir_lock
from bench.run.record import record_refusal

log = logging.getLogger(__name__)


class BenchSweeper(BasicSweeper):
    """``hydra/sweeper=bench`` (the default in conf/config.yaml).

    ``+study=NAME`` (``conf/study/NAME.yaml``) sets ``study``: the sweep is then the study's sweeps,
    one after another (``bench.sweep.study.expand``), each job in its own sweep's dir, with the rest of the
    command line applied over the study's overrides.
    """

    def __init__(self, max_batch_size: int | None = None, params: Any = None, study: Any = None) -> None:
        super().__init__(max_batch_size=max_batch_size, params=params)
        self.study = study

    def split_arguments(self, overrides: list[Any], max_batch_size: int | None) -> list[list[list[str]]]:
        """The jobs of the command line, each in a dir of its own (``bench.sweep.plan``; shadows Hydra's
        staticmethod, which ``sweep`` calls through self)."""
        from bench.sweep.plan import expand

        jobs = expand(self.config, [o.input_line for o in overrides])
        n = max_batch_size or len(jobs) or 1
        return [jobs[i : i + n] for i in range(0, len(jobs), n)]

    def sweep(self, arguments: list[str]) -> Any:
        launcher = self.launcher
        sweeper = self

        class _Filtered:
            """The launcher, handed only the jobs that compose."""

            def launch(self, job_overrides: Sequence[Sequence[str]], initial_job_idx: int) -> Any:
                """Each unbroken run of good jobs at its own job numbers: a job's number (and a dir
                named by it) is its place in the plan, whichever jobs before it were refused."""
                results, run, start = [], [], initial_job_idx
                for i, o in enumerate([*job_overrides, None]):
                    if o is not None and sweeper._composes(o, initial_job_idx + i):
                        run.append(list(o))
                        continue
                    if run:
                        results.extend(launcher.launch(run, initial_job_idx=start))
                    run, start = [], initial_job_idx + i + 1
                return results

            def __getattr__(self, name: str) -> Any:
                return getattr(launcher, name)

        self.launcher = _Filtered()  # type: ignore[assignment]
        try:
            return super().sweep(arguments)
        finally:
            self.launcher = launcher

    def validate_batch_is_legal(self, batch: Sequence[Sequence[str]]) -> None:
        """Composition failures are handled per job in ``_composes``; nothing aborts the sweep."""

    def _composes(self, overrides: Sequence[str], job_idx: int) -> bool:
        from bench.cli.entry import composition_error
        from bench.sweep.plan import job_dir, job_name
        from bench.sweep.summary import record_job

        try:
            self.hydra_context.config_loader.load_sweep_config(self.config, list(overrides))
            return True
        except (HydraException, OmegaConfBaseException, AssertionError) as exc:  # AssertionError: OmegaConf's
            message = composition_error(exc, list(overrides))
        log.info("\t#%d : %s", job_idx, " ".join(overrides))
        out = job_dir(self.config, overrides, job_idx)
        try:
            out.mkdir(parents=True, exist_ok=True)
            with run_dir_lock(out):  # a live run in this dir keeps it: the refusal is only printed
                record_refusal(out, message, _run_keys(self.config, overrides))
        except (BenchError, OSError) as exc:
            message += f" (nothing written: {exc})"
        print(f"error: {message}", file=sys.stderr)
        job = {
            "num": job_idx,
            "name": job_name(overrides),
            "status": "failed",
            "error": message,
            "dir": str(out),
            "metrics": {},
            "wall_s": None,
        }
        print(record_job(self.config.hydra.sweep.dir, job), file=sys.stderr, flush=True)
        return False


def _run_keys(config: Any, overrides: Sequence[str]) -> dict[str, Any]:
    """Best-effort run keys of a job that never composed: its overrides over the sweep's base config."""
    from bench.run.identity import run_keys

    given = dict(o.lstrip("+~").partition("=")[::2] for o in overrides)
    keys = ("strategy.name", "dataset.name", "slam.name", "seed")
    base = {k: OmegaConf.select(config, k, default=None) for k in keys}
    seed = given.get("seed", base["seed"])
    return run_keys(
        {
            "strategy": {"name": given.get("strategy") or base["strategy.name"]},
            "dataset": {"name": given.get("dataset") or base["dataset.name"]},
            "slam": {"name": given.get("slam") or base["slam.name"]},
            "seq": given.get("seq"),
            "seed": int(seed) if str(seed).isdigit() else None,
        }
    )
