"""Display names and orderings, so every table and figure calls a method the same thing."""

from __future__ import annotations

import re
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

# Built-in strategies in the paper's row order (Tables I-IV); third-party names follow, sorted.
METHOD_NAMES: dict[str, str] = {
    "none": "LSG-SLAM baseline",
    "opacity": "LightGaussian",
    "gradient": "LP-3DGS",
    "mask": "MaskGaussian",
    "area": "Ours (w/o Tile Budget)",
    "pocket": "Ours (w/ Tile Budget)",
    "random": "Random (chance baseline)",
    # the literature criteria as their authors' code computes them (issue 42; strategies/<name>.py)
    "lightgaussian": "LightGaussian (code)",
    "radsplat": "RadSplat",
    "minisplatting": "Mini-Splatting",
    "efficientgs": "EfficientGS",
    "speedysplat": "Speedy-Splat",
    "trimfat": "Trimming the Fat",
}
# the literature criteria: a figure panel of their own beside the paper's methods (bench.report.style)
LITERATURE: tuple[str, ...] = ("lightgaussian", "radsplat", "minisplatting", "efficientgs", "speedysplat", "trimfat")
STRATEGY_ORDER: tuple[str, ...] = tuple(METHOD_NAMES)

DATASET_NAMES: dict[str, str] = {
    "kitti": "KITTI",
    "euroc": "EuRoC",
    "tum": "TUM RGB-D",
    "sevenscenes": "7-Scenes",
    "synthetic": "Synthetic",
}


# The names in use: the paper's by default, replaced per report by ``--labels`` (``use_labels``).
_method_names: dict[str, str] = dict(METHOD_NAMES)


def method_name(strategy: str) -> str:
    """The paper's name for a built-in strategy (or the ``--labels`` one); others keep their own."""
    return _method_names.get(strategy, strategy)


@contextmanager
def use_method_names(names: dict[str, str]) -> Iterator[None]:
    """Show strategies under ``names`` (over the paper's) while a report is written."""
    previous = dict(_method_names)
    _method_names.update(names)
    try:
        yield
    finally:
        _method_names.clear()
        _method_names.update(previous)


def column_name(dataset: str, seq: str) -> str:
    """A table column header for a sequence: the synthetic scene is named by its seed (``scene 0``),
    which a bare ``0`` would not say."""
    return f"scene {seq}" if dataset == "synthetic" else str(seq)


def synthetic_drive(seq: str, route: Any = None, route_file: Any = None) -> str:
    """The synthetic sequence a report column stands for: the scene seed, and the route where it is not
    the default straight street, so a grid drive and one along a KITTI track never pool."""
    if isinstance(route_file, str) and route_file.strip():
        return f"{seq} on {Path(route_file).stem}"
    if isinstance(route, str) and route not in ("", "straight"):
        return f"{seq} {route}"
    return str(seq)


def strategy_rank(strategy: str) -> tuple[int, str]:
    """Sort key putting built-ins in paper order and unknown strategies after them."""
    if strategy in STRATEGY_ORDER:
        return (STRATEGY_ORDER.index(strategy), "")
    return (len(STRATEGY_ORDER), strategy)


def dataset_name(dataset: str) -> str:
    return DATASET_NAMES.get(dataset, dataset)


_EUROC_SEQ = re.compile(r"^([A-Za-z]+\d?)_?(\d{2})(?:_.*)?$")


def paper_sequence(dataset: str, seq: str) -> str:
    """The paper's spelling of a sequence, so measured runs line up with its columns.

    KITTI ``6`` -> ``06``; EuRoC ``MH_01_easy`` -> ``MH01`` (``V1_01_easy`` -> ``V101``).
    """
    seq = str(seq).strip()
    if dataset == "kitti" and seq.isdigit():
        return seq.zfill(2)
    if dataset == "euroc":
        match = _EUROC_SEQ.match(seq)
        if match:
            return f"{match.group(1).upper()}{match.group(2)}"
    return seq


def sequence_sort_key(dataset: str, seq: str) -> tuple[str, str]:
    return (paper_sequence(dataset, seq), seq)


def file_token(text: str) -> str:
    """A string safe in a file name (sequence and dataset names come from user configs)."""
    return re.sub(r"[^A-Za-z0-9._-]+", "_", str(text)).strip("_") or "x"
