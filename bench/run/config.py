"""The typed configuration boundary: every setting's schema and default, registered with Hydra.

Each default is written once, in a dataclass beside the code it configures (``SlamConfig`` in
``bench/slam/config.py``, the dataset configs in ``bench/datasets/``, strategy hyperparameters in
``strategies/``); the run-level settings are below. The YAML files under ``bench/conf/`` pick a schema
from the ``ConfigStore`` (``schema/dataset/NAME``, ``schema/strategy/NAME``) and only override it,
so a mistyped key or a wrongly typed value fails at composition, not deep inside a run. Ranges and
choices live on the same fields (``bench.config.settings.setting``) and are checked as each dataclass is built.
Dataset schemas are found through the dataset registry (``bench.datasets.schema``), not imported here.
``bench.run.validate.validate`` converts the composed config once (``to_run_config``) and hands dataclasses down.
``register_configs`` runs when ``bench.cli.entry`` is imported, before Hydra composes anything.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from hydra.core.config_store import ConfigStore
from omegaconf import MISSING, DictConfig, OmegaConf

from bench.conf import CONF_DIR, group_files
from bench.config import plugins as registry
from bench.config.settings import NAME_HINT, NAME_PATTERN, SEED_MAX, as_config, check_rules, setting
from bench.config.settings import expected as expected_in
from bench.datasets import GROUP as DATASET_GROUP
from bench.datasets import schema
from bench.errors import ConfigError, StrategyError
from bench.measure.memory import MALLOC_POLICIES
from bench.run.checkpoint import CheckpointConfig
from bench.run.export import SAVE_MAPS
from bench.slam.config import SlamConfig
from bench.slam.strategy import GROUP as STRATEGY_GROUP
from bench.slam.strategy import PruneConfig

ALIGNMENTS = ("se3", "sim3", "none")
PROTOCOLS = ("full", "splatam", "released")  # bench/metrics/protocol.py:PROTOCOLS
DETERMINISM = ("strict", "fast")  # bench/run/determinism.py:MODES


@dataclass
class MemoryConfig:
    torch_live: bool = True  # track peak bytes of live torch tensors on CPU (see bench/measure/memory.py)
    # how the process holds freed memory (bench/measure/memory.py:set_malloc_policy): retain = glibc keeps freed
    # blocks up to 32 MiB mapped for reuse (no page faults on every iteration's tensors; RSS then reads the heap's
    # high-water); system = glibc's own thresholds, as every run before it. Speed and RSS only: no result changes
    malloc: str = setting("retain", "str", choices=MALLOC_POLICIES)


@dataclass
class EvalConfig:
    every: int = setting(1, "int", lo=1)  # evaluate PSNR/SSIM/LPIPS on every N-th tracked frame
    # which pixels are scored (bench/metrics/protocol.py): full = the whole image (the default; the
    # numbers of every run before protocols); splatam = SplaTAM's valid-depth mask within the dataset's
    # eval_depth_near_m/eval_depth_far_m; released = the released Pocket-SLAM code's rendered silhouette > 0.5
    protocol: str = setting("full", "str", choices=PROTOCOLS)
    # where the image metrics are computed (float64 either way): run = the run's device (a CUDA run scores on
    # its GPU), cpu = the host (the only choice before it existed; on a CPU run the two are the same)
    device: str = setting("run", "str", choices=("run", "cpu"))
    ate_align: str = setting("se3", "str", choices=ALIGNMENTS)
    # estimate <-> ground-truth timestamp association for ATE/RPE
    max_diff_s: float = setting(0.01, "float", lo=0.0, lo_open=True)
    rpe: bool = False
    # computed only where AlexNet weights exist locally (docs/run-directory.md, "What is measured, exactly")
    lpips: bool = True
    lpips_weights: str | None = setting(None, "path", nullable=True)
    # milestones: after this many frames, the map as it is then is evaluated on the frames so far (ATE, and
    # PSNR/SSIM/LPIPS on every `every`-th frame); one milestones.csv row each, outside the SLAM time and the
    # memory windows. What a drive of that length would have scored, from one long run.
    at_frames: list[int] = field(default_factory=list)
    # the refinement's curve: after this many of the final refinement's iterations (slam.refine_iters), the
    # image metrics of the map as it is then; one refine_curve.csv row each, outside refine_s. Whether more
    # refinement would still pay, from one run, without touching it (the iterations and their draws are the same)
    at_refine_iters: list[int] = field(default_factory=list)

    def __post_init__(self) -> None:
        check_rules(self, "eval.")
        frames = list(self.at_frames)
        if not _increasing(frames, 3):
            raise ConfigError(
                f"eval.at_frames: expected increasing frame counts >= 3 (e.g. [50,100,200]), found {frames}"
            )
        iters = list(self.at_refine_iters)
        if not _increasing(iters, 1):
            raise ConfigError(
                f"eval.at_refine_iters: expected increasing iteration counts >= 1 (e.g. [500,1000,2000]), found {iters}"
            )


def _increasing(values: list[Any], lo: int) -> bool:
    """Strictly increasing ints (not bools) of at least ``lo``."""
    ok = all(isinstance(n, int) and not isinstance(n, bool) and n >= lo for n in values)
    return ok and values == sorted(set(values))


@dataclass
class VizConfig:
    """Pictures of what pruning removed (``bench.run.figures.pruned_run``); they cost renders in the SLAM loop."""

    pruning: bool = False  # pruned_kfNNN.png (+ .npz for reports) at the keyframes below
    every: int = setting(5, "int", lo=1)  # keyframes 5, 10, 15, ... (keyframe 0 has nothing to prune)

    def __post_init__(self) -> None:
        check_rules(self, "viz.")


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
    prune: PruneConfig = field(default_factory=PruneConfig)  # bench/slam/strategy.py; +experiment=released changes it
    memory: MemoryConfig = field(default_factory=MemoryConfig)
    eval: EvalConfig = field(default_factory=EvalConfig)
    viz: VizConfig = field(default_factory=VizConfig)
    # the map as a 3DGS PLY (bench/run/export.py): "final" writes map.ply at the end; "every_keyframe" also
    # keeps maps/kf_NNN.npz after each keyframe (python -m bench.export RUN_DIR --keyframe K)
    save_maps: str = setting("final", "str", choices=SAVE_MAPS)
    # always a string: seq=00 and seq=10 behave alike; None = the dataset's default
    seq: str | None = setting(None, "seq", nullable=True)
    # varies what a repeat should vary, nothing else (docs/results.md, "Comparisons that hold")
    seed: int = setting(0, "int", lo=0, hi=SEED_MAX)
    device: str = setting("auto", "str", pattern=r"auto|cpu|cuda(:\d+)?", hint="auto, cpu or cuda[:N]")
    # CPU threads (torch, numba, OpenCV): fixed, because sums split per thread round differently
    threads: int | None = setting(2, "int", lo=1, nullable=True)
    # strict: same config + seed = same numbers; fast: torch may pick non-deterministic kernels
    determinism: str = setting("strict", "str", choices=DETERMINISM)
    max_frames: int | None = setting(None, "int", lo=2, nullable=True)  # cut the sequence short (smoke tests)
    # frames excluded from FPS (the first frame only initialises the map)
    warmup_frames: int = setting(1, "int", lo=0)
    progress: bool = True  # progress bar with frame i/N, Gaussian count, fps
    resume: bool = True  # skip a finished run of the same config, code and inputs; continue an interrupted one
    checkpoint: CheckpointConfig = field(default_factory=CheckpointConfig)  # bench/run/checkpoint.py
    out_dir: str | None = setting(None, "str", nullable=True)  # None = Hydra's output dir
    sweep_name: str = setting("default", "str", pattern=NAME_PATTERN, hint=NAME_HINT)  # multirun/<sweep_name>

    def __post_init__(self) -> None:
        check_rules(self, "")
        iters = list(self.eval.at_refine_iters)
        if iters and iters[-1] > self.slam.refine_iters:
            raise ConfigError(
                f"eval.at_refine_iters: expected iteration counts up to slam.refine_iters={self.slam.refine_iters},"
                f" found {iters}"
            )


def to_run_config(cfg: DictConfig | RunConfig) -> RunConfig:
    """The composed config as dataclasses: the single ``OmegaConf.to_object`` of a run, every rule checked."""
    return as_config(RunConfig, cfg)


def expected(key: str) -> str | None:
    """What setting ``key`` (dotted) takes, in the words of its rule; None where no schema says."""
    group, _, name = key.partition(".")
    if group == "dataset":
        return next(filter(None, (expected_in(cls, name) for cls in dataset_schemas().values())), None)
    return expected_in(RunConfig, key)


def strategy_node(name: str, cls: type) -> DictConfig:
    """``+strategy=NAME`` typed: the name, and ``cls`` (the strategy's dataclass) as the schema of its params."""
    node = OmegaConf.structured(StrategyConfig(name=name))
    node.params = OmegaConf.structured(cls)
    return node


def dataset_schemas() -> dict[str, type]:
    """The config dataclass of each installed dataset that declares one, by name (the dataset registry)."""
    return {name: cls for name in registry.available(DATASET_GROUP) if (cls := schema(name)) is not None}


def compose(overrides: list[str], hydra: bool = False) -> DictConfig:
    """The run config of ``overrides`` as the CLI composes it (``./conf`` first); ``hydra``: with its ``hydra`` node.

    Here rather than in ``bench.cli.entry`` so that modules the CLI imports (``bench.sweep.study``) can compose without
    importing the CLI back; ``bench.cli.entry`` re-exports it and registers the schemas when imported."""
    from hydra import compose as hydra_compose
    from hydra import initialize_config_dir

    if not _REGISTERED:
        register_configs()
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        return hydra_compose(config_name="config", overrides=list(overrides), return_hydra_config=hydra)


_REGISTERED: list[str] = []  # what register_configs stored (empty until it ran)


def register_configs() -> list[str]:
    """Store the run schema, the dataset schemas and every installed strategy's schema.

    The one way a strategy is registered: its dataclass becomes ``schema/strategy/NAME``, and a
    strategy with no YAML under ``bench/conf/strategy/`` also gets ``strategy/NAME`` built on that
    schema, so ``+strategy=NAME strategy.params.X=...`` is typed for a plugin as for a built-in.
    A plugin that fails to import is skipped; naming it then gives the registry's one-line error.
    Returns the names given a ``strategy/NAME`` entry.
    """
    cs = ConfigStore.instance()
    cs.store(name="base_config", node=RunConfig)
    for name, cls in dataset_schemas().items():
        cs.store(group="schema/dataset", name=name, node=cls)
    shipped = set(group_files("strategy"))  # ./conf/strategy/ included
    added = []
    for name in registry.available(STRATEGY_GROUP):
        try:
            node = strategy_node(name, registry.load(STRATEGY_GROUP, "strategy", name, StrategyError))
        except (StrategyError, ValueError, TypeError):  # not installed, or a schema OmegaConf cannot hold
            continue
        cs.store(group="schema/strategy", name=name, node=node)
        if name not in shipped:
            cs.store(group="strategy", name=name, node=node, provider="pocketbench")
            added.append(name)
    _REGISTERED[:] = ["run", *added]
    return added
