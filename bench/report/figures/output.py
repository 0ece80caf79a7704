"""What every figure file is made as (formats, dpi, the tables standing in for gone run dirs) and how it is saved."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from bench.errors import ReportError

Warn = Callable[[str], None]
DPI = 110
FORMATS: tuple[str, ...] = ("png", "pdf", "svg")
# What the figure files are made as; ``make_plots`` sets it for the duration of one report.
OUTPUT: dict[str, Any] = {"formats": ("png",), "dpi": DPI, "keyframes": {}, "milestones": {}, "long_drives": False}


def save_figure(fig: Figure, path: Path) -> Path:
    """Write ``path`` in every requested format (same stem); returns the first one's path."""
    path.parent.mkdir(parents=True, exist_ok=True)
    written = [path.with_suffix(f".{ext}") for ext in OUTPUT["formats"]]
    for target in written:
        fig.savefig(target, dpi=OUTPUT["dpi"])
    return written[0]


def _style_key(label: str, **line: Any) -> Line2D:
    """A legend entry explaining a line style (black, so it reads as "this style means")."""
    return Line2D([], [], color="black", label=label, **line)


def image_axes(ax, colour: str) -> None:
    """An image panel framed in its strategy's colour (the figures' one key to who is who)."""
    ax.set_xticks([])
    ax.set_yticks([])
    for spine in ax.spines.values():
        spine.set_edgecolor(colour)
        spine.set_linewidth(2.5)


def check_figure_options(formats: tuple[str, ...], dpi: int) -> None:
    """One ``ReportError`` line unless every format is one we draw and ``dpi`` is positive: checked
    before a report writes anything, so a refused one leaves its folder as it was."""
    bad = [f for f in formats if f not in FORMATS]
    if bad or not formats:
        raise ReportError(f"expected figure formats among {', '.join(FORMATS)}, found {', '.join(formats) or '(none)'}")
    if dpi <= 0:
        raise ReportError(f"expected a positive dpi, found {dpi}")
