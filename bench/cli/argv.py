"""The command line checked before Hydra takes it: unknown strategies, output dirs that cannot be written,
Hydra's composition failures and a study's shared refusals, each as one ``error:`` line."""

from __future__ import annotations

import dataclasses
import re
import tempfile
from pathlib import Path

from bench.cli.help import strategy_names
from bench.conf import group_files
from bench.config.plugins import unknown_name_message
from bench.config.settings import describe_error
from bench.errors import BenchError, ConfigError, StrategyError
from bench.run.config import compose, expected


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
    multirun = False
    job: list[str] = []
    hyd: list[str] = []
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
        if group == "strategy" and name in strategy_names():  # installed, but its import failed: say why
            from bench.slam.strategy import strategy_class

            try:
                strategy_class(name)
            except BenchError as failed:
                return str(failed)
        names = sorted(exc.options or group_files(group))
        return unknown_name_message(group, name, names)
    if isinstance(exc, AssertionError):  # OmegaConf 2.3 asserts on a.b=... where a is null (no +strategy)
        return _unset_group(overrides) or f"expected overrides that compose, found: {exc}"
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
        return (
            f"unknown setting '{key}'; {parent or 'the config'} has: {known}; "
            f"add a new key with +{bad.lstrip('+~') if bad else key + '=VALUE'}"
        )
    conv = re.match(r"Value '(.*?)' (?:of type '\w+' )?could not be converted to (\w+)", first) or re.match(
        r"Value '(.*?)' is not a valid (bool)", first
    )
    if conv:
        kind = {"Integer": "an integer", "Float": "a number", "Boolean": "true or false", "bool": "true or false"}
        what = expected(key) or kind.get(conv[2], conv[2])
        named = _strategy_param(key, overrides)
        return f"{named or key}: expected {what}, found {conv[1]!r}"
    return f"{key}: {first[:1].lower()}{first[1:]}" if key else first


def _unset_group(overrides: list[str]) -> str | None:
    """``strategy.params.X=...`` with no strategy chosen: the key, and the group to choose first."""
    plain_keys = [o for o in overrides if "." not in o.lstrip("+~").split("=", 1)[0]]
    try:
        base = compose(plain_keys)
    except Exception:  # the rest does not compose either: its own error comes once this one is fixed
        return None
    for o in overrides:
        key = o.lstrip("+~").split("=", 1)[0]
        group = key.split(".", 1)[0]
        if "." in key and group in base and base[group] is None:
            return f"{key}: expected +{group}=NAME first ({group} is not chosen, so it has no settings), found {o}"
    return None


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

    from bench.run.validate import validate
    from bench.sweep.plan import planned

    def refusal(overrides: list[str]) -> str | None:
        task = [o for o in overrides if not o.lstrip("+~").startswith("hydra")]
        try:
            validate(compose(task))
        except (HydraException, OmegaConfBaseException, AssertionError) as exc:
            return composition_error(exc, task)
        except BenchError as exc:
            return str(exc)
        return None

    try:
        jobs = planned(compose([*fixed, *hyd], hydra=True), job)
    except (HydraException, OmegaConfBaseException, ValueError):
        return  # a sweep syntax of another sweeper's: its jobs are checked where they run
    if not jobs:  # seed=range(0,0): Hydra would run nothing, silently
        swept = [o for o in job if o not in fixed]
        raise ConfigError(f"sweep: expected at least one job, found none ({' '.join(swept) or 'no job'} is empty)")
    first = refusal(jobs[0])
    if first is not None and all(refusal(j) == first for j in jobs[1:]):
        raise ConfigError(first if len(jobs) == 1 else f"{first} (in all {len(jobs)} jobs of the sweep)")
