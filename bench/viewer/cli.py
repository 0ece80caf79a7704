"""``pocketbench view RUN_DIR [RUN_DIR_B]`` and ``python -m bench.view``: a run's map in the browser.

Each path is a run dir or a sweep/study dir (``multirun/NAME``). A sweep's runs are listed, numbered,
on stdout, and the page has a dropdown to switch between them; ``--run`` picks the one shown first
(its number in the list, or a part of its path or label that only one run has), else the first.
"""

from __future__ import annotations

import signal
import time
from pathlib import Path

from bench.errors import ArgumentParser, BenchError, ConfigError, failed
from bench.viewer.scene import find_runs, has_map, run_label

EXIT_ERROR = 2


def pick_run(runs: list[Path], root: Path, choice: str | None) -> int:
    """The index of ``choice`` (a 0-based number, or a substring of one run's path or label) in ``runs``; without
    one, the first run that has a map (a sweep's failed runs have none)."""
    if choice is None:
        return next((i for i, r in enumerate(runs) if has_map(r)), 0)
    if choice.isdigit():
        if int(choice) < len(runs):
            return int(choice)
        raise ConfigError(f"--run: expected a number from 0 to {len(runs) - 1}, found {choice}")
    hits = [i for i, r in enumerate(runs) if choice in run_label(r, root)]
    if len(hits) != 1:
        found = "no run" if not hits else f"{len(hits)} runs"
        raise ConfigError(f"--run: expected one run whose path or label holds '{choice}', found {found}")
    return hits[0]


def parse(argv: list[str] | None):
    parser = ArgumentParser(
        prog="pocketbench view",
        description="Serve a run's Gaussian map, trajectories and keyframes in the browser (viser); "
        "two runs side by side, or a sweep's runs to pick from.",
    )
    parser.add_argument("run_dirs", type=Path, nargs="+", metavar="RUN_DIR", help="a run dir or sweep dir (two: A, B)")
    parser.add_argument("--port", type=int, default=8080, help="port to serve on (default 8080; 0: any free one)")
    parser.add_argument("--host", default="127.0.0.1", help="address to serve on (default 127.0.0.1: this machine)")
    parser.add_argument(
        "--run", action="append", default=None, metavar="N|TEXT", help="in a sweep dir, the run shown first (per path)"
    )
    parser.add_argument(
        "--keyframe", type=int, default=None, metavar="K", help="start at keyframe K's snapshot/prune (default: final)"
    )
    args = parser.parse_args(argv)
    if len(args.run_dirs) > 2:
        parser.error(f"expected one or two run dirs, found {len(args.run_dirs)}")
    return args


def plan(run_dirs: list[Path], picks: list[str] | None) -> list[tuple[list[Path], Path, int]]:
    """Per path: (its runs, the path, the index shown first); prints a sweep's numbered list."""
    picks = list(picks or [])
    if len(picks) > len(run_dirs):
        raise ConfigError(f"--run: expected at most one per path ({len(run_dirs)}), found {len(picks)}")
    slots = []
    for i, path in enumerate(run_dirs):
        runs = find_runs(path)
        pick = pick_run(runs, path, picks[i] if i < len(picks) else None)
        if len(runs) > 1:
            print(f"{path}: {len(runs)} runs (pick one on the page, or with --run N)")
            for n, run in enumerate(runs):
                print(
                    f"  {'*' if n == pick else ' '}{n:3d}  {run_label(run, path)}{'' if has_map(run) else '  [no map]'}"
                )
        slots.append((runs, path, pick))
    return slots


def main(argv: list[str] | None = None) -> int:
    args = parse(argv)
    try:
        slots = plan(args.run_dirs, args.run)
        from bench.viewer.serve import Viewer

        viewer = Viewer(slots, host=args.host, port=args.port, keyframe=args.keyframe)
    except BenchError as exc:
        return failed(exc, EXIT_ERROR)
    # Ctrl-C stops the viewer even where it was started with SIGINT ignored (a command put in the background by a
    # shell without job control inherits that, and Python then raises no KeyboardInterrupt)
    signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        print(f"serving {', '.join(s.scene.label for s in viewer.slots)} at {viewer.url} (Ctrl-C stops)", flush=True)
        while True:
            time.sleep(3600)
    except KeyboardInterrupt:
        pass
    finally:
        viewer.stop()
    return 0
