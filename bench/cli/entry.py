"""The thin CLI over ``bench.run.lifecycle`` (``pocketbench`` and ``python -m bench``): Hydra composes the
config, known errors print one line.

The configs ship inside the package (``bench/conf``) and Hydra reads them as ``pkg://bench.conf``,
so a wheel install finds them as an editable one does.

Before Hydra takes over, ``precheck`` composes a single run's config itself and validates it
(``bench.cli.validate``), so a bad setting ends in one ``error:`` line and exit 2 before Hydra creates
a run dir; Hydra's own answers (a multi-line listing for an unknown option, a four-line message for
an unknown key) are turned into that line too. In a sweep each job is checked where it runs and a
bad one is recorded ``failed`` (``hydra_plugins/pocketbench_sweeper``) while the sweep goes on.
"""

from __future__ import annotations

import dataclasses
import logging
import re
import sys
import tempfile
import time
import warnings
from pathlib import Path
from typing import TYPE_CHECKING

import hydra
from hydra.core.hydra_config import HydraConfig
from hydra.types import RunMode
from omegaconf import DictConfig, OmegaConf

from bench.conf import CONF_DIR, group_files
from bench.config.compose import compose, expected, register_configs
from bench.config.plugins import unknown_name_message
from bench.config.settings import describe_error
from bench.errors import BenchError, ConfigError, StrategyError
from bench.sweep.summary import run_table

if TYPE_CHECKING:
    from bench.cli.validate import Built

CONF_PKG = "bench.conf"
# Hydra finds plugins (our sweeper) only in the hydra_plugins namespace package. An editable
# install made before that folder existed does not map it, so the checkout root joins the path
# (last, so installed packages win).
_ROOT = Path(__file__).resolve().parents[2]
if (_ROOT / "hydra_plugins").is_dir() and str(_ROOT) not in sys.path:
    sys.path.append(str(_ROOT))
log = logging.getLogger("bench")
EXIT_CONFIG = 2  # a known error: bad setting, bad input, failed run
_GROUPS = ("dataset", "slam", "strategy", "experiment")
# groups a user picks from, in the order --help lists them; slam_dataset is picked by the dataset
HELP_GROUPS: tuple[str, ...] = ("dataset", "slam", "strategy", "experiment", "study", "hydra/launcher")
# conf/hydra/launcher/submitit_local.yaml shares its name with the plugin's schema (the command is
# hydra/launcher=submitit_local either way); Hydra 1.3 still validates it against that schema and
# warns, at length, that it will stop doing so.
warnings.filterwarnings("ignore", message=r"(?s).*is validated against ConfigStore schema with the same name")


def strategy_names() -> list[str]:
    """Strategies a user can name: built-in configs plus installed entry points."""
    from bench.slam.strategy import available

    return sorted(group_choices("strategy") | set(available()))


def group_choices(group: str) -> set[str]:
    """Config files for ``group``: ``./conf/<group>/*.yaml`` and the shipped ``bench/conf/<group>/*.yaml``."""
    return set(group_files(group))


def help_groups() -> str:
    """The ``--help`` listing: each user-facing group with its choices, installed plugins included."""
    from bench.slam.strategy import available

    defaults = {"dataset": "synthetic", "slam": "default", "hydra/launcher": "basic"}
    lines = []
    for group in HELP_GROUPS:
        choices = group_choices(group) | (set(available()) if group == "strategy" else set())
        if group == "hydra/launcher":
            choices.add("basic")
        if not choices:
            continue  # study: only where ./conf/study/ holds some
        shown = [f"{c} (default)" if c == defaults.get(group) else c for c in sorted(choices)]
        lines.append(f"  {group + ':':<16}{', '.join(shown)}")
    return "\n".join(lines)


def register_resolvers() -> None:
    """The ``${pocketbench.help_groups:}`` interpolation used by ``conf/hydra/help/pocketbench.yaml``."""
    if not OmegaConf.has_resolver("pocketbench.help_groups"):
        OmegaConf.register_new_resolver("pocketbench.help_groups", help_groups)


def check_overrides(argv: list[str]) -> None:
    """Fail fast, in one line, on ``+strategy=NAME[,NAME...]`` naming an unknown strategy."""
    names = None
    for arg in argv:
        key, sep, value = arg.lstrip("+~").partition("=")
        if not sep or key != "strategy":
            continue
        names = names or strategy_names()
        for name in value.split(","):
            if name and name not in names:
                raise StrategyError(unknown_name_message("strategy", name, names))


def split_args(argv: list[str]) -> tuple[bool, list[str], list[str]] | None:
    """(multirun, job overrides, hydra overrides) of a command line; None when it holds other flags."""
    multirun, job, hyd = False, [], []
    for arg in argv:
        if arg in ("-m", "--multirun"):
            multirun = True
        elif arg.startswith("-"):
            return None  # --help, --cfg, --config-dir, ...: Hydra's business
        else:
            key = arg.lstrip("+~").split("=", 1)[0]
            (hyd if key == "hydra" or key.startswith(("hydra.", "hydra/")) else job).append(arg)
    return multirun, job, hyd


def _value(args: list[str], key: str) -> str | None:
    found = None
    for arg in args:
        k, sep, v = arg.lstrip("+").partition("=")
        if sep and k == key:
            found = v
    return found


def check_output_dir(path: str, key: str) -> None:
    """One line unless ``path`` is, or can be created as, a writable directory."""
    text = path.split("${", 1)[0]  # interpolations (${now:...}) are resolved later; check what is fixed
    target = Path(text or ".").expanduser()
    target = target if target.is_absolute() else Path.cwd() / target
    probe = target
    while not probe.exists():
        if probe.parent == probe:
            break
        probe = probe.parent
    if probe.exists() and not probe.is_dir():
        raise ConfigError(f"{key}: expected a directory, found the file {probe}")
    try:  # a real attempt: permission bits say nothing for root, nor for a read-only mount
        tempfile.TemporaryDirectory(dir=probe, prefix=".pocketbench-").cleanup()
    except OSError as exc:
        raise ConfigError(
            f"{key}: expected a writable directory, found {probe} not writable ({exc.strerror or exc}; for {target})"
        ) from None


def check_output_dirs(multirun: bool, job: list[str], hyd: list[str]) -> None:
    out_dir = _value(job, "out_dir")
    if out_dir and out_dir != "null" and "," not in out_dir:
        check_output_dir(out_dir, "out_dir")
    key = "hydra.sweep.dir" if multirun else "hydra.run.dir"
    check_output_dir(_value(hyd, key) or ("multirun" if multirun else "outputs"), key)


def composition_error(exc: Exception, overrides: list[str]) -> str:
    """Hydra's multi-line composition failure as our one line: key, expected, found.

    Typed where Hydra and OmegaConf offer it: ``MissingConfigException`` names the missing group
    option, an OmegaConf error carries ``full_key`` and ``object_type``. What has only its wording
    to go by depends on hydra-core 1.3 / omegaconf 2.3 messages: a ``+`` on a key that exists (Hydra
    raises a bare ``ConfigCompositionException``), the config file a typed key failed in (``In 'X'``),
    and the value and target type of a failed conversion (one ``ValidationError`` for every kind).
    """
    from hydra.errors import MissingConfigException
    from omegaconf.errors import ConfigAttributeError, ConfigKeyError, OmegaConfBaseException

    if isinstance(exc, MissingConfigException) and exc.missing_cfg_file and "/" in exc.missing_cfg_file:
        group, name = exc.missing_cfg_file.rsplit("/", 1)
        names = sorted(exc.options or group_files(group))
        return unknown_name_message(group, name, names)
    appended = re.search(r"Could not append to config\. An item is already at '([^']+)'", str(exc))
    if appended:  # +KEY=VALUE on an existing KEY
        return _append_error(appended[1], overrides)
    cause = exc.__cause__ or exc.__context__
    cause = cause if isinstance(cause, OmegaConfBaseException) else None
    text = str(exc).strip()
    if cause is None:
        return text.splitlines()[0]
    key = getattr(cause, "full_key", None) or ""
    first = str(cause).splitlines()[0]
    owner = getattr(cause, "object_type", None)
    if isinstance(cause, (ConfigKeyError, ConfigAttributeError)):
        if owner is not None and dataclasses.is_dataclass(owner):  # a typed schema's key
            where = re.match(r"In '([^']+)'", text)
            return (f"{where[1]}: " if where else "") + describe_error(cause)
        bad = next((o for o in overrides if o.lstrip("+~").split("=", 1)[0] == key), None)
        parent = key.rsplit(".", 1)[0] if "." in key else ""
        known = _known_keys(parent, [o for o in overrides if o is not bad])
        return (f"unknown setting '{key}'; {parent or 'the config'} has: {known}; "
                f"add a new key with +{bad.lstrip('+~') if bad else key + '=VALUE'}")
    conv = re.match(r"Value '(.*?)' (?:of type '\w+' )?could not be converted to (\w+)", first) or re.match(
        r"Value '(.*?)' is not a valid (bool)", first)
    if conv:
        kind = {"Integer": "an integer", "Float": "a number", "Boolean": "true or false", "bool": "true or false"}
        what = expected(key) or kind.get(conv[2], conv[2])
        named = _strategy_param(key, overrides)
        return f"{named or key}: expected {what}, found {conv[1]!r}"
    return f"{key}: {first[:1].lower()}{first[1:]}" if key else first


def _append_error(key: str, overrides: list[str]) -> str:
    """``+KEY=VALUE`` where KEY is already a setting: the error of ``KEY=VALUE``, or how to write it."""
    from hydra.errors import HydraException
    from omegaconf.errors import OmegaConfBaseException

    added = next((o for o in overrides if o.startswith(f"+{key}=")), None)
    if added is None:
        return f"{key}: expected KEY=VALUE without '+' (the setting exists), found +{key}"
    fixed = [added[1:] if o is added else o for o in overrides]
    try:
        compose(fixed)
    except (HydraException, OmegaConfBaseException) as exc:
        return composition_error(exc, fixed)
    return f"{key}: expected {added[1:]} without '+' (the setting exists), found {added}"


def _strategy_param(key: str, overrides: list[str]) -> str | None:
    """``strategy 'NAME' parameter X`` for ``strategy.params.X``, as the strategy's own checks say it."""
    if not key.startswith("strategy.params."):
        return None
    name = _value(overrides, "strategy")
    return f"strategy '{name}' parameter {key.removeprefix('strategy.params.')}" if name else None


def _known_keys(parent: str, overrides: list[str]) -> str:
    try:
        from omegaconf import OmegaConf

        node = OmegaConf.select(compose(overrides), parent) if parent else compose(overrides)
        return ", ".join(sorted(node)) if node else "(no keys)"
    except Exception:  # the rest of the command line does not compose either: the name is enough
        return "(unknown)"


def precheck(argv: list[str]) -> Built | None:
    """Everything that can be refused before Hydra runs anything: one ``BenchError`` line.

    Returns the run a single-run command line builds (``bench.cli.validate.Built``), for ``bench.run.lifecycle``
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
            job = [o.input_line for o in parsed if not o.is_sweep_override()]
        cfg = compose(job)
    except (HydraException, OmegaConfBaseException) as exc:
        raise ConfigError(composition_error(exc, job)) from None
    if multirun:
        shared_refusal(job, swept, hyd)
        return None  # each job is validated where it runs (our sweeper, bench.run.lifecycle) and recorded if bad
    from bench.cli.validate import validate
    from bench.run.lifecycle import resolve_device

    built = validate(cfg)
    resolve_device(built.config.device)  # a single run runs here: this machine must have the device
    return built


def check_study(job: list[str]) -> None:
    """``+study=NAME`` names a study file that holds a study: one line if not (Hydra's answers run to pages)."""
    name = _value(job, "study")
    if name is not None:
        from bench.sweep.study import load

        load(name)  # the file, its YAML, its sweeps and their overrides


def shared_refusal(fixed: list[str], job: list[str], hyd: list[str]) -> None:
    """Refuse a sweep whose every job is refused for one and the same reason (a bad setting the
    sweep does not vary, ``threads=0 seed=0,1``): one line before any run dir, rather than a dir
    and a ``failed`` record per job. Jobs refused for different reasons still make a sweep that
    records each (``seed=abc,-3``). Only the first job is checked unless it is refused. ``fixed``:
    the command line less its sweeps, ``job`` with them, ``hyd`` its ``hydra.*`` overrides."""
    from hydra.errors import HydraException
    from omegaconf.errors import OmegaConfBaseException

    from bench.cli.validate import validate
    from bench.sweep.plan import planned

    def refusal(overrides: list[str]) -> str | None:
        task = [o for o in overrides if not o.lstrip("+~").startswith("hydra")]
        try:
            validate(compose(task))
        except (HydraException, OmegaConfBaseException) as exc:
            return composition_error(exc, task)
        except BenchError as exc:
            return str(exc)
        return None

    try:
        jobs = planned(compose([*fixed, *hyd], hydra=True), job) or [[]]
    except (HydraException, OmegaConfBaseException, ValueError):
        return  # a sweep syntax of another sweeper's: its jobs are checked where they run
    first = refusal(jobs[0])
    if first is not None and all(refusal(j) == first for j in jobs[1:]):
        raise ConfigError(first if len(jobs) == 1 else f"{first} (in all {len(jobs)} jobs of the sweep)")


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
    """One finished sweep run into the sweep's job record, and the sweep progress line."""
    from bench.sweep.plan import job_name
    from bench.sweep.summary import record_job

    job = {"num": hc.job.num, "name": job_name(list(hc.overrides.task)), "status": status, "dir": str(out_dir),
           "metrics": dict(metrics), "wall_s": wall_s}  # fmt: skip
    print(record_job(hc.sweep.dir, job), file=sys.stderr, flush=True)


# the schemas bench/conf/*.yaml build on, and a strategy/NAME entry for each plugin that ships no YAML,
# before Hydra composes anything; here, so launcher workers (joblib, submitit) that import this module see them
register_configs()
# what precheck built for the single run Hydra is about to start (bench.run.lifecycle checks it is the same config)
_PRECHECKED: list[Built] = []


def main() -> int:
    try:
        check_overrides(sys.argv[1:])
        built = precheck(sys.argv[1:])
    except BenchError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_CONFIG
    _PRECHECKED[:] = [built] if built is not None else []
    register_resolvers()
    _hydra_main()
    return 0


__all__ = ["CONF_DIR", "check_overrides", "compose", "main", "precheck"]
