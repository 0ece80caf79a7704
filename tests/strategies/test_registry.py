"""Loading strategies through entry points: built-ins, config files, errors, and a third-party plugin."""

from __future__ import annotations

import dataclasses
import importlib
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
import yaml

from bench.errors import ConfigError, StrategyError
from bench.slam import strategy as bench_strategy
from bench.slam.strategy import Strategy, available, load_strategy

BUILT_INS = [
    "area",
    "efficientgs",
    "gradient",
    "lightgaussian",
    "mask",
    "minisplatting",
    "none",
    "opacity",
    "pocket",
    "radsplat",
    "random",
    "speedysplat",
    "trimfat",
]
CONF = Path(__file__).resolve().parents[2] / "bench" / "conf" / "strategy"


@pytest.mark.parametrize("name", BUILT_INS)
def test_each_built_in_loads_through_its_entry_point_as_a_strategy_dataclass(name):
    assert name in available()
    s = load_strategy(name)
    assert isinstance(s, Strategy) and dataclasses.is_dataclass(s)
    assert type(s).__module__ == f"strategies.{name}"
    assert type(s).description and "\n" not in type(s).description


@pytest.mark.parametrize("name", BUILT_INS)
def test_config_file_builds_on_the_strategy_dataclass(name):
    """The defaults live in the dataclass; the file only picks its schema (tests/test_config.py composes it)."""
    cfg_text = (CONF / f"{name}.yaml").read_text()
    assert cfg_text.startswith("# @package strategy")
    cfg = yaml.safe_load(cfg_text)
    assert f"/schema/strategy/{name}@_here_" in cfg["defaults"]
    assert set(cfg) == {"defaults"}


def test_misspelt_name_suggests_the_closest():
    with pytest.raises(StrategyError) as err:
        load_strategy("pockt")
    assert str(err.value) == f"unknown strategy 'pockt'; did you mean 'pocket'? available: {', '.join(available())}"


def test_unknown_parameter_is_a_config_error():
    with pytest.raises(ConfigError, match="strategy 'pocket': expected parameters among .*, found 'keep_ratio'"):
        load_strategy("pocket", {"keep_ratio": 0.5})  # the ratio is shared, not a strategy field


def test_third_party_plugin_is_found_through_its_entry_point(tmp_path, monkeypatch):
    (tmp_path / "myplug.py").write_text(
        textwrap.dedent("""
        from dataclasses import dataclass
        from typing import ClassVar

        from bench.slam.strategy import Strategy, top_k_keep


        @dataclass
        class Mine(Strategy):
            description: ClassVar[str] = "keep the most opaque"
            threshold: float = 0.5

            def after_mapping(self, ctx):
                return top_k_keep(ctx.gaussians.opacities, ctx.candidates, ctx.n_target)
    """)
    )
    info = tmp_path / "myplug-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: myplug\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text("[pocketbench.strategies]\nmine = myplug:Mine\n")
    monkeypatch.syspath_prepend(str(tmp_path))  # also invalidates the import caches
    monkeypatch.delitem(sys.modules, "myplug", raising=False)
    importlib.invalidate_caches()
    try:
        assert "mine" in available() and "mine" in bench_strategy.available()
        s = load_strategy("mine", {"threshold": 0.7})
        assert type(s).__name__ == "Mine" and s.threshold == 0.7 and isinstance(s, Strategy)
        with pytest.raises(ConfigError):
            load_strategy("mine", {"thresold": 0.7})
        # registered the one typed way: +strategy=mine composes its dataclass, typed like a built-in's
        from bench.cli.entry import compose, composition_error
        from bench.run.config import register_configs, to_run_config

        assert "mine" in register_configs()  # no YAML of its own: strategy/mine built on its schema
        cfg = to_run_config(compose(["+strategy=mine", "strategy.params.threshold=0.25"]))
        assert type(cfg.strategy.params).__name__ == "Mine" and cfg.strategy.params.threshold == 0.25
        with pytest.raises(Exception) as err:
            compose(["+strategy=mine", "strategy.params.threshold=abc"])
        assert composition_error(err.value, ["+strategy=mine", "strategy.params.threshold=abc"]) == (
            "strategy 'mine' parameter threshold: expected a number, found 'abc'"
        )
    finally:
        sys.modules.pop("myplug", None)


def test_list_strategies_names_the_literature_criteria_and_their_origin():
    from bench.names import LITERATURE

    out = subprocess.run(
        [sys.executable, "-m", "bench.list_strategies"],
        capture_output=True,
        text=True,
        check=True,
        cwd=Path(__file__).resolve().parents[2],
    ).stdout
    authors = {
        "lightgaussian": "LightGaussian",
        "radsplat": "RadSplat",
        "minisplatting": "Mini-Splatting",
        "efficientgs": "EfficientGS",
        "speedysplat": "Speedy-Splat",
        "trimfat": "Trimming the Fat",
    }
    for name in LITERATURE:
        line = next(ln for ln in out.splitlines() if ln.startswith(f"{name} "))
        assert authors[name] in line and "(" in line, line  # the authors, and the commit read
