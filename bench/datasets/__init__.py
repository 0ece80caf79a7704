"""Dataset plugins, looked up through the ``pocketbench.datasets`` entry-point group."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from bench import registry
from bench.datasets.base import Frame, Sequence
from bench.errors import DatasetError

GROUP = "pocketbench.datasets"

__all__ = ["GROUP", "Frame", "Sequence", "open_sequence"]


def open_sequence(name: str, cfg: Mapping[str, Any]) -> Sequence:
    """Open sequence ``cfg['seq']`` of dataset ``name``; a known failure is a ``DatasetError``."""
    factory = registry.load(GROUP, "dataset", name, DatasetError)
    seq = factory(cfg)
    if not isinstance(seq, Sequence):
        raise DatasetError(
            f"dataset plugin '{name}' must return a bench.datasets.Sequence, got {type(seq).__name__}"
        )
    return seq
