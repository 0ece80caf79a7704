"""Each report says which harness settings produced it: runs.csv columns and a tables.md section."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from bench.report.build import make_report
from bench.report.settings import read_settings
from tests.report.conftest import write_run

CONFIG = """\
slam:
  raster_backend: {backend}
  refine_iters: 0
  densify_silhouette: {sil}
prune:
  target: ratio
  every: keyframe
dataset:
  downscale: 4
threads: 1
determinism: strict
"""


def _run(root: Path, name: str, preset: str, backend: str, sil: float, **kw) -> None:
    run_dir = write_run(root / name, seq="06", slam_preset=preset, **kw)
    (run_dir / "config.yaml").write_text(CONFIG.format(backend=backend, sil=sil))


def test_settings_are_columns_and_a_section_per_preset(tmp_path: Path) -> None:
    _run(tmp_path / "sweep", "a", "default", "auto", 0.95, strategy="none", keep_ratio=None)
    _run(tmp_path / "sweep", "b", "splatam", "torch", 0.5, strategy="none", keep_ratio=None)
    _run(tmp_path / "sweep", "c", "splatam", "torch", 0.5, strategy="pocket")
    result = make_report([tmp_path / "sweep"], tmp_path / "out")
    runs = pd.read_csv(tmp_path / "out" / "runs.csv")
    by_preset = runs.groupby("slam_preset")["slam.raster_backend"].agg(set).to_dict()
    assert by_preset == {"default": {"auto (fused)"}, "splatam": {"torch"}}  # auto names what it chose
    assert set(runs["slam.densify_silhouette"]) == {0.95, 0.5}
    text = (tmp_path / "out" / "tables.md").read_text()
    section = text[text.index("## Harness settings") :]
    assert "| kitti | splatam | 2 | torch |" in section
    assert "`prune.every`" in section and "`slam.tracking_iters`" not in section  # unset keys are left out
    assert result.runs["slam.refine_iters"].tolist() == [0, 0, 0]


def test_run_without_config_has_empty_settings(tmp_path: Path) -> None:
    run_dir = write_run(tmp_path / "r", strategy="none", seq="06")
    assert set(read_settings(run_dir, "cpu").values()) == {None}


def test_ratio_plot_draws_the_preset_that_swept_the_ratio(tmp_path: Path) -> None:
    """The area sweep ran under splatam only; default-preset rows must not turn it off or join it."""
    for seed in (0, 1):
        for keep in (0.2, 0.4, 0.8):
            _run(
                tmp_path / "s",
                f"area{keep}_{seed}",
                "splatam",
                "auto",
                0.5,
                strategy="area",
                keep_ratio=keep,
                seed=seed,
                ate_rmse_m=0.1 + keep + seed / 100,
            )
        for preset in ("default", "splatam"):
            _run(tmp_path / "s", f"pocket_{preset}_{seed}", preset, "auto", 0.5, strategy="pocket", seed=seed)
            _run(
                tmp_path / "s",
                f"none_{preset}_{seed}",
                preset,
                "auto",
                0.5,
                strategy="none",
                keep_ratio=None,
                seed=seed,
            )
    make_report([tmp_path / "s"], tmp_path / "out")
    assert (tmp_path / "out" / "ratio_kitti.png").stat().st_size > 0


def test_cells_pooling_runs_of_different_settings_are_named(tmp_path: Path) -> None:
    """Seeds of one cell at two silhouette thresholds would be averaged as noise: the report says so."""
    for seed, sil in ((0, 0.5), (1, 0.95)):
        run_dir = write_run(tmp_path / "s" / f"r{seed}", strategy="none", seq="06", seed=seed, keep_ratio=None)
        (run_dir / "config.yaml").write_text(CONFIG.format(backend="auto", sil=sil))
    result = make_report([tmp_path / "s"], tmp_path / "out")
    expected = "2 runs pooled as seeds differ in slam.densify_silhouette (0.5, 0.95)"
    assert any(expected in w for w in result.warnings), result.warnings


def _input_run(root: Path, name: str, strategy: str, seed: int, downscale: int, mem: float, frames: int | None) -> None:
    run_dir = write_run(root / name, strategy=strategy, seq="06", seed=seed, keep_ratio=0.4, peak_mem_mib=mem)
    text = CONFIG.format(backend="auto", sil=0.5).replace("downscale: 4", f"downscale: {downscale}")
    (run_dir / "config.yaml").write_text(text + (f"max_frames: {frames}\n" if frames else ""))


def test_runs_of_another_input_are_other_rows_with_their_own_baseline(tmp_path: Path) -> None:
    """Two resolutions are two rows, never seeds of one (no pooling warning): each labelled by the input keys that
    differ, compared with the baseline of its own input, ranked for bold among its own input's rows."""
    from bench.report.collect import collect
    from bench.report.tables import build_tables
    from tests.report.test_tables import entry

    for i, (strategy, seed, downscale, mem, frames) in enumerate(
        [
            ("none", 0, 4, 200.0, None),
            ("none", 1, 4, 220.0, None),
            ("pocket", 0, 4, 120.0, None),
            ("pocket", 1, 4, 130.0, None),
            ("none", 0, 2, 800.0, 100),
            ("pocket", 0, 2, 400.0, 100),
            ("mask", 0, 1, 50.0, None),  # an input the baseline never read
        ]
    ):
        _input_run(tmp_path / "s", f"r{i}", strategy, seed, downscale, mem, frames)
    runs = collect([tmp_path / "s"]).runs
    assert set(runs["input"]) == {
        "dataset.downscale=4",
        "dataset.downscale=2, max_frames=100",
        "dataset.downscale=1",
    }
    result = make_report([tmp_path / "s"], tmp_path / "out")
    assert not any("pooled as seeds" in w for w in result.warnings), result.warnings
    perf = next(t for t in build_tables(runs)[0] if t.kind == "performance")
    low, high = "Ours (w/ Tile Budget) {downscale=4}", "Ours (w/ Tile Budget) {downscale=2, max_frames=100}"
    assert entry(perf, "Peak memory [MiB]", low, "06") == "**125.0 ± 7.1**"  # 2 seeds of one input pooled
    assert entry(perf, "Peak memory [MiB]", high, "06") == "**400.0**"  # best among its own input's rows
    assert entry(perf, "Memory vs baseline", low, "06") == "−40.5%"  # 125 / 210
    assert entry(perf, "Memory vs baseline", high, "06") == "−50.0%"  # 400 / 800, not / 210
    assert entry(perf, "Memory vs baseline", "MaskGaussian {downscale=1}", "06") == "n/a"
    assert any("of the same input" in n for n in perf.notes)
