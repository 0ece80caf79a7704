"""Typed settings, one rule each: the range or choice lives on the dataclass field that holds the value.

A field declared with ``setting(default, ...)`` carries its rule (``Rule``) in the field's metadata;
the dataclass's ``__post_init__`` calls ``check_rules(self, "prefix.")`` and a bad value raises one
``ConfigError`` line naming the key, what was expected and what was found. The same rule words the
answer to a value Hydra cannot even convert (``seed=abc``), through ``expected``.

A leaf module: it imports nothing from the project beyond ``bench.errors`` (itself a leaf), so the
config classes of the SLAM backend, the datasets and the run can all use it without import circles.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import re
import types
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Any, TypeVar

from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import ConfigAttributeError, ConfigKeyError, OmegaConfBaseException

from bench.errors import ConfigError

T = TypeVar("T")
SEED_MAX = 2**32 - 1  # numpy's seed range
_RULE = "pocketbench.rule"  # the metadata key a field's Rule sits under


@dataclasses.dataclass(frozen=True)
class Rule:
    """One setting's kind (int, float, bool, str, path, seq), range, choices and whether null is allowed."""

    kind: str
    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False  # lo itself excluded
    hi_open: bool = False  # hi itself excluded
    choices: tuple[str, ...] | None = None
    nullable: bool = False
    pattern: str | None = None  # regex a str must match (device)
    hint: str = ""  # what the value must be, in words, where the range alone would not say it
    also: tuple[float, ...] = ()  # values accepted outside the range (0 = off)

    def expected(self) -> str:
        if self.hint:
            text = self.hint
        elif self.choices:
            text = "one of " + ", ".join(self.choices)
        else:
            text = {
                "int": "an integer",
                "float": "a number",
                "bool": "true or false",
                "str": "a string",
                "path": "a path to a file",
                "seq": "a sequence name",
            }[self.kind]
            if self.lo is not None and self.hi is not None:
                text += (
                    f" in {'(' if self.lo_open else '['}{_fmt(self.lo)}, {_fmt(self.hi)}{')' if self.hi_open else ']'}"
                )
            elif self.lo is not None:
                text += f" {'>' if self.lo_open else '>='} {_fmt(self.lo)}"
            elif self.hi is not None:
                text += f" {'<' if self.hi_open else '<='} {_fmt(self.hi)}"
            if self.also:
                text = " or ".join(_fmt(a) for a in self.also) + " (off) or " + text
        return text + (" or null" if self.nullable else "")

    def check(self, key: str, value: Any) -> None:
        """One-line ``ConfigError`` unless ``value`` fits (ints are accepted as floats)."""
        if value is None:
            if self.nullable:
                return
            raise ConfigError(f"{key}: expected {self.expected()}, found null")
        ok = {
            "int": lambda v: isinstance(v, int) and not isinstance(v, bool),
            "float": lambda v: isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v),
            "bool": lambda v: isinstance(v, bool),
            "str": lambda v: isinstance(v, str) and v.strip() != "",
            "path": lambda v: isinstance(v, str) and v.strip() != "",
            "seq": lambda v: isinstance(v, (str, int)) and not isinstance(v, bool) and str(v).strip() != "",
        }[self.kind](value)
        if ok and self.kind in ("int", "float") and value not in self.also:
            ok = not (self.lo is not None and (value < self.lo or (self.lo_open and value == self.lo)))
            ok = ok and not (self.hi is not None and (value > self.hi or (self.hi_open and value == self.hi)))
        ok = ok and (self.choices is None or value in self.choices)
        ok = ok and (self.pattern is None or re.fullmatch(self.pattern, value) is not None)
        if not ok and self.kind == "float" and isinstance(value, float) and not math.isfinite(value):
            raise ConfigError(f"{key}: expected a finite number ({self.expected()}), found {value!r}")
        if not ok:
            raise ConfigError(f"{key}: expected {self.expected()}, found {value!r}")
        if self.kind == "path" and not Path(value).expanduser().is_file():
            raise ConfigError(f"{key}: expected an existing file, found no file at {Path(value).expanduser()}")


# a name that is one path component: no separator, not . or .. (sweep names: multirun/<name>)
NAME_PATTERN = r"(?!\.\.?$)[^/\\\x00]+"
NAME_HINT = "a name (one folder: no '/', not '.' or '..')"


def check_folder_name(key: str, value: Any) -> None:
    """One ``ConfigError`` line unless ``value`` is a name that stays one folder (``NAME_PATTERN``)."""
    Rule("str", pattern=NAME_PATTERN, hint=NAME_HINT).check(key, value)


def _fmt(x: float) -> str:
    return str(int(x)) if float(x).is_integer() and abs(x) < 1e15 else f"{x:g}"


def setting(default: Any, kind: str, **rule: Any) -> Any:
    """A dataclass field with its default and its rule: ``seed: int = setting(0, "int", lo=0, hi=SEED_MAX)``."""
    return dataclasses.field(default=default, metadata={_RULE: Rule(kind, **rule)})


def rule_of(cls: type, name: str) -> Rule | None:
    """The rule of field ``name`` of dataclass ``cls``; None if it has none.

    Looked up along the MRO: a subclass that only changes a default (``downscale: int = 2``) redeclares
    the field without metadata, and the rule its base declared still holds.
    """
    for klass in cls.__mro__:
        field = getattr(klass, "__dataclass_fields__", {}).get(name)
        if field is not None and _RULE in field.metadata:
            return field.metadata[_RULE]
    return None


def check_rules(obj: Any, prefix: str, cls: type | None = None) -> None:
    """Check every field that has a rule; the key is ``prefix + name``.

    ``obj`` a dataclass instance, or a mapping of its values as given (then ``cls`` names the class).
    """
    cls = cls or type(obj)
    values = obj if isinstance(obj, Mapping) else {f.name: getattr(obj, f.name) for f in dataclasses.fields(obj)}
    for name, value in values.items():
        rule = rule_of(cls, name)
        if rule is not None:
            rule.check(prefix + name, value)


def type_name(tp: Any) -> str:
    """An annotation in the words of an error message (``int | None`` -> ``an integer or null``)."""
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        return " or ".join(type_name(a) for a in typing.get_args(tp))
    if tp is type(None):
        return "null"
    if origin is dict or tp is dict:
        args = typing.get_args(tp)
        return f"a mapping of {type_name(args[1])}" if args else "a mapping"
    return {bool: "true or false", int: "an integer", float: "a number", str: "a string"}.get(tp, str(tp))


def expected(cls: type, dotted: str) -> str | None:
    """What the setting ``dotted`` under dataclass ``cls`` takes: its rule, else its annotation's type."""
    name, _, rest = dotted.partition(".")
    if not dataclasses.is_dataclass(cls) or name not in {f.name for f in dataclasses.fields(cls)}:
        return None
    try:
        tp = typing.get_type_hints(cls).get(name)
    except Exception:  # a plugin's annotation that cannot be resolved
        return None
    if rest:
        return expected(tp, rest) if isinstance(tp, type) else None
    rule = rule_of(cls, name)
    return rule.expected() if rule is not None else None if tp is None else type_name(tp)


def _type_ok(value: Any, tp: Any) -> bool:
    """Whether ``value`` fits the annotation ``tp`` as a config value would (no coercion but int->float)."""
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        return any(_type_ok(value, arg) for arg in typing.get_args(tp))
    if tp is type(None):
        return value is None
    if tp is bool:
        return isinstance(value, bool)
    if tp is int:
        return isinstance(value, int) and not isinstance(value, bool)
    if tp is float:
        return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    if tp is str:
        return isinstance(value, str)
    if origin in (dict, Mapping) or tp is dict:
        args = typing.get_args(tp)
        return isinstance(value, Mapping) and (not args or all(_type_ok(v, args[1]) for v in value.values()))
    if origin in (list, tuple) or tp in (list, tuple):
        return isinstance(value, (list, tuple))
    return True  # Any, or an annotation this checker does not know: the class's own checks decide


def check_types(prefix: str, cls: type, values: Mapping[str, Any]) -> None:
    """Wrong types of ``values`` (a plain mapping meant for the dataclass ``cls``), one line: ``prefix + name``."""
    try:
        hints = typing.get_type_hints(cls)
    except Exception:  # a plugin's annotation that cannot be resolved: its own checks decide
        hints = {}
    for name, value in values.items():
        tp = hints.get(name, Any)
        if not _type_ok(value, tp):
            raise ConfigError(f"{prefix}{name}: expected {type_name(tp)}, found {value!r}")


def did_you_mean(name: str, names: typing.Iterable[str]) -> str:
    """``; did you mean 'X'?`` for the known name closest to ``name``, or nothing when none is close."""
    close = difflib.get_close_matches(name, sorted(names), n=1, cutoff=0.6)
    return f"; did you mean '{close[0]}'?" if close else ""


def unknown_keys(prefix: str, cls: type, values: Mapping[str, Any], deep: bool = False) -> None:
    """``ConfigError`` naming the keys of ``values`` that the dataclass ``cls`` has no field for, with the
    closest known name; ``deep``: in the values of its dataclass-typed fields too (``slam.lrs``), as a ``+KEY``
    added under a typed group gets past composition."""
    fields = {f.name for f in dataclasses.fields(cls) if f.init}
    unknown = sorted(set(values) - fields)
    if unknown:
        raise ConfigError(
            f"{prefix} has no setting {', '.join(repr(u) for u in unknown)}; expected one of: "
            f"{', '.join(sorted(fields)) or '(none)'}{did_you_mean(unknown[0], fields)}"
        )
    if not deep:
        return
    try:
        hints = typing.get_type_hints(cls)
    except (NameError, TypeError):  # an annotation this module cannot resolve: the fields' own checks remain
        return
    for name, value in values.items():
        sub = _dataclass_in(hints.get(name))
        if sub is not None and isinstance(value, Mapping):
            unknown_keys(f"{prefix}.{name}", sub, value, deep=True)


def _dataclass_in(hint: Any) -> type | None:
    """The dataclass a field's annotation names (``X`` or ``X | None``), else None."""
    if isinstance(hint, type) and dataclasses.is_dataclass(hint):
        return hint
    return next((a for a in typing.get_args(hint) if isinstance(a, type) and dataclasses.is_dataclass(a)), None)


def describe_error(exc: OmegaConfBaseException, prefix: str = "") -> str:
    """OmegaConf's multi-line message as one line that names the setting, in "expected ... found" form.

    ``prefix`` names where the converted node sits in the run config (``slam.lrs``).
    """
    key = ".".join(filter(None, (prefix, getattr(exc, "full_key", None) or "")))
    owner = getattr(exc, "object_type", None)
    unknown = isinstance(exc, (ConfigKeyError, ConfigAttributeError))
    if unknown and isinstance(owner, type) and dataclasses.is_dataclass(owner):  # object_type: a class or None
        known = ", ".join(f.name for f in dataclasses.fields(owner))
        where = key.rpartition(".")[0] or owner.__name__
        return f"{where}: expected a setting among {known}, found {key.rpartition('.')[2]}"
    first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    # OmegaConf raises one ValidationError class for every failed conversion; its wording is all that
    # tells the value and the target type apart (omegaconf 2.3)
    converted = re.match(r"Value '(.*)' of type '.*' could not be converted to (\w+)", first)
    text = f"expected {converted[2].lower()}, found '{converted[1]}'" if converted else first[0].lower() + first[1:]
    return f"{key}: {text}" if key else text


def as_config(cls: type[T], cfg: T | Mapping[str, Any], prefix: str = "") -> T:
    """``cfg`` as an instance of the dataclass ``cls``: an instance passes, a mapping is checked against it.

    The one conversion path for callers that hand a plain mapping to a typed API (tests, plugins);
    an unknown key or a wrongly typed value is a ``ConfigError``; the class's own rules run as it is built.
    """
    if isinstance(cfg, cls):
        return cfg
    try:
        node = OmegaConf.merge(OmegaConf.structured(cls), cfg if cfg is not None else {})
        return OmegaConf.to_object(node)  # type: ignore[return-value]
    except OmegaConfBaseException as exc:
        raise ConfigError(describe_error(exc, prefix)) from None


def plain(obj: Any) -> Any:
    """A dataclass tree or a ``DictConfig`` as plain, resolved containers (for a config hash, json, checks).

    A broken interpolation is a ``ConfigError``.
    """
    try:
        if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
            return OmegaConf.to_container(OmegaConf.structured(obj), resolve=True)
        if isinstance(obj, DictConfig):
            return OmegaConf.to_container(obj, resolve=True)
    except OmegaConfBaseException as exc:
        raise ConfigError(f"config cannot be resolved: {str(exc).splitlines()[0]}") from None
    return obj
