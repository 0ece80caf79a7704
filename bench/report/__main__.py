"""CLI: ``python -m bench.report SWEEP_DIR [...] --out reports/NAME [--paper] [--baseline none]``,
or ``python -m bench.report --study NAME``: the runs and options of ``conf/study/NAME.yaml``.

Known failures (``BenchError``) print one line and exit 2; anything else is a bug and keeps its
traceback.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from bench.errors import ArgumentParser, BenchError, ReportError, failed
from bench.report import provenance_check
from bench.report.build import load_labels, make_report, redraw
from bench.report.collect import collect
from bench.report.figures.output import DPI, check_figure_options
from bench.run.signals import Interrupted, raise_on_signals


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = ArgumentParser(
        prog="python -m bench.report",
        description="Tables (CSV, LaTeX, Markdown) and figures from SLAM run dirs.",
    )
    parser.add_argument("dirs", nargs="*", type=Path, help="sweep or run dirs, searched recursively")
    parser.add_argument("--out", type=Path, help="output dir, e.g. reports/NAME")
    parser.add_argument(
        "--redraw",
        type=Path,
        default=None,
        metavar="REPORT_DIR",
        help="draw the figures of a report folder again from its runs.csv and keyframes.csv "
        "(no run dirs needed), in place",
    )
    parser.add_argument(
        "--study",
        default=None,
        help="the runs of conf/study/NAME.yaml (bench.study) and its report options: --out, --paper; "
        "a positional KEY=VALUE is an override the study ran with (as after +study=NAME)",
    )
    parser.add_argument(
        "--index",
        nargs="?",
        const=Path("reports"),
        default=None,
        type=Path,
        metavar="REPORTS_DIR",
        help="write REPORTS_DIR/README.md (default reports/), the index of every report folder, from each "
        "folder's README, runs.csv and study file",
    )
    parser.add_argument(
        "--allow-dirty",
        action="store_true",
        help="with --study: report runs made with uncommitted changes or at a commit not in this repository's "
        "history, and stamp every table and the README with how many (refused without it)",
    )
    parser.add_argument("--paper", action="store_true", default=None, help="add the paper's figures as '(paper)' rows")
    parser.add_argument(
        "--regime",
        action="store_true",
        default=None,
        help="add regime.md and the regime figures: each pruned run's peak against the baseline's of its cell, "
        "by keyframes held and growth density, with the paper's run on the same axes",
    )
    parser.add_argument("--baseline", default="none", help="strategy the relative columns compare with")
    parser.add_argument("--format", default="png", help="figure formats, comma-separated: png,pdf,svg (default png)")
    parser.add_argument("--dpi", type=int, default=DPI, help=f"raster resolution of png figures (default {DPI})")
    parser.add_argument(
        "--labels",
        type=Path,
        default=None,
        help="YAML of method names and metrics to show (default: the paper's names, all metrics; "
        "template: bench/report/labels.yaml)",
    )
    return parser.parse_args(argv)


def study_inputs(args: argparse.Namespace) -> None:
    """``--study NAME``: the study's run dirs that exist, and its report options where the command line gives none."""
    from bench.sweep.study import load

    overrides = [str(d) for d in args.dirs if "=" in str(d) and not d.exists()]
    args.dirs = [d for d in args.dirs if str(d) not in overrides]
    study, jobs = load(args.study, overrides)
    found = [job.run_dir for job in jobs if job.run_dir.is_dir()]
    if not found:
        first = jobs[0].run_dir if jobs else "-"
        raise ReportError(
            f"study '{study.name}': expected run dirs of its {len(jobs)} runs, found none (first: "
            f"{first}); run: pocketbench --multirun +study={study.name}"
        )
    if len(found) < len(jobs):
        print(
            f"warning: study '{study.name}': {len(jobs) - len(found)} of {len(jobs)} run dirs missing", file=sys.stderr
        )
    args.dirs = [*args.dirs, *found]
    args.out = args.out or Path(study.report.get("out", f"reports/{study.name}"))
    args.paper = bool(study.report.get("paper", False)) if args.paper is None else args.paper
    args.regime = bool(study.report.get("regime", False)) if args.regime is None else args.regime


def main(argv: list[str] | None = None) -> int:
    """The CLI; Ctrl-C or SIGTERM is one line and exit 130 / 143, the report folder left as it was
    (``make_report`` builds beside it and swaps it in only once whole)."""
    args = parse_args(argv)
    try:
        with raise_on_signals():
            return _main(args)
    except Interrupted as exc:
        where = args.out or args.redraw
        print(f"error: {exc}" + (f"; {where} left as it was" if where and not args.redraw else ""), file=sys.stderr)
        return exc.exit_code


def _main(args: argparse.Namespace) -> int:
    try:
        formats = tuple(f.strip().lower().lstrip(".") for f in args.format.split(",") if f.strip())
        check_figure_options(formats, args.dpi)  # before any table is written
        if args.index is not None:
            from bench.report.index import write

            if args.dirs or args.out or args.study or args.redraw:
                raise ReportError("--index takes only the reports dir, found run dirs, --out, --study or --redraw")
            print(f"wrote {write(args.index)}")
            return 0
        if args.redraw is not None:
            if args.dirs or args.out:
                raise ReportError(
                    f"--redraw takes no run dirs and no --out, found {len(args.dirs)} dirs"
                    f"{' and --out' if args.out else ''}"
                )
            result = redraw(args.redraw, formats, args.dpi)
            for warning in result.warnings:
                print(f"warning: {warning}", file=sys.stderr)
            print(f"{len(result.runs)} runs: redrew {len(result.files)} figures in {result.out}")
            return 0
        stamp: str | None = None
        if args.study:
            study_inputs(args)
            stamp = provenance_check.check(args.study, collect(args.dirs).runs, args.allow_dirty)
        if not args.dirs or args.out is None:
            raise ReportError("expected run dirs and --out (or --study NAME, or --redraw REPORT_DIR)")
        result = make_report(
            args.dirs,
            args.out,
            paper=bool(args.paper),
            baseline=args.baseline,
            formats=formats,
            dpi=args.dpi,
            labels=load_labels(args.labels),
            regime=bool(args.regime),
        )
        if args.study:
            result.files += [f for f in provenance_check.stamp_report(result.out, stamp) if f not in result.files]
            if stamp:
                print(f"warning: study '{args.study}': {stamp}, stamped on its tables and README", file=sys.stderr)
    except BenchError as exc:
        return failed(exc)
    for warning in result.warnings:
        print(f"warning: {warning}", file=sys.stderr)
    skipped = f", {len(result.skipped)} malformed skipped" if result.skipped else ""
    print(f"{len(result.runs)} runs{skipped}: wrote {len(result.files)} files to {result.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
