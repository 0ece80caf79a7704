"""Figures are written, and the pieces behind them (alignment, peak probe) are right."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bench.report.build import redraw
from bench.report.collect import collect
from bench.report.figures.make import make_plots
from bench.report.figures.runs import seed_band
from bench.report.style import COLOURS, MAX_SERIES, RATIO_STYLES, panel_groups, ratio_style, strategy_colour
from bench.report.variants import Variant

PNG = b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize(
    "name",
    [
        "memory_per_keyframe_kitti_00.png",
        "memory_per_keyframe_kitti_05.png",
        "memory_per_keyframe_euroc_MH_01_easy.png",
        "gaussians_per_keyframe_kitti_00.png",
        "ratio_kitti.png",
        "density_kitti_00.png",
        "density_euroc_MH_01_easy.png",
        "trajectory_kitti_00.png",
        "trajectory_kitti_05.png",
        "pareto_kitti.png",
        "pareto_euroc.png",
    ],
)
def test_plot_is_written(report, name: str) -> None:
    path = report.out / name
    assert path in report.files
    assert path.stat().st_size > 1000
    assert path.read_bytes()[:8] == PNG


def test_ratio_plot_needs_two_ratios_of_one_strategy(report) -> None:
    assert not (report.out / "ratio_euroc.png").exists()  # one keep ratio per strategy there


def test_bad_run_files_cost_a_warning_not_the_report(tmp_path: Path, make_run) -> None:
    run = make_run(tmp_path / "sweep" / "0", strategy="none", seq="00")
    make_run(tmp_path / "sweep" / "1", strategy="pocket", seq="00")
    (run / "traj_est.txt").write_text("not a trajectory\n")
    (run / "keyframes.csv").write_text("a,b\n1,2\n")
    np.savez(run / "density.npz", counts=np.zeros(3))
    warnings: list[str] = []
    written = make_plots(collect([tmp_path / "sweep"]).runs, tmp_path / "out", warnings.append)
    assert {p.name for p in written} >= {"trajectory_kitti_00.png", "memory_per_keyframe_kitti_00.png"}
    for name in ("traj_est.txt", "keyframes.csv", "density.npz"):
        assert any(name in w and "expected" in w for w in warnings), name


def test_panels_hold_at_most_seven_series_and_split_presets_and_sweeps() -> None:
    found = [Variant(s, 0.4, s, p) for p in ("default", "splatam") for s in ("none", "pocket", "area", "opacity")]
    found += [Variant("area", k, "area", "splatam") for k in (0.2, 0.6, 0.8)]
    found += [Variant(f"plugin{i}", 0.4, f"plugin{i}", "default") for i in range(5)]
    panels = panel_groups(found)
    assert all(len(p.variants) <= MAX_SERIES for p in panels)
    assert {v for p in panels for v in p.variants} == set(found)  # every variant is shown
    for panel in panels:
        assert len({v.slam_preset for v in panel.variants}) == 1  # a preset is a panel, never mixed
    sweep = [p for p in panels if "keep ratio" in p.title]
    assert len(sweep) == 1 and {v.keep_ratio for v in sweep[0].variants if v.strategy == "area"} == {0.2, 0.4, 0.6, 0.8}
    assert any(v.strategy == "none" for v in sweep[0].variants)  # the baseline beside the sweep


def test_a_run_looks_the_same_in_its_preset_panel_and_in_the_ratio_panel() -> None:
    found = [Variant(s, 0.4, s, "splatam") for s in ("none", "area")]
    found += [Variant("area", k, "area", "splatam") for k in (0.2, 0.6, 0.8)]
    main, sweep = panel_groups(found)
    usual = Variant("area", 0.4, "area", "splatam")
    assert ratio_style(usual, main) == ratio_style(usual, sweep) == RATIO_STYLES[0]
    others = [ratio_style(Variant("area", k, "area", "splatam"), sweep) for k in (0.2, 0.6, 0.8)]
    assert len(set(others)) == 3 and RATIO_STYLES[0] not in others


def test_an_absolute_target_beside_its_ratio_runs_is_labelled_and_drawn_apart() -> None:
    """The scale study runs pocket at its keep ratio and at an absolute target (no keep ratio)."""
    from bench.report.style import series_label

    found = [
        Variant("none", None, "none", "default"),
        Variant("pocket", 0.4, "pocket", "default"),
        Variant("pocket", None, "pocket", "default"),
    ]
    panels = panel_groups(found)
    together = [p for p in panels if sum(v.strategy == "pocket" for v in p.variants) == 2]
    assert together
    ratio, absolute = (
        next(v for v in together[0].variants if v.strategy == "pocket" and (v.keep_ratio is None) == a)
        for a in (False, True)
    )
    assert series_label(absolute, together[0]).endswith("absolute target")
    assert series_label(ratio, together[0]).endswith("keep 0.4")
    assert ratio_style(ratio, together[0]) != ratio_style(absolute, together[0])


def test_a_strategy_has_one_colour_whatever_else_ran() -> None:
    assert strategy_colour("pocket") == strategy_colour("pocket", ["none", "my_prune"]) == COLOURS["pocket"]
    assert len(set(COLOURS.values())) == len(COLOURS)
    plugins = ["a_plugin", "b_plugin"]
    assert strategy_colour("a_plugin", plugins) != strategy_colour("b_plugin", plugins)


def test_seed_band_is_mean_and_sample_std_over_seeds(tmp_path: Path, make_run) -> None:
    for seed, peak in ((0, 100.0), (1, 200.0)):
        make_run(tmp_path / str(seed), strategy="none", seq="00", seed=seed, peak_mem_mib=peak)
    runs = collect([tmp_path]).runs
    x, mean, std, n, lost = seed_band(runs, lambda _r, kf: kf["torch_live_peak_mib"], lambda _w: None, {})
    assert n == 2 and not lost and list(x) == [0, 5, 10, 15]
    np.testing.assert_allclose(mean, 150.0 * np.array([0.7, 0.8, 0.9, 1.0]))
    np.testing.assert_allclose(std, np.std([[70, 80, 90, 100], [140, 160, 180, 200]], axis=0, ddof=1))


def test_redraw_needs_only_the_report_folder(tmp_path: Path, make_run) -> None:
    from bench.report import make_report

    for seed in (0, 1):
        make_run(tmp_path / "sweep" / f"n{seed}", strategy="none", seq="00", seed=seed)
        make_run(tmp_path / "sweep" / f"p{seed}", strategy="pocket", seq="00", seed=seed)
    made = make_report([tmp_path / "sweep"], tmp_path / "report")
    first = (tmp_path / "report" / "memory_per_keyframe_kitti_00.png").read_bytes()
    import shutil

    shutil.rmtree(tmp_path / "sweep")  # the run dirs are gone
    (tmp_path / "report" / "memory_per_keyframe_kitti_00.png").unlink()
    again = redraw(tmp_path / "report")
    names = {p.name for p in again.files}
    assert {"memory_per_keyframe_kitti_00.png", "gaussians_per_keyframe_kitti_00.png", "pareto_kitti.png"} <= names
    assert "trajectory_kitti_00.png" not in names  # needs the run dirs
    assert (tmp_path / "report" / "memory_per_keyframe_kitti_00.png").read_bytes() == first
    assert len(made.runs) == len(again.runs) == 4


def _pruned_npz(path: Path, kf: int, n_pruned: int) -> None:
    rng = np.random.default_rng(kf)
    image = rng.integers(0, 255, (12, 16, 3), dtype=np.uint8)
    np.savez_compressed(
        path / f"pruned_kf{kf:03d}.npz",
        image=image,
        before=image,
        after=image // 2,
        uv=rng.random((n_pruned, 2)).astype(np.float32) * 10,
        coverage=rng.random(n_pruned) + 0.5,
        n_pruned=n_pruned,
        n_before=100,
        kf=kf,
        frame=3 * kf,
        label="x",
    )


def test_pruned_figure_puts_strategies_on_their_last_common_keyframe(tmp_path: Path, make_run) -> None:
    none = make_run(tmp_path / "sweep" / "0", strategy="none", seq="00")
    pocket = make_run(tmp_path / "sweep" / "1", strategy="pocket", seq="00")
    make_run(tmp_path / "sweep" / "2", strategy="opacity", seq="00")  # ran without viz: left out
    for kf in (5, 10):
        _pruned_npz(none, kf, 0)
    for kf in (5, 10, 15):
        _pruned_npz(pocket, kf, 7)
    written = make_plots(collect([tmp_path / "sweep"]).runs, tmp_path / "out", lambda w: None)
    assert [p.name for p in written if p.name.startswith("pruned_")] == ["pruned_kitti_00_kf010.png"]


def test_literature_criteria_get_a_panel_of_their_own() -> None:
    from bench.names import LITERATURE

    paper = ("none", "pocket", "area", "opacity", "gradient", "mask")
    found = [Variant(s, 0.4, s, "default") for s in (*paper, *LITERATURE)]
    panels = panel_groups(found)
    assert [p.title for p in panels] == ["paper's methods", "literature"]
    assert {v.strategy for v in panels[1].variants} == {"none", *LITERATURE}
    assert all(len(p.variants) <= MAX_SERIES for p in panels)
    assert len(panel_groups([Variant(s, 0.4, s, "default") for s in ("none", *LITERATURE)])) == 1


def test_memory_policies_get_a_panel_of_their_own_with_todays_runs_beside_them():
    """Runs under another memory policy never join today's panel; their panel holds each strategy's run under
    today's policy first (solid, round), then its policies in the next styles, each named in the legend."""
    from bench.report.style import RATIO_STYLES, panel_groups, ratio_style, series_label

    found = [Variant("none", None, "none", "default"), Variant("pocket", 0.4, "pocket", "default")]
    found += [
        Variant("none", None, "none+disk", "default", "keyframes.residency=disk"),
        Variant("pocket", 0.4, "pocket+cap", "default", "densify.cap=30000"),
        Variant("pocket", 0.4, "pocket+cap+disk", "default", "keyframes.residency=disk, densify.cap=30000"),
    ]
    panels = panel_groups(found)
    assert [p.by_policy for p in panels] == [False, True]
    assert all(not v.memory_policy for v in panels[0].variants)
    policy = panels[1]
    assert [v.label for v in policy.variants] == ["none", "none+disk", "pocket", "pocket+cap", "pocket+cap+disk"]
    styles = [ratio_style(v, policy) for v in policy.variants]
    assert styles == [RATIO_STYLES[0], RATIO_STYLES[1], RATIO_STYLES[0], RATIO_STYLES[1], RATIO_STYLES[2]]
    assert series_label(policy.variants[4], policy).endswith("+ kf.residency=disk, cap=30000")
    assert series_label(policy.variants[0], policy).endswith("today's policy")


def test_absolute_targets_that_differ_in_floor_or_parameters_are_labelled_and_drawn_apart() -> None:
    """The regime study runs pocket at one absolute N_tar with and without a floor, with rank=random, and at a keep
    ratio, beside other criteria at the floored target: the main panel shows each strategy once (at the shared
    schedule), the schedule panel every pocket variant, each with its own style and a legend entry of its own."""
    from bench.report.style import series_label

    target, floor = "N_tar 166223/Mpx", "N_tar 166223/Mpx, floor 1/px"
    found = [Variant("none", None, "none", "default")]
    found += [Variant(s, None, s, "default", pruning=floor) for s in ("pocket", "opacity", "random")]
    found += [
        Variant("pocket", None, "p-nofloor", "default", pruning=target),
        Variant("pocket", None, "p-random", "default", pruning=floor + ", rank=random"),
        Variant("pocket", 0.4, "p-keep", "default"),
        Variant("pocket", None, "p-disk", "default", "keyframes.residency=disk", pruning=floor),
    ]
    main, sweep, policy = panel_groups(found)
    assert sorted(v.label for v in main.variants) == ["none", "opacity", "pocket", "random"]
    assert "by pruning schedule" in sweep.title
    pockets = [v for v in sweep.variants if v.strategy == "pocket"]
    assert len(pockets) == 4
    labels = {v.label: series_label(v, sweep) for v in pockets}
    assert len(set(labels.values())) == 4
    assert labels["p-nofloor"].endswith("N_tar 166223/Mpx, no floor, default rank")
    assert labels["p-random"].endswith("floor 1/px, rank=random")
    assert labels["p-keep"].endswith("keep 0.4, default rank")
    assert len({ratio_style(v, sweep) for v in pockets}) == 4
    usual = next(v for v in pockets if v.label == "pocket")
    assert ratio_style(usual, sweep) == ratio_style(usual, main) == RATIO_STYLES[0]
    assert [v.label for v in policy.variants] == ["pocket", "p-disk"]  # today's run at the same schedule only


def test_a_figure_that_draws_some_variants_names_and_styles_them_as_the_others_do() -> None:
    """The pareto figure draws only variants with a measured peak (every run of one lost: none); its legend
    leaves the lost one out but keeps the others' styles and names from the whole panel."""
    from matplotlib.lines import Line2D

    from bench.report.style import series_label, strategy_keys

    target, floor = "N_tar 166223/Mpx", "N_tar 166223/Mpx, floor 1/px"
    found = [Variant("none", None, "none", "default"), Variant("pocket", None, "p-floor", "default", pruning=floor)]
    found += [
        Variant("pocket", None, "p-lost", "default", pruning=target),
        Variant("pocket", None, "p-random", "default", pruning=floor + ", rank=random"),
    ]
    panels = panel_groups(found)
    shown = [v for v in found if v.label != "p-lost"]
    keys = strategy_keys(panels, ["none", "pocket"], shown=shown)
    labels = [k.get_label() for k in keys]
    sweep = next(p for p in panels if len(p.variants) > 2)
    lost = next(v for v in sweep.variants if v.label == "p-lost")
    assert series_label(lost, sweep) not in labels
    for v in (v for v in sweep.variants if v.strategy == "pocket" and v.label != "p-lost"):
        entry = keys[labels.index(series_label(v, sweep))]
        assert (entry.get_linestyle(), entry.get_marker()) == (
            Line2D([], [], ls=ratio_style(v, sweep)[0]).get_linestyle(),
            ratio_style(v, sweep)[1],
        )
