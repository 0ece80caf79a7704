"""A study file as data: its sweeps, their runs' overrides, and its report options (``bench.sweep.study`` loads it).

Kept apart from ``bench.sweep.study`` because the sweeper (``bench.sweep.plan``) expands a study's sweeps while
``bench.sweep.study`` asks the sweeper for each run's dir: neither imports the other through this module.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bench.config.settings import check_folder_name
from bench.errors import ConfigError

GROUP = "study"


@dataclass
class Study:
    """One study file, composed: its sweeps (name -> overrides, sweeps as ``a,b,c``) and report options."""

    name: str
    sweeps: dict[str, list[str]]
    # out (the folder), paper, baseline, format, dpi, planned, regime
    report: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class Job:
    """One run of a study: the overrides it is composed with and the dir it writes."""

    sweep: str
    overrides: tuple[str, ...]
    run_dir: Path


def parse(name: str, node: Mapping[str, Any] | None) -> Study:
    """The ``hydra.sweeper.study`` node of a composed config as a ``Study``; one line if it is malformed."""
    if not isinstance(node, Mapping) or not isinstance(node.get("sweeps"), Mapping) or not node["sweeps"]:
        raise ConfigError(
            f"study '{name}': expected hydra.sweeper.study.sweeps, a mapping of sweep name to overrides, found {node!r}"
        )
    sweeps = {}
    for sweep, overrides in node["sweeps"].items():
        if (
            not isinstance(overrides, Sequence)
            or isinstance(overrides, str)
            or not all(isinstance(o, str) for o in overrides)
        ):
            raise ConfigError(f"study '{name}' sweep '{sweep}': expected a list of overrides, found {overrides!r}")
        check_folder_name(f"study '{name}' sweep name", str(sweep))  # its runs go to multirun/<sweep>
        # the key's parts: hydra.* and any _target_ node (prune.n_target_per_mpx is a run setting, not a _target_)
        barred = [
            o
            for o in overrides
            if _key_parts(o)[0] == "hydra" or "_target_" in _key_parts(o) or "_target_" in o.partition("=")[2]
        ]
        if barred:
            raise ConfigError(
                f"study '{name}' sweep '{sweep}': expected run settings, found {barred[0]!r} "
                "(a study sets no hydra.* key and no _target_)"
            )
        sweeps[str(sweep)] = list(overrides)
    report = dict(node.get("report") or {})
    return Study(name, sweeps, report)


# what a study file may hold (conf/study/*.yaml): its sweep dir, a launcher, its sweeps and report options
FILE_KEYS = ("defaults", "sweep_name", "hydra")
REPORT_KEYS = ("out", "paper", "baseline", "format", "dpi", "planned", "regime")  # planned: committed before its runs
LAUNCHER_DEFAULT = "override /hydra/launcher"


def check_file(name: str, path: Path) -> None:
    """One line unless study file ``path`` holds only what a study needs (``FILE_KEYS``: ``sweep_name``, a
    ``defaults`` list that picks a launcher, ``hydra.sweeper.study`` with ``sweeps`` and ``report``): a study
    file is composed into the run's config, where any other key (``hydra.callbacks``, a ``_target_``) would
    run code or change settings the study does not show. YAML that does not parse is left to the composition."""
    import yaml

    try:
        raw = yaml.safe_load(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, yaml.YAMLError):
        return

    def refuse(where: str, expected: str, found: Any) -> None:
        raise ConfigError(f"study '{name}' ({path}) {where}: expected {expected}, found {found}")

    if not isinstance(raw, Mapping):
        return
    extra = sorted(str(k) for k in raw if k not in FILE_KEYS)
    if extra:
        refuse("keys", f"only {', '.join(FILE_KEYS)}", ", ".join(extra))
    defaults = raw.get("defaults") or []
    for item in defaults if isinstance(defaults, list) else [defaults]:
        launcher = isinstance(item, Mapping) and list(item) == [LAUNCHER_DEFAULT]
        if not (launcher and isinstance(item[LAUNCHER_DEFAULT], str)):
            refuse("defaults", f"'{LAUNCHER_DEFAULT}: NAME' only", repr(item))
    if "sweep_name" in raw:
        check_folder_name(f"study '{name}' sweep_name", raw["sweep_name"])
    hydra = raw.get("hydra")
    sweeper = hydra.get("sweeper") if isinstance(hydra, Mapping) else None
    study = sweeper.get("study") if isinstance(sweeper, Mapping) else None
    for where, node, allowed in (
        ("hydra", hydra, ("sweeper",)),
        ("hydra.sweeper", sweeper, ("study",)),
        ("hydra.sweeper.study", study, ("sweeps", "report")),
        ("hydra.sweeper.study.report", study.get("report") if isinstance(study, Mapping) else None, REPORT_KEYS),
    ):
        extra = sorted(str(k) for k in node if k not in allowed) if isinstance(node, Mapping) else []
        if extra:
            refuse(where, f"only {', '.join(allowed)}", ", ".join(extra))


def expand(study: Study, extra: Sequence[str] = ()) -> list[tuple[str, list[str]]]:
    """``(sweep name, job overrides)`` for every run, in order: each sweep's product of ``a,b,c`` values,
    with ``extra`` (the rest of the command line) applied over the study's own overrides.

    A sweep runs in ``multirun/<its name>`` unless its overrides name another ``sweep_name`` (two
    products sharing one sweep dir)."""
    from hydra._internal.core_plugins.basic_sweeper import BasicSweeper  # Hydra's own expansion (hydra-core 1.3)
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from hydra.errors import HydraException

    parser = OverridesParser.create()
    jobs = []
    for sweep, overrides in study.sweeps.items():
        try:
            parsed = parser.parse_overrides([f"sweep_name={sweep}", *overrides, *extra])
        except HydraException as exc:
            found = str(exc).strip().splitlines()[0]
            raise ConfigError(
                f"study '{study.name}' sweep '{sweep}': expected overrides as on a command line, found: {found}"
            ) from None
        for job in BasicSweeper.split_arguments(parsed, None)[0]:
            name = next(o.split("=", 1)[1] for o in job if o.startswith("sweep_name="))
            check_folder_name(f"study '{study.name}' sweep '{sweep}' sweep_name", name)  # an override may set it
            jobs.append((name, job))
    return jobs


def check_name(name: str) -> None:
    """One line unless ``name`` has a study file (else Hydra takes ``+study=NAME`` for a new setting)."""
    from bench.conf import group_files

    check_folder_name("study", name)  # a name under conf/study/, not a path to a file elsewhere
    if name not in group_files(GROUP):
        found = ", ".join(sorted(group_files(GROUP))) or "none (no conf/study/ in the current directory)"
        raise ConfigError(f"unknown study '{name}': expected a file conf/study/{name}.yaml, found: {found}")


def _key_parts(override: str) -> list[str]:
    """The dotted (or group-path) parts of an override's key: ``+slam.lrs.means=1`` gives slam, lrs, means."""
    return re.split(r"[./@]", override.lstrip("+~").split("=", 1)[0])
