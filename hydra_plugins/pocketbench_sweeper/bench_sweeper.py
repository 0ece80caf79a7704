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
from pathlib import Path
from typing import Any

# Hydra internals (hydra-core 1.3, hence the <1.4 pin in pyproject.toml): the basic sweeper is not
# public API but is the sweeper this one extends, and get_overrides_dirname is how Hydra names a job's
# dir (hydra.job.override_dirname), which a failed job's record must match
from hydra._internal.config_loader_impl import get_overrides_dirname
from hydra._internal.core_plugins.basic_sweeper import BasicSweeper
from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.errors import HydraException
from omegaconf import OmegaConf
from omegaconf.errors import OmegaConfBaseException

from bench.record import record_refusal

log = logging.getLogger(__name__)
_OVERRIDE_DIRNAME = "${hydra:job.override_dirname}"


class BenchSweeper(BasicSweeper):
    """``hydra/sweeper=bench`` (the default in conf/config.yaml).

    ``+study=NAME`` (``conf/study/NAME.yaml``) sets ``study``: the sweep is then the study's sweeps,
    one after another (``bench.study.expand``), each job in its own sweep's dir, with the rest of the
    command line applied over the study's overrides.
    """

    def __init__(self, max_batch_size: int | None = None, params: Any = None, study: Any = None) -> None:
        super().__init__(max_batch_size=max_batch_size, params=params)
        self.study = study

    def split_arguments(self, overrides: list[Any], max_batch_size: int | None) -> list[list[list[str]]]:
        """The jobs of the command line (shadows Hydra's staticmethod, which ``sweep`` calls through self)."""
        if not self.study:
            return BasicSweeper.split_arguments(overrides, max_batch_size)
        from bench.study import expand, parse

        given = [o for o in overrides if o.key_or_group != "study"]
        name = next((o.value() for o in overrides if o.key_or_group == "study"), "?")
        jobs = [job for _, job in expand(parse(str(name), self.study), [o.input_line for o in given])]
        n = max_batch_size or len(jobs) or 1
        return [jobs[i : i + n] for i in range(0, len(jobs), n)]

    def sweep(self, arguments: list[str]) -> Any:
        launcher = self.launcher
        sweeper = self

        class _Filtered:
            """The launcher, handed only the jobs that compose."""

            def launch(self, job_overrides: Sequence[Sequence[str]], initial_job_idx: int) -> Any:
                good = [list(o) for i, o in enumerate(job_overrides) if sweeper._composes(o, initial_job_idx + i)]
                return launcher.launch(good, initial_job_idx=initial_job_idx) if good else []

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
        from bench.cli import composition_error

        try:
            self.hydra_context.config_loader.load_sweep_config(self.config, list(overrides))
            return True
        except (HydraException, OmegaConfBaseException) as exc:
            message = composition_error(exc, list(overrides))
        log.info("\t#%d : %s", job_idx, " ".join(overrides))
        out = self._job_dir(overrides, job_idx)
        record_refusal(out, message, _run_keys(self.config, overrides))
        print(f"error: {message}", file=sys.stderr)
        return False

    def _job_dir(self, overrides: Sequence[str], job_idx: int) -> Path:
        hc = self.config.hydra
        sweep_dir = Path(str(hc.sweep.dir))
        subdir = OmegaConf.to_container(hc.sweep, resolve=False).get("subdir")
        if subdir != _OVERRIDE_DIRNAME:
            return sweep_dir / str(job_idx)
        parsed = OverridesParser.create().parse_overrides(list(overrides))
        od = hc.job.config.override_dirname
        return sweep_dir / get_overrides_dirname(parsed, list(od.exclude_keys), od.item_sep, od.kv_sep)


def _run_keys(config: Any, overrides: Sequence[str]) -> dict[str, Any]:
    """Best-effort run keys of a job that never composed: its overrides over the sweep's base config."""
    from bench.keys import run_keys

    given = dict(o.lstrip("+~").partition("=")[::2] for o in overrides)
    keys = ("strategy.name", "dataset.name", "slam.name", "seed")
    base = {k: OmegaConf.select(config, k, default=None) for k in keys}
    seed = given.get("seed", base["seed"])
    return run_keys({
        "strategy": {"name": given.get("strategy") or base["strategy.name"]},
        "dataset": {"name": given.get("dataset") or base["dataset.name"]},
        "slam": {"name": given.get("slam") or base["slam.name"]},
        "seq": given.get("seq"),
        "seed": int(seed) if str(seed).isdigit() else None,
    })
