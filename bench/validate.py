"""Every setting checked before any work: types, ranges and choices in one place.

Why a table instead of checks where values are used: a value checked only where it is used
(``eval.ate_align`` after the SLAM loop, ``prune.keep_ratio`` inside a strategy) lets a bad
setting cost a whole run, or worse, become a result (a keep ratio of 1.5 ending ``ok``). So
``validate(cfg)`` runs first, in the CLI before Hydra creates a run dir and again at the top of
``bench.run.run``, and raises the first problem as one ``ConfigError`` line naming the key, what
was expected and what was found. Types of the SLAM backend and of strategy hyperparameters come
from their dataclass annotations; their ranges live with them (``SlamConfig.__post_init__``, a
strategy's ``__post_init__``), which this module calls by building both.
"""

from __future__ import annotations

import dataclasses
import math
import re
import types
import typing
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from bench.errors import BenchError, ConfigError

ALIGNMENTS = ("se3", "sim3", "none")
_SEED_MAX = 2**32 - 1  # numpy's seed range


@dataclasses.dataclass(frozen=True)
class Spec:
    """One setting: its kind (int, float, bool, str, path), range, choices and whether null is allowed."""

    kind: str
    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False  # lo itself excluded
    choices: tuple[str, ...] | None = None
    nullable: bool = False
    pattern: str | None = None  # regex a str must match (device)
    hint: str = ""  # what null means, shown in the message

    def expected(self) -> str:
        if self.choices:
            text = "one of " + ", ".join(self.choices)
        elif self.pattern:
            text = self.hint
        else:
            text = {"int": "an integer", "float": "a number", "bool": "true or false", "str": "a string",
                    "path": "a path to a file", "seq": "a sequence name"}[self.kind]
            if self.lo is not None and self.hi is not None:
                text += f" in {'(' if self.lo_open else '['}{_fmt(self.lo)}, {_fmt(self.hi)}]"
            elif self.lo is not None:
                text += f" {'>' if self.lo_open else '>='} {_fmt(self.lo)}"
        return text + (" or null" if self.nullable else "")


def _fmt(x: float) -> str:
    return str(int(x)) if float(x).is_integer() and abs(x) < 1e15 else f"{x:g}"


# The harness's own settings (conf/config.yaml). Strategy, slam and dataset groups follow below.
SETTINGS: dict[str, Spec] = {
    "seq": Spec("seq", nullable=True),
    "seed": Spec("int", 0, _SEED_MAX),
    "device": Spec("str", pattern=r"auto|cpu|cuda(:\d+)?", hint="auto, cpu or cuda[:N]"),
    "threads": Spec("int", 1, nullable=True),
    "determinism": Spec("str", choices=("strict", "fast")),  # bench/determinism.py:MODES
    "max_frames": Spec("int", 2, nullable=True),
    "warmup_frames": Spec("int", 0),
    "progress": Spec("bool"),
    "resume": Spec("bool"),
    "out_dir": Spec("str", nullable=True),
    "sweep_name": Spec("str"),
    "prune.keep_ratio": Spec("float", 0.0, 1.0, lo_open=True),
    # choices and the absolute target's count: bench.strategy.PruneConfig (built in _validate_prune)
    "prune.target": Spec("str"),
    "prune.n_target": Spec("int", 0, nullable=True),
    "prune.every": Spec("str"),
    "prune.grad_source": Spec("str"),
    "memory.torch_live": Spec("bool"),
    "eval.every": Spec("int", 1),
    "eval.ate_align": Spec("str", choices=ALIGNMENTS),
    "eval.max_diff_s": Spec("float", 0.0, lo_open=True),
    "eval.rpe": Spec("bool"),
    "eval.lpips": Spec("bool"),
    "eval.lpips_weights": Spec("path", nullable=True),
    "save_maps": Spec("str", choices=("final", "every_keyframe")),  # bench/export.py:SAVE_MAPS
    "viz.pruning": Spec("bool"),
    "viz.every": Spec("int", 1),
    "checkpoint.every": Spec("int", 0),  # bench/checkpoint.py:CheckpointConfig
    "checkpoint.keep": Spec("int", 1, 2),
}
# Groups whose keys are all listed above: an unknown key there is a typo (``+eval.evry=2``).
CLOSED_GROUPS = ("prune", "memory", "eval", "viz", "checkpoint")
OPEN_TOP = {"dataset", "slam", "strategy", *CLOSED_GROUPS}  # checked by their own specs

# Dataset knobs shared by the built-in loaders; a third-party dataset's other keys pass through.
DATASET_SETTINGS: dict[str, Spec] = {
    "name": Spec("str"),
    "root": Spec("str", nullable=True),
    "seq": Spec("seq", nullable=True),
    "default_seq": Spec("seq", nullable=True),
    "downscale": Spec("int", 1),
    "first": Spec("int", 0),
    "last": Spec("int", 0, nullable=True),
    "stride": Spec("int", 1),
    "max_depth_m": Spec("float", 0.0, lo_open=True, nullable=True),
    "gt_max_diff_s": Spec("float", 0.0, lo_open=True),
    "max_diff_s": Spec("float", 0.0, lo_open=True),
    "gt_missing": Spec("str", choices=("drop", "error")),
    "color": Spec("str", choices=("auto", "color", "gray")),
    "rectify_alpha": Spec("float", 0.0, 1.0),
    "depth_scale": Spec("float", 0.0, lo_open=True),
    "cache_dir": Spec("str", nullable=True),
    # synthetic
    "seed": Spec("int", 0, _SEED_MAX),
    "run_seed": Spec("int", 0, _SEED_MAX),
    "rgb_noise_std": Spec("float", 0.0),
    "depth_noise_rel": Spec("float", 0.0),
    "width": Spec("int", 16),
    "height": Spec("int", 16),
    "n_frames": Spec("int", 2),
    "speed_m_per_frame": Spec("float", 0.0, lo_open=True),
    "sway_m": Spec("float", 0.0),
    "fov_deg": Spec("float", 0.0, 180.0, lo_open=True),
    "supersample": Spec("int", 1),
    "fps_hz": Spec("float", 0.0, lo_open=True),
}


def check_value(key: str, value: Any, spec: Spec) -> Any:
    """``value`` if it fits ``spec`` (ints accepted as floats), else a one-line ``ConfigError``."""
    if value is None:
        if spec.nullable:
            return None
        raise ConfigError(f"{key}: expected {spec.expected()}, found null")
    ok = {
        "int": lambda v: isinstance(v, int) and not isinstance(v, bool),
        "float": lambda v: isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v),
        "bool": lambda v: isinstance(v, bool),
        "str": lambda v: isinstance(v, str) and v.strip() != "",
        "path": lambda v: isinstance(v, str) and v.strip() != "",
        "seq": lambda v: isinstance(v, (str, int)) and not isinstance(v, bool) and str(v).strip() != "",
    }[spec.kind](value)
    if ok and spec.kind in ("int", "float"):
        if spec.lo is not None and (value < spec.lo or (spec.lo_open and value == spec.lo)):
            ok = False
        if spec.hi is not None and value > spec.hi:
            ok = False
    if ok and spec.choices is not None:
        ok = value in spec.choices
    if ok and spec.pattern is not None:
        ok = re.fullmatch(spec.pattern, value) is not None
    if not ok:
        raise ConfigError(f"{key}: expected {spec.expected()}, found {value!r}")
    if spec.kind == "path":
        path = Path(value).expanduser()
        if not path.is_file():
            raise ConfigError(f"{key}: expected an existing file, found no file at {path}")
    return value


def _get(tree: Mapping[str, Any], dotted: str) -> tuple[bool, Any]:
    node: Any = tree
    for part in dotted.split("."):
        if not isinstance(node, Mapping) or part not in node:
            return False, None
        node = node[part]
    return True, node


# ---------------------------------------------------------------- dataclass-typed groups
def _type_ok(value: Any, tp: Any) -> bool:
    """Whether ``value`` fits the annotation ``tp`` as a config value would (no coercion but int->float)."""
    if tp is Any:
        return True
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
        if not isinstance(value, Mapping):
            return False
        args = typing.get_args(tp)
        return not args or all(_type_ok(v, args[1]) for v in value.values())
    if origin in (list, tuple) or tp in (list, tuple):
        return isinstance(value, (list, tuple))
    return True  # an annotation this checker does not know: the class's own checks decide


def _type_name(tp: Any) -> str:
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        names = [_type_name(a) for a in typing.get_args(tp)]
        return " or ".join(names)
    if tp is type(None):
        return "null"
    if origin is dict or tp is dict:
        args = typing.get_args(tp)
        return f"a mapping of {_type_name(args[1])}" if args else "a mapping"
    return {bool: "true or false", int: "an integer", float: "a number", str: "a string"}.get(tp, str(tp))


def check_fields(prefix: str, cls: type, values: Mapping[str, Any], sep: str = ".") -> None:
    """Unknown keys and wrong types of ``values`` against the dataclass ``cls``, one line each.

    A key is named ``prefix + sep + field`` (``slam.kf_every``, ``strategy 'mask' parameter gumbel_tau``).
    """
    try:
        hints = typing.get_type_hints(cls)
    except Exception:  # a plugin's annotation that cannot be resolved: its own checks decide
        hints = {}
    fields = {f.name for f in dataclasses.fields(cls) if f.init}
    unknown = sorted(set(values) - fields)
    if unknown:
        raise ConfigError(
            f"{prefix} has no setting {', '.join(repr(u) for u in unknown)}; expected one of: "
            f"{', '.join(sorted(fields)) or '(none)'}"
        )
    for name, value in values.items():
        tp = hints.get(name, Any)
        args = typing.get_args(tp)
        if typing.get_origin(tp) is dict and isinstance(value, Mapping) and len(args) == 2:
            for sub, item in value.items():  # name the entry, not the whole mapping
                if not _type_ok(item, args[1]):
                    raise ConfigError(f"{prefix}{sep}{name}.{sub}: expected {_type_name(args[1])}, found {item!r}")
        elif not _type_ok(value, tp):
            raise ConfigError(f"{prefix}{sep}{name}: expected {_type_name(tp)}, found {value!r}")


def _build(prefix: str, make: Callable[[], Any]) -> Any:
    """Run a constructor whose own checks raise; a stray TypeError/ValueError becomes one line."""
    try:
        return make()
    except BenchError:
        raise
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{prefix}: {str(exc).splitlines()[0]}") from None


# ---------------------------------------------------------------- the whole config
def plain(cfg: Any) -> dict[str, Any]:
    """The config as plain, resolved containers; a broken interpolation is a ``ConfigError``."""
    from omegaconf import DictConfig, OmegaConf
    from omegaconf.errors import OmegaConfBaseException

    if isinstance(cfg, DictConfig):
        try:
            return OmegaConf.to_container(cfg, resolve=True)  # type: ignore[return-value]
        except OmegaConfBaseException as exc:
            raise ConfigError(f"config cannot be resolved: {str(exc).splitlines()[0]}") from None
    if dataclasses.is_dataclass(cfg):
        return dataclasses.asdict(cfg)
    return dict(cfg)


def validate(cfg: Any) -> None:
    """Raise the first bad setting of the whole run config as one ``ConfigError`` line.

    Cheap by design (no dataset files are read, no SLAM state is built), so it can run before
    any work in every process: a sweep job that fails here is recorded ``failed`` in seconds.
    """
    tree = plain(cfg)
    for key, spec in SETTINGS.items():
        present, value = _get(tree, key)
        if present:
            check_value(key, value, spec)
    known_top = {k.split(".")[0] for k in SETTINGS} | OPEN_TOP
    unknown = sorted(k for k in tree if k not in known_top and k != "hydra")
    if unknown:
        raise ConfigError(f"unknown setting {', '.join(repr(u) for u in unknown)}; expected one of: "
                          f"{', '.join(sorted(known_top))}")
    for group in CLOSED_GROUPS:
        sub = tree.get(group)
        if sub is None:
            continue
        if not isinstance(sub, Mapping):
            raise ConfigError(f"{group}: expected a group of settings, found {sub!r}")
        known = sorted(k.split(".", 1)[1] for k in SETTINGS if k.startswith(group + "."))
        bad = sorted(set(sub) - set(known))
        if bad:
            raise ConfigError(f"{group} has no setting {', '.join(repr(b) for b in bad)}; expected one of: "
                              f"{', '.join(known)}")
    _validate_dataset(tree.get("dataset"))
    _validate_prune(tree.get("prune") or {})
    _validate_slam(tree)
    _validate_strategy(tree.get("strategy"))
    _validate_lpips(tree.get("eval") or {})


def expected(key: str) -> str | None:
    """What setting ``key`` (dotted) takes, in the words of its check; None if this module does not know."""
    if key in SETTINGS:
        return SETTINGS[key].expected()
    group, _, name = key.partition(".")
    if group == "dataset" and name in DATASET_SETTINGS:
        return DATASET_SETTINGS[name].expected()
    if group == "slam":
        from bench.slam.frontend import FlowPnpConfig
        from bench.slam.system import SlamConfig

        cls, name = (FlowPnpConfig, name.split(".", 1)[1]) if name.startswith("flow_pnp.") else (SlamConfig, name)
        tp = typing.get_type_hints(cls).get(name)
        return None if tp is None else _type_name(tp)
    return None


def _validate_dataset(ds: Any) -> None:
    if not isinstance(ds, Mapping) or not ds.get("name"):
        raise ConfigError(f"dataset: expected a dataset group with a name (dataset=synthetic|kitti|euroc|tum), "
                          f"found {ds!r}")
    for key, value in ds.items():
        spec = DATASET_SETTINGS.get(key)
        if spec is not None:
            check_value(f"dataset.{key}", value, spec)
    if isinstance(ds.get("last"), int) and ds.get("last") < ds.get("first", 0):
        raise ConfigError(f"dataset frame range: expected first <= last, found first={ds.get('first', 0)} "
                          f"last={ds['last']}")


def _validate_prune(prune: Mapping[str, Any]) -> None:
    from bench.strategy import PruneConfig

    _build("prune", lambda: PruneConfig(**prune))


def _validate_slam(tree: Mapping[str, Any]) -> None:
    from bench.slam.frontend import FlowPnpConfig
    from bench.slam.system import SlamConfig

    slam = tree.get("slam")
    if not isinstance(slam, Mapping):
        raise ConfigError(f"slam: expected a group of backend settings, found {slam!r}")
    slam = dict(slam)
    check_fields("slam.flow_pnp", FlowPnpConfig, slam.get("flow_pnp") or {})
    check_fields("slam", SlamConfig, slam)
    _build("slam", lambda: SlamConfig(**{**slam, "seed": tree.get("seed", 0)}))


def _validate_strategy(strategy: Any) -> None:
    if strategy is None:
        return
    from bench.strategy import load_strategy

    if not isinstance(strategy, Mapping) or not isinstance(strategy.get("name"), str):
        raise ConfigError(f"strategy: expected a group with a name (+strategy=NAME), found {strategy!r}")
    extra = sorted(set(strategy) - {"name", "params"})
    if extra:
        raise ConfigError(f"strategy has no setting {', '.join(repr(e) for e in extra)}; expected name and params")
    params = strategy.get("params") or {}
    if not isinstance(params, Mapping):
        raise ConfigError(f"strategy.params: expected a mapping of hyperparameters, found {params!r}")
    load_strategy(strategy["name"], dict(params))


def _validate_lpips(ev: Mapping[str, Any]) -> None:
    """A given weights file is loaded now: a broken one would otherwise fail after the whole run."""
    path = ev.get("lpips_weights")
    if not ev.get("lpips", True) or path is None:
        return
    from bench.metrics.lpips import LPIPS

    try:
        LPIPS.from_weights(path)
    except BenchError as exc:
        raise ConfigError(f"eval.lpips_weights: {exc}") from None
