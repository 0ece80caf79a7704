"""What ``pocketbench --help`` lists: each group a user picks from, with its choices (installed plugins included)."""

from __future__ import annotations

from omegaconf import OmegaConf

from bench.conf import group_files

# groups a user picks from, in the order --help lists them; slam_dataset is picked by the dataset
HELP_GROUPS: tuple[str, ...] = ("dataset", "slam", "strategy", "experiment", "study", "hydra/launcher")


def strategy_names() -> list[str]:
    """Strategies a user can name: built-in configs plus installed entry points."""
    from bench.slam.strategy import available

    return sorted(group_choices("strategy") | set(available()))


def group_choices(group: str) -> set[str]:
    """Config files for ``group``: ``./conf/<group>/*.yaml`` and the shipped ``bench/conf/<group>/*.yaml``."""
    return set(group_files(group))


def help_groups() -> str:
    """The ``--help`` listing: each user-facing group with its choices, installed plugins included."""
    from bench.slam.strategy import available

    defaults = {"dataset": "synthetic", "slam": "default", "hydra/launcher": "basic"}
    lines = []
    for group in HELP_GROUPS:
        choices = group_choices(group) | (set(available()) if group == "strategy" else set())
        if group == "hydra/launcher":
            choices.add("basic")
        if not choices:
            continue  # study: only where ./conf/study/ holds some
        shown = [f"{c} (default)" if c == defaults.get(group) else c for c in sorted(choices)]
        lines.append(f"  {group + ':':<16}{', '.join(shown)}")
    return "\n".join(lines)


def register_resolvers() -> None:
    """The ``${pocketbench.help_groups:}`` interpolation used by ``conf/hydra/help/pocketbench.yaml``."""
    if not OmegaConf.has_resolver("pocketbench.help_groups"):
        OmegaConf.register_new_resolver("pocketbench.help_groups", help_groups)
