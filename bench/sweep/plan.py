"""A sweep's jobs, planned once: their overrides, their run dirs, their names in the summary.

Why one place: the sweeper launches the jobs, the summary callback lists them (every planned job,
run or not), ``bench.sweep.study`` lists a study's run dirs and the CLI refuses a sweep whose every job
is bad. All four must agree on what the jobs are and where each writes.

Hydra names a job's dir by its overrides less ``hydra.job.config.override_dirname.exclude_keys``
(``dataset.root``, ``checkpoint.every``, ...: settings that should not rename a run's dir). Two jobs
of one sweep that differ only in such a key would share a dir, and the later would overwrite or
skip the earlier. ``own_dirs`` gives each of them a dir of its own by naming the differing keys
too, as a per-job ``hydra.sweep.subdir``; jobs that share no dir keep Hydra's name.

A name longer than a file system allows (255 bytes on ext4, XFS, APFS; a study of memory policies
names a dozen settings) is cut and ends in a hash of the whole name (``short_name``), so the job still
gets a dir of its own and the same dir on every rerun; names that fit are Hydra's, unchanged.
"""

from __future__ import annotations

import hashlib
import re
from collections import defaultdict
from collections.abc import Sequence
from pathlib import Path
from typing import Any, cast

from omegaconf import DictConfig, OmegaConf

_OVERRIDE_DIRNAME = "${hydra:job.override_dirname}"
SUBDIR_KEY = "hydra.sweep.subdir"
NAME_MAX_BYTES = 255  # one path component (NAME_MAX on Linux and macOS file systems)
_DIGEST_CHARS = 12


def short_name(name: str) -> str:
    """``name`` when each of its path components fits in ``NAME_MAX_BYTES`` (a value's ``/`` nests the dir, as
    Hydra writes it), else each component too long cut, ending in ``~`` and a hash of the whole name."""
    parts = name.split("/")
    if all(len(p.encode()) <= NAME_MAX_BYTES for p in parts):
        return name
    digest = hashlib.sha1(name.encode()).hexdigest()[:_DIGEST_CHARS]
    cut = NAME_MAX_BYTES - _DIGEST_CHARS - 1
    return "/".join(
        p if len(p.encode()) <= NAME_MAX_BYTES else f"{p.encode()[:cut].decode(errors='ignore')}~{digest}"
        for p in parts
    )


def planned(config: DictConfig, arguments: Sequence[str]) -> list[list[str]]:
    """Every job of the sweep, in launch order: Hydra's basic expansion of ``arguments`` (and the
    sweeper's ``params``), or a study's sweeps (``+study=NAME``), each job with a dir of its own."""
    params = OmegaConf.select(config, "hydra.sweeper.params") or {}
    return expand(config, [*(f"{k}={v}" for k, v in params.items()), *arguments])


def expand(config: DictConfig, lines: Sequence[str]) -> list[list[str]]:
    """The jobs of these overrides (the sweeper's ``params`` already among them), each with its own dir."""
    from hydra._internal.core_plugins.basic_sweeper import BasicSweeper
    from hydra.core.override_parser.overrides_parser import OverridesParser

    parsed = OverridesParser.create().parse_overrides(list(lines))
    study = OmegaConf.select(config, "hydra.sweeper.study")
    if study:
        from bench.sweep.studyfile import expand as expand_study
        from bench.sweep.studyfile import parse

        name = next((str(o.value()) for o in parsed if o.key_or_group == "study"), "?")
        # the launcher's and sweeper's settings (hydra.launcher.n_jobs=1) configure the multirun, not a job: a job
        # is composed without the study file, whose defaults chose the launcher, so there they name no setting
        given = [
            o.input_line
            for o in parsed
            if o.key_or_group != "study" and o.input_line is not None and not multirun_only(o.input_line)
        ]
        jobs = [job for _, job in expand_study(parse(name, study), given)]
    else:
        jobs = BasicSweeper.split_arguments(parsed, None)[0]  # Hydra's own expansion (hydra-core 1.3)
    return own_dirs(config, [list(j) for j in jobs])


def own_dirs(config: DictConfig, jobs: list[list[str]]) -> list[list[str]]:
    """``jobs`` with a ``hydra.sweep.subdir`` override on each job that would otherwise share its dir
    with a job of other settings: Hydra's name plus the left-out keys that differ (a path's ``/``
    written as ``%2F``, so the dir stays one level deep)."""
    from hydra._internal.config_loader_impl import get_overrides_dirname  # how Hydra names a job dir
    from hydra.core.override_parser.overrides_parser import OverridesParser

    sweep = _sweep_node(config)
    if sweep.get("subdir") != _OVERRIDE_DIRNAME:
        return jobs  # a subdir of the user's (the job number, say): theirs to keep apart
    od = config.hydra.job.config.override_dirname
    excluded = list(od.exclude_keys)
    parser = OverridesParser.create()
    groups: dict[tuple[str, str], list[int]] = defaultdict(list)
    values: list[dict[str, str]] = []
    names: list[str] = []
    for i, job in enumerate(jobs):
        parsed = parser.parse_overrides([o for o in job if not _is_hydra(o)])
        values.append({o.key_or_group: o.get_value_element_as_str() for o in parsed})
        names.append(get_overrides_dirname(parsed, excluded, od.item_sep, od.kv_sep))
        groups[(str(sweep_dir(config, job)), names[i])].append(i)
    for members in groups.values():
        differ = [k for k in excluded if len({values[m].get(k) for m in members}) > 1]
        for m in members:
            extra = [f"{k}{od.kv_sep}{_safe(values[m][k])}" for k in differ if k in values[m]]
            subdir = od.item_sep.join([names[m], *extra] if names[m] else extra)
            if differ or short_name(subdir) != subdir:
                jobs[m] = [*jobs[m], f"{SUBDIR_KEY}='{_quoted(short_name(subdir))}'"]
    return jobs


def job_dir(config: DictConfig, job: Sequence[str], num: int | None = None) -> Path:
    """The run dir of job number ``num``: ``hydra.sweep.dir`` as the job resolves it
    (``multirun/${sweep_name}``), and its own ``hydra.sweep.subdir`` or Hydra's name of its overrides."""
    from hydra._internal.config_loader_impl import get_overrides_dirname
    from hydra.core.override_parser.overrides_parser import OverridesParser

    given = dict(_split(o) for o in job)
    if SUBDIR_KEY in given:
        return sweep_dir(config, job) / _unquoted(given[SUBDIR_KEY])
    if _sweep_node(config).get("subdir") != _OVERRIDE_DIRNAME:
        return sweep_dir(config, job) / str(num)  # a subdir of the user's: by job number, as Hydra's default
    od = config.hydra.job.config.override_dirname
    parsed = OverridesParser.create().parse_overrides([o for o in job if not _is_hydra(o)])
    return sweep_dir(config, job) / get_overrides_dirname(parsed, list(od.exclude_keys), od.item_sep, od.kv_sep)


def _sweep_node(config: DictConfig) -> dict[str, Any]:
    """``hydra.sweep`` as written (``dir``, ``subdir``), interpolations unresolved."""
    return cast(dict[str, Any], OmegaConf.to_container(config.hydra.sweep, resolve=False))  # a DictConfig node


def sweep_dir(config: DictConfig, job: Sequence[str]) -> Path:
    """``hydra.sweep.dir`` as ``job`` resolves it: ``multirun/${sweep_name}`` with the job's ``sweep_name``."""
    given = dict(_split(o) for o in job)
    node = OmegaConf.create(
        {
            "sweep_name": given.get("sweep_name", OmegaConf.select(config, "sweep_name")),
            "hydra": {"sweep": {"dir": _sweep_node(config)["dir"]}},
        }
    )
    return Path(str(node.hydra.sweep.dir))


def job_name(job: Sequence[str]) -> str:
    """A job in the sweep summary: all its settings (a left-out key too), sorted as Hydra names dirs."""
    return ",".join(sorted(o for o in job if not _is_hydra(o)))


def multirun_only(override: str) -> bool:
    """An override of the launcher or the sweeper (``hydra.launcher.n_jobs=1``, ``hydra/launcher=slurm``): it
    configures how a study's jobs are launched, and is no job's setting."""
    key = _split(override)[0]
    return any(
        key == k or key.startswith((f"{k}.", f"{k}/"))
        for k in ("hydra.launcher", "hydra/launcher", "hydra.sweeper", "hydra/sweeper")
    )


def _is_hydra(override: str) -> bool:
    key = override.lstrip("+~").split("=", 1)[0]
    return key == "hydra" or key.startswith(("hydra.", "hydra/"))


def _split(override: str) -> tuple[str, str]:
    key, _, value = override.lstrip("+~").partition("=")
    return key, value


def _safe(value: str) -> str:
    return value.replace("%", "%25").replace("/", "%2F")


def _quoted(text: str) -> str:
    return text.replace("\\", "\\\\").replace("'", "\\'")


def _unquoted(value: str) -> str:
    if len(value) >= 2 and value[0] == value[-1] == "'":
        return re.sub(r"\\(.)", r"\1", value[1:-1])
    return value


def header(config: DictConfig, jobs: list[list[str]]) -> dict[str, Any]:
    """What the summary needs of the plan: each job's number, name, dir and sweep dir (the summary's folder: a
    value with ``/`` nests a job's dir deeper than one level below it)."""
    return {
        "total": len(jobs),
        "planned": [
            {"num": i, "name": job_name(j), "dir": str(job_dir(config, j, i)), "sweep": str(sweep_dir(config, j))}
            for i, j in enumerate(jobs)
        ],
    }
