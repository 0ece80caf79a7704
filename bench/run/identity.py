"""What identifies a run: the ``run`` block of metrics.json, computed here and nowhere else.

Strategy, dataset, canonical sequence, seed, keep ratio and preset name a run in a report; the
config hash and the resume key (code version, input files) decide whether a stored run is the same
run (``bench.run.resume``). A run computes its keys once (``bench.run.lifecycle``); a job that never composed or
validated (the sweeper, a refused config) gets what of them its settings as given allow, from the
same function.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from omegaconf import DictConfig

from bench.datasets import FrameSequence, canonical_seq
from bench.errors import BenchError
from bench.run import provenance
from bench.run.config import RunConfig, to_run_config
from bench.run.resume import input_fingerprint, resume_key

# keys that change how a run is shown or stored (or checkpointed), not what it computes
NOT_HASHED = ("progress", "out_dir", "resume", "checkpoint")


def run_keys(
    cfg: RunConfig | Mapping[str, Any], tree: Mapping[str, Any] | None = None, seq: FrameSequence | None = None
) -> dict[str, Any]:
    """The ``run`` block of metrics.json.

    ``cfg`` typed (or a composed ``DictConfig``): the keys as reported; with ``tree`` (the resolved
    config) also the config hash, and with ``seq`` (the opened sequence) also the code version and
    input fingerprint. A ``DictConfig`` that does not validate (``seed=abc``), or a plain mapping of
    settings as given (a job that never composed): the names as given, the rest null.
    """
    if isinstance(cfg, DictConfig):
        given = cfg
        try:
            cfg = to_run_config(given)
        except BenchError:  # the bad value may be one of the keys: record the names as given
            return _as_given(given)
    if not isinstance(cfg, RunConfig):
        return _as_given(cfg)
    prunes = cfg.strategy is not None and cfg.strategy.name != "none"
    keys: dict[str, Any] = {
        "strategy": cfg.strategy.name if cfg.strategy is not None else "none",
        "dataset": dataset_name(cfg.dataset),
        "seq": canonical_seq(dataset_name(cfg.dataset), sequence_name(cfg)),
        "seed": cfg.seed,
        # no pruning, or an absolute target (prune.n_target), no ratio: such runs never pool with ratio runs
        "keep_ratio": cfg.prune.keep_ratio if prunes and cfg.prune.target == "ratio" else None,
        "slam_preset": cfg.slam.name,  # runs of different presets never pool
    }
    if tree is not None:
        keys["config_hash"] = provenance.config_hash({k: v for k, v in tree.items() if k not in NOT_HASHED})
        if seq is not None:
            keys.update(resume_key(keys["config_hash"], provenance.code_version(), input_fingerprint(seq.source_files)))
    return keys


def _as_given(cfg: Mapping[str, Any]) -> dict[str, Any]:
    def get(group: str, key: str = "name") -> Any:
        node = cfg.get(group) if isinstance(cfg, Mapping) else None
        return node.get(key) if isinstance(node, Mapping) else node

    dataset, seq, seed = str(get("dataset") or "unknown"), cfg.get("seq"), cfg.get("seed")
    return {
        "strategy": str(get("strategy") or "none"),
        "dataset": dataset,
        "seq": None if seq is None else canonical_seq(dataset, seq),
        "seed": seed if isinstance(seed, int) and not isinstance(seed, bool) and seed >= 0 else None,
        "keep_ratio": None,
        "slam_preset": None if get("slam") is None else str(get("slam")),
    }


def dataset_name(dataset: Any) -> str:
    return str(dataset["name"] if isinstance(dataset, Mapping) else dataset.name)  # a plugin's plain dict, or typed


def sequence_name(cfg: RunConfig) -> str | None:
    """The sequence as written (``seq=``), else the dataset's own default; None if it has none."""
    if cfg.seq is not None:
        return str(cfg.seq)
    ds = cfg.dataset
    if isinstance(ds, Mapping):
        return None if ds.get("seq") is None else str(ds["seq"])
    default = ds.default_sequence() if hasattr(ds, "default_sequence") else None
    return None if default is None else str(default)
