"""The typed configuration boundary: every shipped config composes and validates, defaults live once."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from bench.cli.entry import CONF_DIR
from bench.config.settings import as_config
from bench.datasets.kitti import KittiConfig
from bench.errors import ConfigError
from bench.run.config import RunConfig, dataset_schemas, to_run_config
from bench.slam.config import SlamConfig
from bench.slam.strategy import Strategy


def compose_cfg(*overrides: str):
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        return compose(config_name="config", overrides=list(overrides))


def _options(group: str) -> list[str]:
    return sorted(p.stem for p in (CONF_DIR / group).glob("*.yaml"))


SHIPPED = (
    [(f"dataset={n}",) for n in _options("dataset")]
    + [(f"slam={n}",) for n in _options("slam")]
    + [(f"+strategy={n}",) for n in _options("strategy")]
    + [(f"+experiment={n}",) for n in _options("experiment")]
    + [(f"dataset={d}", f"slam={s}") for d in _options("dataset") for s in _options("slam")]
)


@pytest.mark.parametrize("overrides", SHIPPED, ids=lambda o: " ".join(o))
def test_every_shipped_config_composes_and_validates(overrides):
    cfg = to_run_config(compose_cfg(*overrides))
    assert isinstance(cfg, RunConfig) and isinstance(cfg.slam, SlamConfig)
    assert dataclasses.is_dataclass(cfg.dataset)  # a built-in dataset arrives typed
    if cfg.strategy is not None:
        assert isinstance(cfg.strategy.params, Strategy)  # the strategy's own dataclass, __post_init__ run
    if overrides[0].startswith("+strategy="):
        assert cfg.strategy.params == type(cfg.strategy.params)()  # its defaults, not a copy in YAML
        assert cfg.strategy.name == overrides[0].split("=")[1]


OURS = [p for p in sorted(CONF_DIR.rglob("*.yaml")) if p.parent != CONF_DIR and "hydra" not in p.parts]  # not Hydra's


@pytest.mark.parametrize("path", OURS, ids=lambda p: str(p.relative_to(CONF_DIR)))
def test_yaml_files_only_override(path: Path):
    """A YAML value equal to the schema's default would be a second copy of that default."""
    raw = OmegaConf.to_container(OmegaConf.load(path)) or {}
    raw.pop("defaults", None)
    group = path.parent.name
    if group == "experiment":
        return  # an experiment is a set of overrides across groups
    if group == "dataset":
        schema = dataset_schemas()[path.stem]()
    elif group in ("slam", "slam_dataset"):
        schema = SlamConfig()
    else:
        assert not raw, f"{path} sets values: {raw}"
        return
    for key, value in raw.items():
        assert getattr(schema, key) != value, f"{path}: {key}: {value} repeats the dataclass default"


def test_cli_value_of_the_wrong_type_is_caught_at_composition():
    with pytest.raises(Exception, match="tracking_iters"):
        compose_cfg("slam.tracking_iters=many")


def test_unknown_setting_is_caught_at_composition():
    with pytest.raises(Exception, match="trackng_iters"):
        compose_cfg("slam.trackng_iters=3")


def test_strategy_params_are_typed_and_checked():
    cfg = to_run_config(compose_cfg("+strategy=pocket", "strategy.params.area=analytic"))
    assert cfg.strategy.params.area == "analytic"
    with pytest.raises(ConfigError, match="strategy 'pocket': area: expected one of exact, analytic, radius"):
        to_run_config(compose_cfg("+strategy=pocket", "strategy.params.area=pixels"))


def test_seq_and_seed_reach_the_typed_config():
    cfg = to_run_config(compose_cfg("dataset=kitti", "seq=10", "seed=3"))
    assert cfg.seq == "10" and isinstance(cfg.dataset, KittiConfig)
    assert cfg.slam.seed == 3  # one seed: conf/config.yaml interpolates slam.seed


def test_mapping_is_checked_against_the_dataclass():
    assert as_config(KittiConfig, {"downscale": 2}).downscale == 2
    with pytest.raises(ConfigError, match="downscale"):
        as_config(KittiConfig, {"downscale": "half"})
    with pytest.raises(ConfigError, match="found dwnscale"):
        as_config(KittiConfig, {"dwnscale": 2})
    with pytest.raises(ConfigError, match="dataset.stride: expected an integer >= 1, found 0"):
        as_config(KittiConfig, {"stride": 0})


@pytest.mark.parametrize("preset", ["default", "faithful_fit", "splatam"])
def test_kitti_tracks_with_the_corners_in_every_preset(preset: str):
    """bench/conf/slam_dataset/kitti.yaml: the feature term on KITTI whatever the preset; nowhere else; the
    command line still wins."""
    assert to_run_config(compose_cfg("dataset=kitti", f"slam={preset}")).slam.feature_weight == 2.0
    assert (
        to_run_config(compose_cfg("dataset=kitti", f"slam={preset}", "slam.feature_weight=0")).slam.feature_weight == 0
    )
    assert to_run_config(compose_cfg("dataset=euroc", f"slam={preset}")).slam.feature_weight == 0.0
    assert to_run_config(compose_cfg("dataset=sevenscenes", f"slam={preset}")).slam.feature_weight == 0.0
