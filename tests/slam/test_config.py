import pytest

from bench.config.settings import as_config
from bench.errors import ConfigError
from bench.slam.config import SlamConfig


@pytest.mark.parametrize(
    ("kwargs", "needle"),
    [
        ({"tracking_iters": 0}, "slam.tracking_iters: expected an integer >= 1, found 0"),
        ({"kf_every": 0}, "slam.kf_every: expected an integer >= 1, found 0"),
        ({"refine_iters": -1}, "slam.refine_iters: expected an integer >= 0, found -1"),
        ({"refine_lr_final": 0.0}, r"slam.refine_lr_final: expected a number in \(0, 1\], found 0.0"),
        ({"mapping_window": 0}, "slam.mapping_window: expected an integer >= 1 or null, found 0"),
        ({"tracking_mask": "fixed"}, "slam.tracking_mask: expected one of current, init, found 'fixed'"),
        ({"densify_err_median": "all"}, "slam.densify_err_median: expected one of confident, image, found 'all'"),
        ({"densify_sigma_px": 0.0}, "slam.densify_sigma_px: expected a number > 0 or null, found 0.0"),
        ({"init_opacity": 1.0}, r"slam.init_opacity: expected a number in \(0, 1\), found 1.0"),
    ],
)
def test_bad_values_name_the_setting(kwargs, needle):
    with pytest.raises(ConfigError, match=needle):
        SlamConfig(**kwargs)


def test_unknown_setting_lists_the_known_ones():
    needle = "SlamConfig: expected a setting among .*tracking_iters.*, found trackng_iters"
    with pytest.raises(ConfigError, match=needle):
        as_config(SlamConfig, {"trackng_iters": 3})


@pytest.mark.parametrize(
    ("kwargs", "needle"),
    [
        ({"target": "count"}, "prune.target: expected one of ratio, absolute, found 'count'"),
        ({"target": "absolute"}, "expected exactly one of them with prune.target=absolute, found neither"),
        (
            {"target": "absolute", "n_target": 5, "n_target_per_mpx": 1e5},
            "expected exactly one of them .* found n_target and n_target_per_mpx",
        ),
        ({"n_target_per_mpx": 1e5}, "prune.n_target_per_mpx: expected it only with prune.target=absolute"),
        ({"n_target_floor_per_px": 1.0}, "prune.n_target_floor_per_px: expected it only with prune.target=absolute"),
        (
            {"target": "absolute", "n_target": 5, "n_target_floor_per_px": 0.0},
            r"prune.n_target_floor_per_px: expected a number > 0",
        ),
        ({"every": "second"}, "prune.every: expected one of keyframe, frame, found 'second'"),
        ({"grad_source": "x"}, "prune.grad_source: expected one of params_last, means2d_all, found 'x'"),
        ({"keep_ratio": 1.5}, r"prune.keep_ratio: expected a number in \(0, 1\], found 1.5"),
    ],
)
def test_bad_prune_settings_name_the_setting(kwargs, needle):
    from bench.slam.strategy import PruneConfig

    with pytest.raises(ConfigError, match=needle):
        PruneConfig(**kwargs)


def _composed(*overrides: str):
    from hydra import compose, initialize_config_dir

    from bench.cli.entry import CONF_DIR
    from bench.run.config import to_run_config

    with initialize_config_dir(config_dir=str(CONF_DIR), version_base=None):
        return to_run_config(compose(config_name="config", overrides=list(overrides)))


def test_splatam_preset_is_splatams_densification_and_nothing_else():
    default, splatam = _composed("slam=default").slam, _composed("slam=splatam").slam
    changed = {k for k in vars(default) if getattr(default, k) != getattr(splatam, k)}
    assert changed == {
        "name",
        "densify_stride",
        "densify_silhouette",
        "densify_err_median",
        "densify_color_err",
        "densify_sigma_px",
        "init_opacity",
    }
    assert (
        splatam.name,
        splatam.densify_stride,
        splatam.densify_silhouette,
        splatam.densify_color_err,
        splatam.densify_sigma_px,
        splatam.init_opacity,
    ) == ("splatam", 1, 0.5, 0.0, 1.0, 0.5)


def test_released_experiment_composes_the_released_schedule():
    from bench.run.identity import run_keys

    cfg = _composed("+experiment=released", "dataset=kitti")
    prune = cfg.prune
    assert (prune.target, prune.n_target, prune.every, prune.grad_source) == ("absolute", 80000, "frame", "means2d_all")
    assert cfg.strategy.name == "pocket" and cfg.strategy.params.tile_source == "zero"
    assert run_keys(cfg)["slam_preset"] == "released"
