import pytest
from omegaconf import OmegaConf

from bench.errors import ConfigError
from bench.run import slam_config
from bench.slam.system import SlamConfig


@pytest.mark.parametrize(
    ("kwargs", "needle"),
    [
        ({"tracking_iters": 0}, "slam.tracking_iters must be >= 1, got 0"),
        ({"kf_every": 0}, "slam.kf_every must be >= 1, got 0"),
        ({"refine_iters": -1}, "slam.refine_iters must be >= 0, got -1"),
        ({"mapping_window": 0}, "slam.mapping_window must be >= 1, got 0"),
        ({"tracking_mask": "fixed"}, "slam.tracking_mask must be 'current' or 'init', got 'fixed'"),
        ({"densify_err_median": "all"}, "slam.densify_err_median must be 'confident' or 'image', got 'all'"),
        ({"densify_sigma_px": 0.0}, "slam.densify_sigma_px must be > 0 or null, got 0.0"),
        ({"init_opacity": 1.0}, r"slam.init_opacity must be in \(0, 1\), got 1.0"),
    ],
)
def test_bad_values_name_the_setting(kwargs, needle):
    with pytest.raises(ConfigError, match=needle):
        SlamConfig(**kwargs)


def test_unknown_setting_lists_the_known_ones():
    with pytest.raises(ConfigError, match="slam has no setting trackng_iters; expected one of: .*tracking_iters"):
        slam_config(OmegaConf.create({"slam": {"trackng_iters": 3}, "seed": 0}))


def test_yaml_default_matches_dataclass_fields():
    from bench.cli import CONF_DIR

    raw = OmegaConf.to_container(OmegaConf.load(CONF_DIR / "slam" / "default.yaml"))
    cfg = slam_config(OmegaConf.create({"slam": raw, "seed": 0}))
    assert cfg.tracking_mask == "current"


@pytest.mark.parametrize(
    ("kwargs", "needle"),
    [
        ({"target": "count"}, "prune.target must be one of ratio, absolute, got 'count'"),
        ({"target": "absolute"}, "prune.target=absolute needs an integer prune.n_target >= 0, got None"),
        ({"every": "second"}, "prune.every must be one of keyframe, frame, got 'second'"),
        ({"grad_source": "x"}, "prune.grad_source must be one of params_last, means2d_all, got 'x'"),
        ({"keep_ratio": 1.5}, r"prune.keep_ratio must be in \(0, 1\], got 1.5"),
    ],
)
def test_bad_prune_settings_name_the_setting(kwargs, needle):
    from bench.strategy import PruneConfig

    with pytest.raises(ConfigError, match=needle):
        PruneConfig(**kwargs)


def _preset(name: str) -> SlamConfig:
    from hydra import compose, initialize_config_dir

    from bench.cli import CONF_DIR

    with initialize_config_dir(config_dir=str(CONF_DIR), version_base=None):
        return slam_config(compose(config_name="config", overrides=[f"slam={name}"]))


def test_splatam_preset_is_splatams_densification_and_nothing_else():
    default, splatam = _preset("default"), _preset("splatam")
    changed = {k for k in vars(default) if getattr(default, k) != getattr(splatam, k)}
    assert changed == {"name", "densify_stride", "densify_silhouette", "densify_err_median", "densify_color_err",
                       "densify_sigma_px", "init_opacity"}
    assert (splatam.name, splatam.densify_stride, splatam.densify_silhouette, splatam.densify_color_err,
            splatam.densify_sigma_px, splatam.init_opacity) == ("splatam", 1, 0.5, 0.0, 1.0, 0.5)


def test_released_experiment_composes_the_released_schedule():
    from hydra import compose, initialize_config_dir

    from bench.cli import CONF_DIR
    from bench.run import prune_config, run_keys

    with initialize_config_dir(config_dir=str(CONF_DIR), version_base=None):
        cfg = compose(config_name="config", overrides=["+experiment=released", "dataset=kitti"])
    prune = prune_config(cfg)
    assert (prune.target, prune.n_target, prune.every, prune.grad_source) == ("absolute", 80000, "frame", "means2d_all")
    assert cfg.strategy.name == "pocket" and cfg.strategy.params.tile_source == "zero"
    assert run_keys(cfg)["slam_preset"] == "released"
