"""One visual language for every figure the harness draws (report and per-run).

- A strategy has one colour everywhere (``strategy_colour``): colour-blind-safe Okabe-Ito hues,
  the unpruned baseline in black. A backend preset is a panel (``panel_groups``), never a colour;
  a keep ratio within one strategy is a line style and marker (``ratio_style``).
- At most ``MAX_SERIES`` series per panel: variants are split into small multiples, one panel per
  preset, and a strategy swept over keep ratios gets a panel of its own beside the baseline.
- One y axis per panel (no twin axes: a second quantity gets its own row of panels), y shared
  along a row where the row shows one quantity.
- Legends go outside the data (``legend_outside``); seeds are a band, mean ± sample std (``band``).
"""

from __future__ import annotations

import re
import textwrap
from collections import Counter
from collections.abc import Collection, Sequence
from dataclasses import dataclass

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from bench.names import LITERATURE, STRATEGY_ORDER, method_name
from bench.report.variants import Variant, input_differences

MAX_SERIES = 7
BASELINE = "none"
# Okabe & Ito (2008): distinguishable with the common colour-vision deficiencies and in grey print
COLOURS: dict[str, str] = {
    "none": "#000000",  # black: the reference every other line is read against
    "pocket": "#D55E00",  # vermillion
    "area": "#E69F00",  # orange: pocket's ablation, a neighbour hue
    "opacity": "#0072B2",  # blue
    "gradient": "#009E73",  # bluish green
    "mask": "#CC79A7",  # reddish purple
    "random": "#555555",  # dark grey: chance, the floor a criterion is read against
    # the literature criteria (their own panel): Paul Tol's muted scheme, also colour-blind-safe
    "lightgaussian": "#332288",  # indigo
    "radsplat": "#88CCEE",  # cyan
    "minisplatting": "#44AA99",  # teal
    "efficientgs": "#117733",  # green
    "speedysplat": "#999933",  # olive
    "trimfat": "#882255",  # wine
}
EXTRA_COLOURS: tuple[str, ...] = ("#56B4E9", "#F0E442", "#8C564B", "#7F7F7F")
RATIO_STYLES: tuple[tuple[str | tuple, str], ...] = (
    ("-", "o"),
    ("--", "s"),
    (":", "^"),
    ("-.", "D"),
    ((0, (5, 1)), "v"),
)
FONT = {"axes.titlesize": 10, "axes.labelsize": 9, "xtick.labelsize": 8, "ytick.labelsize": 8, "legend.fontsize": 8}


def strategy_colour(strategy: str, known: Sequence[str] = ()) -> str:
    """The strategy's colour: fixed for the built-ins, by sorted name for third-party ones."""
    if strategy in COLOURS:
        return COLOURS[strategy]
    extra = sorted(s for s in set(known) | {strategy} if s not in COLOURS)
    return EXTRA_COLOURS[extra.index(strategy) % len(EXTRA_COLOURS)]


Schedule = tuple[float | None, str]  # how a variant pruned: (keep ratio, ``Variant.pruning``)


def schedule(variant: Variant) -> Schedule:
    return variant.keep_ratio, variant.pruning


def _schedule_order(s: Schedule) -> tuple:
    return s[0] is None, s[0] or 0.0, s[1]


def _schedule_parts(s: Schedule) -> dict[str, str]:
    """A schedule's parts by key: its budget (``keep 0.4`` or ``N_tar 166223/Mpx``; ``absolute target`` for a run
    recorded before the pruning column) under "budget", ``floor 1/px`` under "floor", ``rank=random`` under "rank"."""
    parts = {"budget": f"keep {s[0]:g}" if s[0] is not None else "absolute target"}
    for part in s[1].split(", ") if s[1] else ():
        key = re.split(r"[= ]", part, maxsplit=1)[0]
        parts["budget" if key == "N_tar" else key] = part
    return parts


def schedule_differences(schedules: set[Schedule]) -> dict[Schedule, str]:
    """Per schedule, the parts that tell it from the others (``keep 0.4``; ``N_tar 166223/Mpx, floor 1/px``;
    ``no floor`` where an absolute target lacks the floor others set; ``default rank`` where a strategy parameter
    others set is at its default): what a legend names beside the method."""
    parsed = {s: _schedule_parts(s) for s in schedules}
    keys = dict.fromkeys(k for parts in parsed.values() for k in parts)
    differ = [k for k in keys if len({parts.get(k) for parts in parsed.values()}) > 1]

    def missing(key: str, parts: dict[str, str]) -> str:  # a keep ratio has no floor: nothing to name
        if key == "floor":
            return "" if parts["budget"].startswith("keep") else "no floor"
        return f"default {key}"

    return {s: ", ".join(p for k in differ if (p := parts.get(k) or missing(k, parts))) for s, parts in parsed.items()}


@dataclass(frozen=True)
class Panel:
    """One small multiple: a title and at most ``MAX_SERIES`` variants."""

    title: str
    variants: tuple[Variant, ...]
    preset: str
    usual: Schedule | None = None  # the schedule the preset's main panel shows: solid in a schedule panel too
    by_policy: bool = False  # a panel of memory policies: each strategy's policies take the styles in turn


def _preset_title(preset: str, several: bool) -> str:
    return f"slam={preset}" if several else ""


def panel_groups(found: Sequence[Variant]) -> list[Panel]:
    """Variants split into panels: per preset (and per input, image size and frame window, where the runs read
    several: titled by the input keys that differ), the strategies at the preset's usual keep ratio; a
    strategy run at several ratios also gets a panel of its ratios (with the baseline); a panel
    with more than ``MAX_SERIES`` variants is cut into several."""
    count = Counter(v.slam_preset for v in found)
    presets = sorted(count, key=lambda p: (p != "default", -count[p], p))  # the harness's own first
    several = len(presets) > 1
    inputs = sorted({v.input for v in found})
    shown = input_differences(set(inputs))
    panels: list[Panel] = []
    for preset, inp in [(p, i) for p in presets for i in inputs]:
        everything = [v for v in found if v.slam_preset == preset and v.input == inp]
        if not everything:
            continue
        mine = [v for v in everything if not v.memory_policy]  # today's system; memory policies get their panel
        per_strategy = Counter(v.strategy for v in mine)
        schedules = Counter(schedule(v) for v in mine if v.strategy != BASELINE)
        # the most common schedule; a keep ratio before an absolute target on a tie (the studies' usual one)
        usual = max(schedules, key=lambda s: (schedules[s], s[0] is not None)) if schedules else None
        at_usual = {v.strategy for v in mine if schedule(v) == usual}
        main = [v for v in mine if per_strategy[v.strategy] == 1 or v.strategy not in at_usual or schedule(v) == usual]
        read = f"{{{shown[inp]}}}" if len(inputs) > 1 else ""
        title = " ".join(t for t in (_preset_title(preset, several), read) if t)
        panels += _families(title, main, preset, usual)
        for strategy in [s for s, n in per_strategy.items() if n > 1]:
            swept = [v for v in mine if v.strategy == strategy]
            base = [v for v in mine if v.strategy == BASELINE and strategy != BASELINE]
            by = "keep ratio" if not any(v.pruning for v in swept) else "pruning schedule"
            sweep_title = (f"{title}:\n" if title else "") + f"{method_name(strategy)} by {by}"
            panels += _cut(sweep_title, base + swept, preset, usual)
        policies = [v for v in everything if v.memory_policy]
        if policies:  # each strategy's policies beside its run under today's policy at the same schedule
            strategies = list(dict.fromkeys(v.strategy for v in policies))
            ran = {(v.strategy, schedule(v)) for v in policies}
            ladder = [v for s in strategies for v in everything if v.strategy == s and (s, schedule(v)) in ran]
            policy_title = (f"{title}:\n" if title else "") + "memory policies"
            for panel in _cut(policy_title, ladder, preset, usual, size=2 * len(RATIO_STYLES)):
                panels.append(Panel(panel.title, panel.variants, preset, usual, by_policy=True))
    return panels


def _families(title: str, variants: list[Variant], preset: str, usual: Schedule | None) -> list[Panel]:
    """The paper's methods and the literature criteria (``names.LITERATURE``) in panels of their own, each
    with the baseline, when both ran; else one group."""
    lit = [v for v in variants if v.strategy in LITERATURE]
    if not lit or len(lit) == len([v for v in variants if v.strategy != BASELINE]):
        return _cut(title, variants, preset, usual)
    base = [v for v in variants if v.strategy == BASELINE]
    paper = [v for v in variants if v.strategy not in LITERATURE]
    head = f"{title}: " if title else ""
    return _cut(f"{head}paper's methods", paper, preset, usual) + _cut(f"{head}literature", base + lit, preset, usual)


def _cut(
    title: str, variants: list[Variant], preset: str, usual: Schedule | None, size: int = MAX_SERIES
) -> list[Panel]:
    chunks = [variants[i : i + size] for i in range(0, len(variants), size)]
    if len(chunks) == 1:
        return [Panel(title, tuple(chunks[0]), preset, usual)]
    return [Panel(f"{title} ({i + 1}/{len(chunks)})", tuple(c), preset, usual) for i, c in enumerate(chunks)]


def ratio_style(variant: Variant, panel: Panel) -> tuple[str | tuple, str]:
    """(line style, marker): solid and round unless the panel holds several schedules of the strategy (keep
    ratios, absolute targets, parameter sets); then the preset's usual schedule keeps solid and round, so one run
    looks the same in its preset's panel and in the schedule panel, and the others take the next styles in order
    (ratios ascending, then absolute targets)."""
    if panel.by_policy:  # today's policy solid and round, then the strategy's policies in the panel's order
        mine = [v for v in panel.variants if v.strategy == variant.strategy]
        return RATIO_STYLES[mine.index(variant) % len(RATIO_STYLES)] if variant in mine else RATIO_STYLES[0]
    same = sorted({schedule(v) for v in panel.variants if v.strategy == variant.strategy}, key=_schedule_order)
    if len(same) < 2 or schedule(variant) not in same:
        return RATIO_STYLES[0]
    if panel.usual in same:
        same.remove(panel.usual)
        same.insert(0, panel.usual)
    return RATIO_STYLES[same.index(schedule(variant)) % len(RATIO_STYLES)]


def series_label(variant: Variant, panel: Panel | None = None) -> str:
    """A legend entry: the method's name, and what tells its schedule (``schedule_differences``) or memory policy
    from the strategy's other variants where the panel shows several."""
    label = method_name(variant.strategy)
    if panel is None:
        return label
    schedules = {schedule(v) for v in panel.variants if v.strategy == variant.strategy}
    if len(schedules) > 1:
        label += ", " + schedule_differences(schedules)[schedule(variant)]
    if panel.by_policy:
        return label + (f" + {short_policy(variant.memory_policy)}" if variant.memory_policy else ", today's policy")
    return label


def short_policy(policy: str) -> str:
    """A memory policy (``bench.report.settings.policy_label``) short enough for a legend: the sections'
    names abbreviated (``kf.``, ``res.``; the cap and budget keys need no prefix)."""
    return policy.replace("keyframes.", "kf.").replace("densify.", "").replace("residency.", "res.")


def new_figure(width_in: float, height_in: float) -> Figure:
    """A figure with room for the legend beside its panels (at least 6.2 in wide)."""
    return Figure(figsize=(max(6.2, width_in), height_in), layout="constrained")


def apply_fonts(ax: Axes) -> None:
    """Sizes for a figure read at its committed size (about 100 px per inch)."""
    ax.title.set_fontsize(FONT["axes.titlesize"])
    ax.xaxis.label.set_fontsize(FONT["axes.labelsize"])
    ax.yaxis.label.set_fontsize(FONT["axes.labelsize"])
    ax.tick_params(labelsize=FONT["xtick.labelsize"])
    ax.grid(alpha=0.3, lw=0.6)


def band(
    ax: Axes,
    x: np.ndarray,
    mean: np.ndarray,
    std: np.ndarray | None,
    colour: str,
    ls="-",
    marker="o",
    label: str | None = None,
    markevery: int | None = None,
) -> Line2D:
    """The seeds' mean as a line, and mean ± sample std as a shaded band (where there are >= 2 seeds)."""
    (line,) = ax.plot(x, mean, ls=ls, marker=marker, ms=3, lw=1.4, color=colour, label=label, markevery=markevery)
    if std is not None and np.isfinite(std).any():
        ax.fill_between(x, mean - std, mean + std, color=colour, alpha=0.18, lw=0)
    return line


def key(label: str, colour: str = "black", ls: str | tuple = "-", marker: str = "", **kw) -> Line2D:
    """A legend entry that explains a colour or a style."""
    return Line2D([], [], color=colour, ls=ls, marker=marker, ms=4, label=label, **kw)


def legend_outside(fig: Figure, handles: list, title: str | None = None) -> None:
    """One legend for the whole figure, to the right of every panel."""
    seen: dict[str, object] = {}
    for h in handles:
        seen.setdefault(h.get_label(), h)
    fig.legend(
        handles=list(seen.values()),
        loc="outside right upper",
        fontsize=FONT["legend.fontsize"],
        title=title,
        title_fontsize=FONT["legend.fontsize"],
        frameon=False,
    )


def fig_title(fig: Figure, text: str) -> None:
    """The figure's title, left-aligned and wrapped to the figure's width, so that it never runs
    into the legend on the right."""
    # about 11 characters per inch at 11 pt, over the width left of the legend (about 2.7 in)
    width_chars = max(24, int((fig.get_figwidth() - 2.7) * 11))
    fig.suptitle(textwrap.fill(text, width_chars), x=0.01, ha="left", fontsize=11)


def strategy_keys(
    panels: Sequence[Panel], known: Sequence[str], several_styles: bool = True, shown: Collection[Variant] | None = None
) -> list[Line2D]:
    """Legend entries: one per strategy (its colour) and one per schedule style in use; with ``shown``, only for
    the variants a figure drew (styles and names still from the whole panel, as in the report's other figures)."""
    handles: list[Line2D] = []
    strategies = []
    for panel in panels:
        for v in panel.variants:
            if v.strategy not in strategies and (shown is None or v in shown):
                strategies.append(v.strategy)
    order = sorted(strategies, key=lambda s: (STRATEGY_ORDER.index(s) if s in STRATEGY_ORDER else 99, s))
    for s in order:
        handles.append(key(method_name(s), strategy_colour(s, known), marker="o"))
    if several_styles:
        for panel in panels:
            for v in panel.variants:
                if shown is not None and v not in shown:
                    continue
                ls, marker = ratio_style(v, panel)
                if (ls, marker) != RATIO_STYLES[0] or sum(u.strategy == v.strategy for u in panel.variants) > 1:
                    handles.append(key(series_label(v, panel), strategy_colour(v.strategy, known), ls, marker))
    return handles
