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
