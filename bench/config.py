"""The typed configuration boundary: every setting's schema and default, registered with Hydra.

Each default is written once, in a dataclass beside the code it configures (``SlamConfig`` in
``bench/slam/system.py``, the dataset configs in ``bench/datasets/``, strategy hyperparameters in
``strategies/``); the run-level settings are below. The YAML files under ``bench/conf/`` pick a schema
from the ``ConfigStore`` (``schema/dataset/NAME``, ``schema/strategy/NAME``) and only override it,
so a mistyped key or a wrongly typed value fails at composition, not deep inside a run.
``bench.run`` converts the composed config once (``to_run_config``) and hands dataclasses down.
``register_configs`` runs when ``bench.cli`` is imported, before Hydra composes anything.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass, field, fields, is_dataclass
from typing import Any, TypeVar

from hydra.core.config_store import ConfigStore
from omegaconf import MISSING, DictConfig, OmegaConf
from omegaconf.errors import ConfigAttributeError, ConfigKeyError, OmegaConfBaseException

from bench.checkpoint import CheckpointConfig
from bench.conf import CONF_DIR
from bench.errors import ConfigError, StrategyError
from bench.slam.system import SlamConfig
from bench.strategy import PruneConfig

T = TypeVar("T")


@dataclass
class MemoryConfig:
    torch_live: bool = True  # track peak bytes of live torch tensors on CPU (see bench/measure.py)


@dataclass
class EvalConfig:
    every: int = 1  # evaluate PSNR/SSIM/LPIPS on every N-th tracked frame
    ate_align: str = "se3"  # se3 | sim3 | none
    max_diff_s: float = 0.01  # estimate <-> ground-truth timestamp association for ATE/RPE
    rpe: bool = False
    lpips: bool = True  # computed only where AlexNet weights exist locally (see README)
    lpips_weights: str | None = None


@dataclass
class VizConfig:
    """Pictures of what pruning removed (``bench/viz.py``); they cost renders inside the SLAM loop."""

    pruning: bool = False  # pruned_kfNNN.png (+ .npz for reports) at the keyframes below
    every: int = 5  # keyframes 5, 10, 15, ... (keyframe 0 has nothing to prune)


@dataclass
class StrategyConfig:
    """``+strategy=NAME``: the plugin's name and its hyperparameters (its own dataclass once registered)."""

    name: str = MISSING
    params: Any = field(default_factory=dict)


@dataclass
class RunConfig:
    """Everything one run reads; ``conf/config.yaml`` picks the groups and overrides nothing else."""

    dataset: Any = MISSING  # a dataset config dataclass (bench/datasets/), or a plugin's plain dict
    slam: SlamConfig = field(default_factory=SlamConfig)
    strategy: StrategyConfig | None = None  # None: no pruning
    prune: PruneConfig = field(default_factory=PruneConfig)  # bench/strategy.py; +experiment=released changes it
    memory: MemoryConfig = field(default_factory=MemoryConfig)
    eval: EvalConfig = field(default_factory=EvalConfig)
    viz: VizConfig = field(default_factory=VizConfig)
    # the map as a 3DGS PLY (bench/export.py): "final" writes map.ply at the end; "every_keyframe" also
    # keeps maps/kf_NNN.npz after each keyframe (python -m bench.export RUN_DIR --keyframe K)
    save_maps: str = "final"
    seq: str | None = None  # always a string: seq=00 and seq=10 behave alike; None = the dataset's default
    seed: int = 0  # varies what a repeat should vary, nothing else (README: "Comparisons that hold")
    device: str = "auto"  # auto | cpu | cuda[:N]
    # CPU threads (torch, numba, OpenCV): fixed, because sums split per thread round differently
    threads: int | None = 2
    # strict: same config + seed = same numbers; fast: torch may pick non-deterministic kernels
    determinism: str = "strict"
    max_frames: int | None = None  # cut the sequence short (smoke tests)
    warmup_frames: int = 1  # frames excluded from FPS (the first frame only initialises the map)
    progress: bool = True  # progress bar with frame i/N, Gaussian count, fps
    resume: bool = True  # skip a finished run of the same config, code and inputs; continue an interrupted one
    checkpoint: CheckpointConfig = field(default_factory=CheckpointConfig)  # bench/checkpoint.py
    out_dir: str | None = None  # None = Hydra's output dir
    sweep_name: str = "default"  # multirun/<sweep_name>


def describe_error(exc: OmegaConfBaseException) -> str:
    """OmegaConf's multi-line message as one line that names the setting, in "expected ... found" form."""
    key = getattr(exc, "full_key", None) or ""
    owner = getattr(exc, "object_type", None)
    if isinstance(exc, (ConfigKeyError, ConfigAttributeError)) and owner is not None and is_dataclass(owner):
        known = ", ".join(f.name for f in fields(owner))
        where = key.rpartition(".")[0] or owner.__name__
        return f"{where}: expected a setting among {known}, found {key.rpartition('.')[2]}"
    first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    converted = re.match(r"Value '(.*)' of type '.*' could not be converted to (\w+)", first)
    text = f"expected {converted[2].lower()}, found '{converted[1]}'" if converted else first[0].lower() + first[1:]
    return f"{key}: {text}" if key else text


def as_config(cls: type[T], cfg: T | Mapping[str, Any]) -> T:
    """``cfg`` as an instance of the dataclass ``cls``: an instance passes, a mapping is checked against it.

    The one conversion path for callers that hand a plain mapping to a typed API (tests, plugins);
    an unknown key or a wrongly typed value is a ``ConfigError``.
    """
    if isinstance(cfg, cls):
        return cfg
    try:
        node = OmegaConf.merge(OmegaConf.structured(cls), cfg if cfg is not None else {})
        return OmegaConf.to_object(node)  # type: ignore[return-value]
    except OmegaConfBaseException as exc:
        raise ConfigError(describe_error(exc)) from None


def to_run_config(cfg: DictConfig | RunConfig) -> RunConfig:
    """The composed config as dataclasses: the single ``OmegaConf.to_object`` of a run."""
    return as_config(RunConfig, cfg)


def plain(obj: Any) -> Any:
    """A dataclass tree (or plain dict) as plain Python containers, e.g. for a config hash or json."""
    if is_dataclass(obj) and not isinstance(obj, type):
        return OmegaConf.to_container(OmegaConf.structured(obj), resolve=True)
    if isinstance(obj, DictConfig):
        return OmegaConf.to_container(obj, resolve=True)
    return obj


def register_strategy(name: str, cls: type) -> None:
    """Make ``cls`` the schema of ``strategy.params`` for ``+strategy=NAME`` (``schema/strategy/NAME``)."""
    node = OmegaConf.structured(StrategyConfig(name=name))
    node.params = OmegaConf.structured(cls)
    ConfigStore.instance().store(group="schema/strategy", name=name, node=node)


def dataset_schemas() -> dict[str, type]:
    """The built-in datasets' config dataclasses by name."""
    from bench.datasets.euroc import EurocConfig
    from bench.datasets.kitti import KittiConfig
    from bench.datasets.synthetic import SyntheticConfig
    from bench.datasets.tum import TumConfig

    return {"synthetic": SyntheticConfig, "kitti": KittiConfig, "euroc": EurocConfig, "tum": TumConfig}


def register_configs() -> None:
    """Store the run schema, the built-in dataset schemas and the shipped strategies' schemas."""
    from bench import registry
    from bench.strategy import GROUP as STRATEGY_GROUP

    cs = ConfigStore.instance()
    cs.store(name="base_config", node=RunConfig)
    for name, cls in dataset_schemas().items():
        cs.store(group="schema/dataset", name=name, node=cls)
    for path in sorted((CONF_DIR / "strategy").glob("*.yaml")):
        try:
            cls = registry.load(STRATEGY_GROUP, "strategy", path.stem, StrategyError)
        except StrategyError:
            continue  # not installed: composing +strategy=NAME then fails with Hydra's own message
        register_strategy(path.stem, cls)
