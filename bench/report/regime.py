"""The regime beside every comparison with the paper: the paper's (``paper_regime.yaml``, data beside
``paper_tables.csv``) and the runs' own, read from ``runs.csv``, in one Markdown table.

``bench.report`` prints it in ``tables.md`` when the report sets the paper's rows beside ours (``--paper``); the
committed folders get it from their ``runs.csv`` (``python -m bench.report.committed reports/NAME``;
``tests/report/test_regime.py`` checks every folder whose study sets ``paper: true``).
"""

from __future__ import annotations

from collections.abc import Sequence
from importlib import resources
from pathlib import Path
from typing import Any

import pandas as pd
import yaml

from bench.errors import ReportError
from bench.report.blocks import get_block, put_block

REGIME_FILE = "paper_regime.yaml"
BLOCK = "regime"
STAMP_END = "<!-- /provenance-stamp -->"  # bench.report.provenance_check's block, which stays first
ROWS: tuple[str, ...] = (
    "scoring protocol", "image", "resolution", "frames / keyframes", "device", "memory measure", "preset",
    "pruning target",
)  # fmt: skip
# The image type a dataset's loader reads. KITTI's loader takes the colour pair (image_2/3) where the data has it
# and falls back to the grayscale pair (image_0/1); runs.csv does not record which, so the shared data decides:
# it holds image_0/1 only (datasets/kitti/README.md).
IMAGE = {
    "kitti": "grayscale (image_0/1: the shared KITTI frames hold no colour pair)",
    "euroc": "grayscale",
    "sevenscenes": "colour (unregistered to depth)",
    "synthetic": "colour (rendered)",
    "tum": "colour",
}
PAPER_DATASETS = ("kitti", "euroc")  # the datasets of paper_tables.csv
MEMORY = {
    "torch_live": "CPU: peak of live torch tensors per keyframe window",
    "cuda_alloc": "CUDA allocator peak (torch.cuda.max_memory_allocated)",
    "cpu_rss": "CPU: process resident set peak",
}


def paper_regime(dataset: str) -> dict[str, str]:
    """The paper's regime on ``dataset`` (its KITTI regime for a dataset it has no rows for)."""
    raw = yaml.safe_load(resources.files("bench.report").joinpath(REGIME_FILE).read_text(encoding="utf-8"))
    regime = {str(k): str(v) for k, v in raw["regime"].items()}
    regime.update({str(k): str(v) for k, v in (raw.get("datasets") or {}).get(dataset, {}).items()})
    return regime


def _values(runs: pd.DataFrame, column: str) -> list[Any]:
    if column not in runs:
        return []
    return sorted({v for v in runs[column].dropna()}, key=str)


def _join(values: Sequence[Any], missing: str = "not recorded") -> str:
    return ", ".join(_text(v) for v in values) or missing


def _text(value: Any) -> str:
    if isinstance(value, float) and value.is_integer():
        return str(int(value))
    return str(value)


def _span(values: Sequence[Any]) -> str:
    numbers = [int(v) for v in values]
    return f"{min(numbers)}-{max(numbers)}" if len(set(numbers)) > 1 else str(numbers[0])


def our_regime(runs: pd.DataFrame) -> dict[str, str]:
    """The regime of ``runs`` (rows of one dataset), as ``runs.csv`` records it."""
    datasets = _values(runs, "dataset")
    sizes = sorted(
        {
            f"{int(w)}x{int(h)}"
            for w, h in zip(runs.get("dataset.width", []), runs.get("dataset.height", []), strict=False)
            if pd.notna(w) and pd.notna(h)
        }
    )
    scales = [f"1/{_text(d)}" for d in _values(runs, "dataset.downscale")]
    strides = [f"stride {_text(s)}" for s in _values(runs, "dataset.stride") if _text(s) != "1"]
    frames = _values(runs, "num_frames")
    keyframes = _values(runs, "num_keyframes")
    device = _join(_values(runs, "device"))
    cpu = _values(runs, "torch_cpu_capability")
    targets = []
    for target in _values(runs, "prune.target") or (["ratio"] if _values(runs, "keep_ratio") else []):
        if target == "absolute":
            counts = [_text(v) for v in _values(runs, "prune.n_target")]
            counts += [f"{_text(v)} per Mpx" for v in _values(runs, "prune.n_target_per_mpx")]
            targets.append(f"absolute N_tar {_join(counts)}")
        else:
            targets.append(f"keep ratio {_join(_values(runs, 'keep_ratio'), 'n/a')} of the candidates")
    return {
        "scoring protocol": _join(_values(runs, "eval_protocol")),
        "image": _join([IMAGE.get(str(d), "not recorded") for d in datasets]),
        "resolution": _join([*sizes, *scales]) + (f" ({', '.join(strides)})" if strides else ""),
        "frames / keyframes": (
            f"{_span(frames)} frames / {_span(keyframes)} keyframes" if frames and keyframes else "not recorded"
        )
        + (" (a clip, not the whole sequence)" if "kitti" in datasets else ""),
        "device": device + (f" ({_join(cpu)})" if cpu else ""),
        "memory measure": _join([MEMORY.get(str(m), str(m)) for m in _values(runs, "peak_mem_source")]),
        "preset": _join(_values(runs, "slam_preset")),
        "pruning target": _join(targets, "none"),
    }


def regime_markdown(runs: pd.DataFrame) -> str:
    """One table per dataset of ``runs``: each row of the regime, the paper's beside these runs'."""
    lines = [
        "## The two regimes",
        "",
        "The paper's figures and these runs' differ in more than the method: read every comparison with the paper "
        "against this table (the paper's side is `bench/report/paper_regime.yaml`; ours is read from `runs.csv`).",
    ]
    for dataset, rows in runs.groupby(runs["dataset"].astype(str), sort=True):
        ours, paper = our_regime(rows), paper_regime(dataset)
        own = " (the paper has no rows on it: its KITTI regime)" if dataset not in PAPER_DATASETS else ""
        lines += ["", f"**{dataset}**{own}", "", "| | the paper | these runs |", "|---|---|---|"]
        lines += [f"| {row} | {paper.get(row, '-')} | {ours[row]} |" for row in ROWS]
    return "\n".join(lines) + "\n"


def put_regime(text: str, runs: pd.DataFrame) -> str:
    """``text`` (a ``tables.md`` or ``scale.md``) with the regime block at its top, after any provenance stamp."""
    end = text.find(STAMP_END)
    if end < 0 or get_block(text, BLOCK) is not None:
        return put_block(text, BLOCK, regime_markdown(runs))
    end += len(STAMP_END)
    return text[:end] + "\n\n" + put_block(text[end:].lstrip("\n"), BLOCK, regime_markdown(runs))


def regime_committed(folder: Path, tables: bool) -> list[Path]:
    """Write the regime block from ``folder/runs.csv`` into its ``scale.md`` (which sets the paper's peak beside
    ours) and, when ``tables`` (a study with ``paper: true``), its ``tables.md``; the files written."""
    runs_csv = Path(folder) / "runs.csv"
    if not runs_csv.is_file():
        raise ReportError(f"expected a report folder with runs.csv, found no '{runs_csv}'")
    runs = pd.read_csv(runs_csv, low_memory=False)
    written = []
    for path in (Path(folder) / "tables.md" if tables else None, Path(folder) / "scale.md"):
        if path is not None and path.is_file():
            path.write_text(put_regime(path.read_text(encoding="utf-8"), runs), encoding="utf-8")
            written.append(path)
    return written


def paper_study(folder: Path) -> bool:
    """Whether the study behind ``folder`` (``conf/study/NAME.yaml``) reports with the paper's rows."""
    from bench.sweep.study import load

    return bool(load(Path(folder).name)[0].report.get("paper", False))
