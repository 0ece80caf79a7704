"""Precompute the stereo depth cache of a sequence, so benchmark runs only read ``.npy`` files.

    python -m bench.datasets.prepare kitti --seq 06 --root /data/kitti
    python -m bench.datasets.prepare euroc --seq MH01 downscale=1 stereo.num_disparities=96

Options after the dataset name are ``key=value`` overrides of conf/dataset/<name>.yaml (a
``dataset.`` prefix is accepted, so Hydra-style overrides can be pasted). The cache key covers
every depth parameter, so prepare with the same overrides the benchmark will use.
"""

from __future__ import annotations

import dataclasses
import logging
import sys
import time
from typing import Any

import numpy as np
from omegaconf import OmegaConf

from bench.conf import CONF_DIR, group_files
from bench.datasets import open_sequence
from bench.datasets.stereo import StereoSequence
from bench.errors import ArgumentParser, BenchError, ConfigError, failed

LOG = logging.getLogger("bench.datasets.prepare")


def load_cfg(name: str, overrides: list[str]) -> Any:
    """The dataset config as ``python -m bench dataset=NAME dataset.KEY=VALUE ...`` composes it."""
    from hydra import compose, initialize_config_dir
    from hydra.errors import HydraException
    from omegaconf.errors import OmegaConfBaseException

    from bench.config.settings import describe_error
    from bench.run.config import register_configs

    files = group_files("dataset")  # ./conf/dataset/ first, then the shipped ones
    if name not in files:
        found = ", ".join(sorted(files)) or "(none)"
        raise ConfigError(
            f"dataset config not found: expected {CONF_DIR / 'dataset' / name}.yaml or "
            f"conf/dataset/{name}.yaml, found configs: {found}"
        )
    dotlist = []
    for item in overrides:
        if "=" not in item:
            raise ConfigError(f"override {item!r}: expected key=value, found no '='")
        key, value = item.split("=", 1)
        dotlist.append(f"dataset.{key.removeprefix('dataset.')}={value}")
    register_configs()
    try:
        with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
            cfg = compose(config_name="config", overrides=[f"dataset={name}", *dotlist])
        return OmegaConf.to_object(cfg.dataset)
    except OmegaConfBaseException as exc:
        raise ConfigError(describe_error(exc)) from None
    except HydraException as exc:
        raise ConfigError(str(exc).splitlines()[0]) from None


def prepare(name: str, cfg: Any) -> dict[str, float]:
    """Fill the depth cache for every selected frame; returns summary statistics."""
    seq = open_sequence(name, cfg)
    if not isinstance(seq, StereoSequence):
        LOG.info("%s: depth comes from the dataset, nothing to cache; %d frames open fine", seq.name, len(seq))
        return {"frames": len(seq), "computed": 0, "cached": 0}
    if seq.cache.root is None:
        raise ConfigError(f"{name} cache_dir: expected a directory to fill, found null (cache disabled)")
    t0 = time.perf_counter()
    computed = cached = 0
    valid, medians = [], []
    for i in range(len(seq)):
        path = seq.cache.path(seq.depth_key(i))
        hit = path is not None and path.is_file()
        depth = seq.depth(i)  # [h, w]
        cached += hit
        computed += not hit
        ok = depth > 0
        valid.append(ok.mean())
        if ok.any():
            medians.append(float(np.median(depth[ok])))
        if (i + 1) % 50 == 0 or i + 1 == len(seq):
            LOG.info("%s: %d/%d frames (%d computed, %d cached)", seq.name, i + 1, len(seq), computed, cached)
    stats = {
        "frames": len(seq),
        "computed": computed,
        "cached": cached,
        "valid_fraction": float(np.mean(valid)),
        "median_depth_m": float(np.median(medians)) if medians else float("nan"),
        "seconds": time.perf_counter() - t0,
    }
    LOG.info(
        "%s: depth cache at %s; valid fraction %.3f, median depth %.2f m, %.1f s",
        seq.name,
        seq.cache.root,
        stats["valid_fraction"],
        stats["median_depth_m"],
        stats["seconds"],
    )
    return stats


def main(argv: list[str] | None = None) -> int:
    parser = ArgumentParser(prog="python -m bench.datasets.prepare", description=__doc__.split("\n")[0])
    parser.add_argument("dataset", help="dataset config name: kitti, euroc or tum")
    parser.add_argument("--seq", help="sequence (default: the yaml's default_seq)")
    parser.add_argument("--root", help="dataset root (default: the yaml's root)")
    parser.add_argument("--cache-dir", help="depth cache directory (default: the yaml's cache_dir)")
    parser.add_argument("overrides", nargs="*", help="key=value config overrides, e.g. downscale=2")
    args = parser.parse_intermixed_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    extra = [f"seq={args.seq}"] if args.seq is not None else []
    extra += [f"root={args.root}"] if args.root is not None else []
    extra += [f"cache_dir={args.cache_dir}"] if args.cache_dir is not None else []
    try:
        cfg = load_cfg(args.dataset, [*args.overrides, *extra])
        if args.seq is not None:
            cfg = dataclasses.replace(cfg, seq=args.seq)  # as typed: '06' stays '06'
        prepare(args.dataset, cfg)
    except BenchError as exc:
        return failed(exc)
    return 0


if __name__ == "__main__":
    sys.exit(main())
