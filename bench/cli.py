"""The thin CLI over ``bench.run``: Hydra composes the config, known errors print one line.

Strategy names are checked before Hydra composes, because Hydra's own answer to an unknown
config option is a multi-line listing; ours is ``unknown strategy 'pockt'; did you mean ...``.
"""

from __future__ import annotations

import logging
import sys
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from hydra.types import RunMode
from omegaconf import DictConfig

from bench.errors import BenchError, StrategyError
from bench.registry import unknown_name_message

CONF_DIR = Path(__file__).resolve().parents[1] / "conf"
log = logging.getLogger("bench")


def strategy_names() -> list[str]:
    """Strategies a user can name: built-in configs plus installed entry points."""
    from bench.strategy import available

    return sorted({p.stem for p in (CONF_DIR / "strategy").glob("*.yaml")} | set(available()))


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


@hydra.main(version_base="1.3", config_path=str(CONF_DIR), config_name="config")
def _hydra_main(cfg: DictConfig) -> None:
    from bench.run import run

    hc = HydraConfig.get()
    multirun = hc.mode == RunMode.MULTIRUN
    try:
        result = run(cfg, out_dir=cfg.get("out_dir") or hc.runtime.output_dir)
    except BenchError as exc:  # a config error before the run dir exists
        print(f"error: {exc}", file=sys.stderr)
        if multirun:
            return
        sys.exit(2)
    m = result.metrics
    word = "skipped (completed)" if result.skipped else result.status
    summary = ", ".join(
        f"{k}={m.get(k)}" for k in ("ate_rmse_m", "psnr_db", "ssim", "fps", "gaussians_peak", "peak_mem_mib") if k in m
    )
    print(f"[{word}] {result.out_dir}" + (f": {summary}" if summary else ""))
    if result.error:
        print(f"error: {result.error}", file=sys.stderr)
        if result.status == "failed" and not multirun:
            sys.exit(2)


def main() -> int:
    try:
        check_overrides(sys.argv[1:])
    except BenchError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    _hydra_main()
    return 0
