"""One exception family, so the CLI can print known failures as a single line.

Messages are lowercase and state what was expected and what was found (evo's style).
Anything that is not a ``BenchError`` is a bug and keeps its traceback.
"""

from __future__ import annotations

import argparse
import sys
from typing import NoReturn


class BenchError(Exception):
    """Base of every error the harness raises on purpose."""


class ConfigError(BenchError):
    """A config value is missing, of the wrong type or out of range."""


class DatasetError(BenchError):
    """A dataset is missing, laid out wrongly, or holds malformed files."""


class StrategyError(BenchError):
    """A pruning strategy is unknown, fails to load, or breaks the contract."""


class MetricError(BenchError):
    """A metric cannot be computed from the inputs it was given."""


class ReportError(BenchError):
    """Report inputs are missing or malformed (no run dirs, bad metrics.json, bad arguments)."""


class RunDirBusy(BenchError):
    """Another live process writes the run dir (it holds the dir's lock); nothing is written."""


class TrackingLost(BenchError):
    """Tracking diverged; the run ends with status ``lost`` and keeps its partial results."""


class ArgumentParser(argparse.ArgumentParser):
    """argparse with its usage errors as the harness's one ``error:`` line (exit 2): argparse's own
    print the usage, then a line that begins with the program's name."""

    def error(self, message: str) -> NoReturn:
        print(f"error: {message} (usage: {self.prog} --help)", file=sys.stderr)
        sys.exit(2)


def failed(exc: BaseException, exit_code: int = 2) -> int:
    """A known failure at the command line: its one ``error:`` line on stderr; returns the exit status
    (2, as argparse's usage errors) for the command's ``main`` to return."""
    print(f"error: {exc}", file=sys.stderr)
    return exit_code
