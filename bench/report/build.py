"""``make_report``: run dirs in, CSV + LaTeX + Markdown + PNG figures out.

The one entry point shared by the CLI and by notebooks or tests, so both see the same files.
"""

from __future__ import annotations

import statistics
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd
import yaml

from bench.errors import ReportError
from bench.names import use_method_names
from bench.report.cells import Table
from bench.report.collect import collect, finished_run_tables, grouped_run_tables, stack_run_tables
from bench.report.figures.make import make_plots, regime_plots
from bench.report.figures.output import DPI
from bench.report.figures.runs import read_keyframes
from bench.report.growth import regime_markdown
from bench.report.paper import load_paper_tables
from bench.report.regime import put_regime
from bench.report.render import tables_markdown, to_latex
from bench.report.route_scale import MILESTONES_FILE, read_milestones, scale_markdown
from bench.report.settings import mixed_settings, settings_markdown
from bench.report.stats import confidence_interval
from bench.report.swap import built_beside
from bench.report.tables import SELECTABLE_METRICS, build_tables


@dataclass
class ReportResult:
    """What a report wrote and what it had to leave out, for the CLI summary and for tests."""

    out: Path
    runs: pd.DataFrame  # one row per run, as written to runs.csv
    tables: list[Table]
    files: list[Path] = field(default_factory=list)
    skipped: list[tuple[Path, str]] = field(default_factory=list)  # malformed run dirs and why
    warnings: list[str] = field(default_factory=list)


@dataclass(frozen=True)
class Labels:
    """``--labels``: method names (over the paper's) and the metrics the tables show (None: all)."""

    methods: dict[str, str] = field(default_factory=dict)
    metrics: tuple[str, ...] | None = None


def load_labels(path: Path | None) -> Labels:
    """Read a labels YAML (see ``bench/report/labels.yaml``); None gives the paper's defaults."""
    if path is None:
        return Labels()
    try:
        raw = yaml.safe_load(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:  # missing, binary, not YAML
        raise ReportError(f"cannot read labels file '{path}': {str(exc).splitlines()[0]}") from None
    raw = {} if raw is None else raw
    if not isinstance(raw, dict) or set(raw) - {"methods", "metrics"}:
        found = sorted(raw) if isinstance(raw, dict) else type(raw).__name__
        raise ReportError(f"labels file '{path}': expected keys methods and metrics, found {found}")
    methods = raw.get("methods") or {}
    if not isinstance(methods, dict) or not all(isinstance(v, str) for v in methods.values()):
        raise ReportError(f"labels file '{path}': expected methods as strategy: name, found {methods!r}")
    metrics = raw.get("metrics")
    if metrics is not None:
        bad = [m for m in metrics if m not in SELECTABLE_METRICS] if isinstance(metrics, list) else [metrics]
        if bad or not metrics:
            raise ReportError(
                f"labels file '{path}': expected metrics among {', '.join(SELECTABLE_METRICS)}, "
                f"found {', '.join(map(str, bad)) or '(none)'}"
            )
        metrics = tuple(metrics)
    return Labels({str(k): v for k, v in methods.items()}, metrics)


def make_report(
    run_dirs: list[Path],
    out: Path,
    paper: bool = False,
    baseline: str = "none",
    formats: tuple[str, ...] = ("png",),
    dpi: int = DPI,
    labels: Labels | None = None,
    regime: bool = False,
) -> ReportResult:
    """Collect every run under ``run_dirs`` (sweep or run dirs, searched recursively) and write
    ``runs.csv``, ``accuracy_<dataset>.tex``, ``performance_<dataset>.tex``, ``tables.md``,
    ``stats.csv`` (seed statistics of every table cell) and the figures (each in ``formats``, at
    ``dpi``) into ``out``; with ``regime``, also ``regime.md`` and the regime figures (``bench.report.growth``).
    Raises ``ReportError`` when no
    usable run is found. ``out`` is replaced as a unit (``bench.report.swap``): a report stopped part-way
    leaves it as it was."""
    labels = labels or Labels()
    with use_method_names(labels.methods), built_beside(Path(out), run_dirs) as work:
        result = _make_report(run_dirs, work, paper, baseline, formats, dpi, labels.metrics, regime)
    result.out, result.files = Path(out), [Path(out) / f.relative_to(work) for f in result.files]
    return result


def _make_report(
    run_dirs: list[Path],
    out: Path,
    paper: bool,
    baseline: str,
    formats: tuple[str, ...],
    dpi: int,
    metrics: tuple[str, ...] | None,
    regime: bool = False,
) -> ReportResult:
    if not baseline:
        raise ReportError("expected a baseline strategy name, found an empty string")
    collection = collect(run_dirs)
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ReportError(f"expected an output dir, found the file '{out}'")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ReportError(f"cannot create output dir '{out}': {exc.strerror or exc}") from exc
    runs = collection.runs
    warnings = list(collection.warnings) + mixed_settings(runs)

    files = [out / "runs.csv"]
    runs.to_csv(files[0], index=False)
    keyframes = finished_run_tables(runs, lambda run_dir: read_keyframes(run_dir, warnings.append))
    milestones = finished_run_tables(runs, lambda run_dir: read_milestones(run_dir, warnings.append))
    files.append(out / POOLED_KEYFRAMES_FILE)
    stack_run_tables(keyframes).to_csv(files[-1], index=False)

    tables, table_warnings = build_tables(runs, load_paper_tables() if paper else None, baseline, metrics)
    warnings += table_warnings
    for table in tables:
        path = out / f"{table.name}.tex"
        path.write_text(to_latex(table), encoding="utf-8")
        files.append(path)
    markdown = out / "tables.md"
    text = tables_markdown(tables) + "\n" + settings_markdown(runs)
    markdown.write_text(put_regime(text, runs) if paper else text, encoding="utf-8")  # the paper's rows: both regimes
    files.append(markdown)
    files.append(out / "stats.csv")
    seed_statistics(tables, baseline).to_csv(files[-1], index=False)

    long_drives = any(len(t) for t in milestones.values())
    if long_drives:  # runs made with eval.at_frames: the scale section (bench/report/route_scale.py)
        files.append(out / MILESTONES_FILE)
        stacked = stack_run_tables(milestones)
        stacked.to_csv(files[-1], index=False)
        files.append(out / "scale.md")
        files[-1].write_text(put_regime(scale_markdown(runs, keyframes, stacked, baseline), runs), encoding="utf-8")
    files += make_plots(
        runs, out, warnings.append, formats, dpi, keyframes=keyframes, milestones=milestones, long_drives=long_drives
    )
    if regime:  # the regime study's table and figures (bench/report/growth.py)
        files.append(out / "regime.md")
        files[-1].write_text(regime_markdown(runs, baseline, keyframes), encoding="utf-8")
        files += regime_plots(runs, keyframes, out, baseline, formats, dpi)
    return ReportResult(out, runs, tables, files, collection.skipped, warnings)


POOLED_KEYFRAMES_FILE = "keyframes.csv"  # every finished run's keyframes.csv rows, keyed by its runs.csv path
TEXT_COLUMNS = ("strategy", "method", "dataset", "seq", "slam_preset", "eval_protocol", "status", "path")


def redraw(report_dir: Path, formats: tuple[str, ...] = ("png",), dpi: int = DPI) -> ReportResult:
    """The figures of a report folder again, from its ``runs.csv`` and ``keyframes.csv`` alone.

    Accuracy-memory, keep-ratio and per-keyframe figures need nothing else; trajectory, density
    and pruned-Gaussian figures need the run dirs and are drawn only where those still exist.
    """
    report_dir = Path(report_dir)
    runs_path = report_dir / "runs.csv"
    if not runs_path.is_file():
        raise ReportError(f"expected a report folder with runs.csv, found no '{runs_path}'")
    try:
        runs = pd.read_csv(runs_path, dtype={c: str for c in TEXT_COLUMNS})
        if "seed" in runs:
            runs["seed"] = runs["seed"].astype("Int64")
    except (OSError, ValueError) as exc:
        raise ReportError(f"cannot read the report tables in '{report_dir}': {exc}") from None
    missing = sorted({"strategy", "dataset", "seq", "status", "path", "keep_ratio"} - set(runs.columns))
    if missing:
        raise ReportError(f"expected runs.csv columns {', '.join(missing)} in '{runs_path}', found none of them")
    _check_numbers(runs, runs_path)
    warnings: list[str] = []
    keyframes = _stored_run_tables(report_dir / POOLED_KEYFRAMES_FILE)
    if not keyframes:
        warnings.append(f"no {POOLED_KEYFRAMES_FILE} in '{report_dir}': per-keyframe figures need the run dirs")
    milestones = _stored_run_tables(report_dir / MILESTONES_FILE)
    files = make_plots(
        runs,
        report_dir,
        warnings.append,
        formats,
        dpi,
        keyframes=keyframes,
        milestones=milestones,
        long_drives=bool(milestones),
    )
    return ReportResult(report_dir, runs, [], files, [], warnings)


def _stored_run_tables(path: Path) -> dict[str, pd.DataFrame]:
    """A report folder's stacked per-run table split back by run path; {} when the folder has none."""
    if not path.is_file():
        return {}
    try:
        table = pd.read_csv(path, dtype={"path": str})
    except (OSError, ValueError) as exc:
        raise ReportError(f"cannot read '{path}': {exc}") from None
    if "path" not in table:
        raise ReportError(
            f"expected a path column (the run each row belongs to) in '{path}', found columns: "
            f"{', '.join(map(str, table.columns[:8]))}{', ...' if len(table.columns) > 8 else ''}"
        )
    _check_numbers(table, path)
    return grouped_run_tables(table)


def _check_numbers(table: pd.DataFrame, path: Path) -> None:
    """One ``ReportError`` line for text in a column the schema holds numbers in: a figure would
    otherwise fail mid-drawing, after others were written."""
    from bench import schema

    numbers = {
        f.name
        for fields in (schema.RUN_FIELDS, schema.METRIC_FIELDS, schema.KEYFRAME_FIELDS, schema.MILESTONE_FIELDS)
        for f in fields
        if f.kind == "number"
    }
    for column in table.columns:
        if column not in numbers or pd.api.types.is_numeric_dtype(table[column]):
            continue
        bad = table[column].notna() & pd.to_numeric(table[column], errors="coerce").isna()
        if bad.any():
            row = int(bad.to_numpy().nonzero()[0][0])
            raise ReportError(
                f"expected numbers in column '{column}' of '{path}', found "
                f"{table[column].iloc[row]!r} on line {row + 2}"
            )


STATS_COLUMNS: tuple[str, ...] = (
    "dataset", "metric", "method", "strategy", "keep_ratio", "slam_preset", "seq", "n_seeds", "seeds", "mean",
    "std", "ci95_low", "ci95_high", "baseline", "p_welch", "within_noise", "eval_protocol",
)  # fmt: skip


def seed_statistics(tables: list[Table], baseline: str) -> pd.DataFrame:
    """One row per measured table cell (metric blocks, Avg included): n, mean, sample std, the
    Student-t 95% confidence interval, and Welch's p against the baseline with its verdict."""
    rows = []
    for table in tables:
        for block in table.blocks:
            if block.style != "value":
                continue  # relative blocks restate the metric blocks' tests
            for row in block.rows:
                if row.variant is None:
                    continue
                for column, cell in zip(table.columns, row.cells, strict=True):
                    if cell.kind != "num":
                        continue
                    ci = confidence_interval(cell.values, 0.95)
                    rows.append(
                        {
                            "dataset": table.dataset,
                            "metric": block.key,
                            "method": row.label,
                            "strategy": row.variant.strategy,
                            "keep_ratio": row.variant.keep_ratio,
                            "slam_preset": row.variant.slam_preset,
                            "seq": column,
                            "n_seeds": len(cell.values),
                            "seeds": " ".join(str(s) for s in cell.seeds),
                            "mean": cell.mean,
                            "std": statistics.stdev(cell.values) if len(cell.values) > 1 else None,
                            "ci95_low": None if ci is None else ci[0],
                            "ci95_high": None if ci is None else ci[1],
                            "baseline": baseline if row.variant.strategy != baseline else None,
                            "p_welch": cell.p_value,
                            "within_noise": cell.noise if cell.p_value is not None else None,
                            "eval_protocol": table.protocol,
                        }
                    )
    return pd.DataFrame(rows, columns=list(STATS_COLUMNS))
