"""Dataset plugins, looked up through the ``pocketbench.datasets`` entry-point group."""

from __future__ import annotations

import sys
from collections.abc import Mapping
from typing import Any

from bench.config import plugins as registry
from bench.datasets.base import Frame, FrameSequence
from bench.errors import DatasetError

GROUP = "pocketbench.datasets"

__all__ = ["GROUP", "Frame", "FrameSequence", "canonical_seq", "open_sequence", "schema"]

Sequence = FrameSequence  # the name dataset plugins written before FrameSequence subclass


def open_sequence(name: str, cfg: Mapping[str, Any]) -> FrameSequence:
    """Open sequence ``cfg['seq']`` of dataset ``name``; a known failure is a ``DatasetError``."""
    factory = registry.load(GROUP, "dataset", name, DatasetError)
    seq = factory(cfg)
    if not isinstance(seq, FrameSequence):
        found = type(seq).__name__
        raise DatasetError(f"dataset plugin '{name}': expected a bench.datasets.FrameSequence, found {found}")
    return seq


def _module(name: str) -> Any:
    """The module that defines dataset ``name``'s factory; None if the dataset is not installed."""
    try:
        factory = registry.load(GROUP, "dataset", name, DatasetError)
    except DatasetError:
        return None
    return sys.modules.get(getattr(factory, "__module__", ""))


def schema(name: str) -> type | None:
    """The config dataclass of dataset ``name``: ``SCHEMA`` beside its factory; None for a plugin without one
    (its settings then arrive as a plain dict)."""
    return getattr(_module(name), "SCHEMA", None)


def canonical_seq(name: str, seq: Any) -> str | None:
    """The one name sequence ``seq`` of dataset ``name`` is recorded and reported under.

    Why: ``seq=6`` and ``seq=06`` (or EuRoC's ``V101`` and ``V1_01_easy``) are one sequence; recorded
    as typed, a report would show two columns and count the sequence twice in its average. A
    plugin defines ``canonical_seq(seq) -> str`` beside its factory; without one the name is kept.
    """
    if seq is None or str(seq).strip() == "":
        return None
    fn = getattr(_module(name), "canonical_seq", None)
    return str(fn(seq)) if callable(fn) else str(seq).strip()
