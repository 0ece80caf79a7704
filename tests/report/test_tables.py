"""The paper-layout tables: marks, bold best, seeds, relative figures and paper rows, by hand."""

from __future__ import annotations

import io
from importlib import resources
from pathlib import Path

import pandas as pd
import pytest

from bench.report.cells import Table
from bench.report.collect import collect
from bench.report.paper import load_paper_tables
from bench.report.render import format_cell, to_markdown
from bench.report.tables import build_tables

SHARED_PAPER = Path(__file__).resolve().parents[2].parent / "shared" / "paper" / "pocket_slam_tables.csv"


def table(report, kind: str, dataset: str) -> Table:
    return next(t for t in report.tables if t.kind == kind and t.dataset == dataset)


def entry(tab: Table, block: str, label: str, column: str, target: str = "md") -> str:
    """The printed entry of one cell, found by block title, row label and column name."""
    blk = next(b for b in tab.blocks if b.title == block)
    row = next(r for r in blk.rows if r.label == label)
    return format_cell(row.cells[tab.columns.index(column)], blk, target)  # type: ignore[arg-type]


POCKET = "Ours (w/ Tile Budget) (keep 0.4)"


def test_rows_use_the_paper_names_in_paper_order(report) -> None:
    labels = [r.label for r in table(report, "accuracy", "kitti").blocks[0].rows if not r.paper]
    assert labels == [
        "LSG-SLAM baseline",
        "LightGaussian",
        "MaskGaussian",
        "Ours (w/ Tile Budget) (keep 0.2)",
        POCKET,
        "my_prune",  # third-party strategies keep their own name, after the built-ins
    ]


def test_columns_are_sequences_then_avg(report) -> None:
    assert table(report, "accuracy", "kitti").columns == ["00", "05", "Avg"]
    assert table(report, "performance", "euroc").columns == ["MH_01_easy", "Avg"]


def test_best_per_column_is_bold(report) -> None:
    acc = table(report, "accuracy", "kitti")
    # † : with two seeds a side, 0.090 vs 0.110 ± 0.014 cannot be told from seed noise
    assert entry(acc, "ATE [m]", POCKET, "00") == "**0.090 ± 0.000**†"
    assert entry(acc, "ATE [m]", POCKET, "00", "tex") == r"\textbf{0.090\,$\pm$\,0.000}$^\dagger$"
    assert entry(acc, "ATE [m]", "LSG-SLAM baseline", "00") == "0.110 ± 0.014"
    assert entry(acc, "PSNR [dB]", POCKET, "Avg") == "**26.00**†"  # per-seed averages 26, 26 vs 24.5, 25
    perf = table(report, "performance", "kitti")
    assert entry(perf, "FPS", "Ours (w/ Tile Budget) (keep 0.2)", "00") == "**2.50**"


def test_a_column_where_all_tie_has_no_bold(report) -> None:
    acc = table(report, "accuracy", "kitti")
    ssim = next(b for b in acc.blocks if b.title == "SSIM")
    assert not any(row.cells[0].bold for row in ssim.rows)


def test_lost_is_a_dash_null_is_na_failed_is_failed(report) -> None:
    acc = table(report, "accuracy", "kitti")
    assert entry(acc, "ATE [m]", "LightGaussian", "05") == "-"
    assert entry(acc, "LPIPS", "LightGaussian", "00") == "n/a"
    assert entry(acc, "ATE [m]", "MaskGaussian", "00") == "failed"
    assert entry(acc, "ATE [m]", "my_prune", "05") == ""  # never ran
    perf = table(report, "performance", "kitti")
    assert entry(perf, "Peak memory [MiB]", "LightGaussian", "05") == "-"
    assert entry(perf, "Memory vs baseline", "LightGaussian", "05") == "-"


def test_mean_and_sample_std_over_seeds(report) -> None:
    acc = table(report, "accuracy", "kitti")
    # ATE 0.10, 0.12 -> mean 0.11, sample std 0.01414; PSNR 25, 26 -> 25.5 +- 0.7071
    assert entry(acc, "ATE [m]", "LSG-SLAM baseline", "00") == "0.110 ± 0.014"
    assert entry(acc, "PSNR [dB]", "LSG-SLAM baseline", "00") == "25.50 ± 0.71"
    assert entry(acc, "ATE [m]", "LightGaussian", "00") == "0.500"  # one seed: no std
    # two ok seeds (0.19, 0.21) and one lost seed, which is counted but not averaged
    assert entry(acc, "ATE [m]", POCKET, "05") == "**0.200 ± 0.014**† (1/3 lost)"


def test_avg_is_over_sequences_with_a_value(report) -> None:
    acc = table(report, "accuracy", "kitti")
    assert entry(acc, "ATE [m]", "LSG-SLAM baseline", "Avg") == "0.155"  # (0.11 + 0.20) / 2
    # lost on 05: the paper's convention averages the rest, we say so and do not rank it
    assert entry(acc, "ATE [m]", "LightGaussian", "Avg") == "0.500 (1/2 seqs)"
    assert entry(acc, "ATE [m]", "my_prune", "Avg") == "0.150 (1/2 seqs)"


def test_relative_to_baseline_by_hand(report) -> None:
    perf = table(report, "performance", "kitti")
    # memory: baseline 00 mean(1000, 1100) = 1050, 05 = 2000; pocket 00 mean(400, 420) = 410, 05 = 800
    assert entry(perf, "Memory vs baseline", POCKET, "00") == "−61.0%"  # 410 / 1050 - 1 = -60.95 %
    assert entry(perf, "Memory vs baseline", POCKET, "05") == "−60.0%"  # 800 / 2000 - 1
    assert entry(perf, "Memory vs baseline", POCKET, "Avg") == "−60.3%"  # 605 / 1525 - 1 = -60.33 %
    assert entry(perf, "Memory vs baseline", POCKET, "Avg", "tex") == r"$-$60.3\%"
    # FPS: baseline 00 mean(1.0, 1.2) = 1.1, 05 = 0.5; pocket 00 mean(2.0, 2.4) = 2.2, 05 = 1.5
    # 2.2 vs 1.1 on two seeds a side (Welch p = 0.07): within noise; 05 has no spread at all: not
    assert entry(perf, "FPS vs baseline", POCKET, "00") == "×2.00†"
    assert entry(perf, "FPS vs baseline", POCKET, "05") == "×3.00"
    assert entry(perf, "FPS vs baseline", POCKET, "Avg") == "×2.31"  # 1.85 / 0.8 = 2.3125
    # LightGaussian lost 05: its Avg compares the one sequence both have, 500 / 1050 - 1
    assert entry(perf, "Memory vs baseline", "LightGaussian", "Avg") == "−52.4% (1/2 seqs)"
    assert entry(perf, "Memory vs baseline", "LSG-SLAM baseline", "00") == "ref"
    block = next(b for b in perf.blocks if b.title == "Memory vs baseline")
    row = next(r for r in block.rows if r.label == POCKET)
    assert row.cells[-1].mean == pytest.approx((605 / 1525 - 1) * 100)


def test_missing_baseline_drops_relative_blocks_with_a_warning(report) -> None:
    tables, warnings = build_tables(report.runs, baseline="nosuch")
    perf = next(t for t in tables if t.kind == "performance" and t.dataset == "kitti")
    assert [b.title for b in perf.blocks] == ["Peak memory [MiB]", "FPS", "Gaussians at end", "Peak Gaussians"]
    assert any("no runs of baseline strategy 'nosuch'" in w for w in warnings)


def test_other_baseline_is_honoured(report) -> None:
    tables, _ = build_tables(report.runs, baseline="my_prune")
    perf = next(t for t in tables if t.kind == "performance" and t.dataset == "kitti")
    assert entry(perf, "Memory vs baseline", "my_prune", "00") == "ref"
    assert entry(perf, "Memory vs baseline", "LightGaussian", "00") == "−28.6%"  # 500 / 700 - 1


def test_baseline_at_several_keep_ratios_pairs_by_ratio(tmp_path: Path, make_run) -> None:
    from bench.report.collect import collect

    for i, (strategy, keep, mem) in enumerate(
        [
            ("none", 0.2, 1000.0),
            ("none", 0.4, 800.0),
            ("pocket", 0.2, 250.0),
            ("pocket", 0.4, 400.0),
            ("mask", 0.3, 500.0),
        ]
    ):
        make_run(tmp_path / str(i), strategy=strategy, seq="00", keep_ratio=keep, peak_mem_mib=mem)
    tables, warnings = build_tables(collect([tmp_path]).runs)
    perf = next(t for t in tables if t.kind == "performance")
    assert entry(perf, "Memory vs baseline", "Ours (w/ Tile Budget) (keep 0.2)", "00") == "−75.0%"  # 250 / 1000
    assert entry(perf, "Memory vs baseline", "Ours (w/ Tile Budget) (keep 0.4)", "00") == "−50.0%"  # 400 / 800
    assert entry(perf, "Memory vs baseline", "MaskGaussian", "00") == "−50.0%"  # no 0.3 baseline: the first one
    assert entry(perf, "Memory vs baseline", "LSG-SLAM baseline (keep 0.4)", "00") == "ref"
    assert any("several keep ratios" in w for w in warnings)


def test_presets_are_separate_rows_compared_with_their_own_baseline(tmp_path: Path, make_run) -> None:
    from bench.report.collect import collect

    for i, (strategy, preset, mem, final) in enumerate(
        [
            ("none", None, 1000.0, 9000),
            ("pocket", None, 900.0, 8800),
            ("none", "splatam", 600.0, 4000),
            ("pocket", "splatam", 300.0, 3000),
        ]
    ):
        make_run(
            tmp_path / str(i),
            strategy=strategy,
            seq="00",
            keep_ratio=0.4,
            slam_preset=preset,
            peak_mem_mib=mem,
            gaussians_final=final,
        )
    runs = collect([tmp_path]).runs
    assert sorted(runs["slam_preset"]) == ["default", "default", "splatam", "splatam"]  # old runs: default
    tables, _ = build_tables(runs)
    perf = next(t for t in tables if t.kind == "performance")
    assert entry(perf, "Peak memory [MiB]", "Ours (w/ Tile Budget) [splatam]", "00") == "**300.0**"  # not pooled
    assert entry(perf, "Memory vs baseline", "Ours (w/ Tile Budget) [default]", "00") == "−10.0%"  # 900 / 1000
    assert entry(perf, "Memory vs baseline", "Ours (w/ Tile Budget) [splatam]", "00") == "−50.0%"  # 300 / 600
    assert entry(perf, "Gaussians at end", "Ours (w/ Tile Budget) [splatam]", "00") == "**3000**"
    assert entry(perf, "Peak Gaussians", "LSG-SLAM baseline [default]", "00") == "1200"


def test_paper_rows_sit_beside_measured_rows(report) -> None:
    acc = table(report, "accuracy", "kitti")
    labels = [r.label for r in acc.blocks[0].rows]
    assert labels.index("(paper) LSG-SLAM") == labels.index("LSG-SLAM baseline") + 1
    assert labels.index("(paper) Ours (w/ Tile Budget)") == labels.index(POCKET) + 1
    assert "(paper) LP-3DGS" in labels  # paper methods we did not run still show
    paper = pd.read_csv(resources.files("bench.report").joinpath("paper_tables.csv").open(), dtype=str)

    def printed(table_: str, dataset: str, method: str, metric: str, seq: str) -> str:
        hit = paper[
            (paper.table == table_)
            & (paper.dataset == dataset)
            & (paper.method == method)
            & (paper.metric == metric)
            & (paper.sequence == seq)
        ]
        return hit["value"].item()

    assert entry(acc, "ATE [m]", "(paper) LSG-SLAM", "00") == printed("accuracy", "kitti", "LSG-SLAM", "ATE", "00")
    assert entry(acc, "ATE [m]", "(paper) LightGaussian", "00") == "-"  # lost in the paper too
    euroc = table(report, "accuracy", "euroc")  # MH_01_easy is the paper's MH01
    assert entry(euroc, "PSNR [dB]", "(paper) LSG-SLAM", "MH_01_easy") == printed(
        "accuracy", "euroc", "LSG-SLAM", "PSNR", "MH01"
    )
    perf = table(report, "performance", "kitti")
    gb = printed("performance", "kitti", "Ours", "Memory_GB", "05")
    assert entry(perf, "Peak memory [MiB]", "(paper) Ours", "05") == f"{gb} GB"
    base_gb = float(printed("performance", "kitti", "LSG-SLAM", "Memory_GB", "05"))
    rel = (float(gb) / base_gb - 1) * 100
    assert entry(perf, "Memory vs baseline", "(paper) Ours", "05") == f"−{abs(rel):.1f}%"
    assert not any(c.bold for r in acc.blocks[0].rows if r.paper for c in r.cells)
    assert "(paper) LSG-SLAM" in (report.out / "tables.md").read_text()
    assert r"\textit{(paper) LSG-SLAM}" in (report.out / "accuracy_kitti.tex").read_text()


def test_paper_ssim_stands_beside_our_ms_ssim(report) -> None:
    """The paper's "SSIM" is its base system's MS-SSIM: it fills the MS-SSIM block, not ours."""
    acc = table(report, "accuracy", "kitti")
    titles = [b.title for b in acc.blocks]
    assert titles == ["ATE [m]", "PSNR [dB]", "SSIM", "MS-SSIM", "LPIPS"]
    paper = pd.read_csv(resources.files("bench.report").joinpath("paper_tables.csv").open(), dtype=str)
    printed = paper[
        (paper.table == "accuracy")
        & (paper.dataset == "kitti")
        & (paper.method == "LSG-SLAM")
        & (paper.metric == "SSIM")
        & (paper.sequence == "00")
    ]["value"].item()
    assert entry(acc, "MS-SSIM", "(paper) LSG-SLAM", "00") == printed
    assert not any(r.paper for r in next(b for b in acc.blocks if b.title == "SSIM").rows)
    assert any("eval.protocol=splatam" in n for n in acc.notes) and "splatam" in acc.caption


def test_full_protocol_runs_stand_without_paper_rows(tmp_path, make_run) -> None:
    """Runs scored on the whole image (and runs from before protocols) get no paper accuracy rows, and a
    line saying why; the paper's memory rows stay, since the protocol does not touch them."""
    make_run(tmp_path / "0", strategy="none", seq="00", keep_ratio=None, eval_protocol="full")
    make_run(tmp_path / "1", strategy="pocket", seq="00")  # written before eval.protocol existed
    runs = collect([tmp_path]).runs
    assert list(runs["eval_protocol"]) == ["full", "full"]
    tables, _ = build_tables(runs, load_paper_tables())
    acc = next(t for t in tables if t.kind == "accuracy")
    assert not any(r.paper for b in acc.blocks for r in b.rows)
    assert "MS-SSIM" not in [b.title for b in acc.blocks]  # no run has it, no paper row fills it
    why = [n for n in acc.notes if n.startswith("(paper) rows left out")]
    assert len(why) == 1 and "eval.protocol=full" in why[0]
    text = to_markdown(acc)
    assert "(paper)" not in text.replace("(paper) rows left out", "") and "eval.protocol=full" in text
    perf = next(t for t in tables if t.kind == "performance")
    assert any(r.paper for b in perf.blocks for r in b.rows) and "eval.protocol=full" in perf.caption


def test_mixed_protocols_get_a_table_each(tmp_path, make_run) -> None:
    for i, protocol in enumerate(("full", "splatam", "released")):
        make_run(
            tmp_path / f"none_{i}",
            strategy="none",
            seq="00",
            keep_ratio=None,
            eval_protocol=protocol,
            psnr_db=20.0 + i,
            ms_ssim=0.8,
        )
    runs = collect([tmp_path]).runs
    tables, warnings = build_tables(runs, load_paper_tables())
    names = [t.name for t in tables]
    assert names == [
        f"{kind}_kitti_{p}" for p in ("full", "splatam", "released") for kind in ("accuracy", "performance")
    ]
    for t in tables:  # one protocol per table, every cell one run: nothing pooled across protocols
        assert t.protocol in t.name and f"eval.protocol={t.protocol}" in t.caption
    for t in (t for t in tables if t.kind == "accuracy"):
        psnr_db = 20.0 + ("full", "splatam", "released").index(t.protocol)
        assert entry(t, "PSNR [dB]", "LSG-SLAM baseline", "00") == f"{psnr_db:.2f}"
        assert any(r.paper for b in t.blocks for r in b.rows) == (t.protocol != "full")
    assert any("several eval.protocol values (full, splatam, released)" in w for w in warnings)
    assert not any("duplicate run" in w for w in collect([tmp_path]).warnings)


def test_no_paper_rows_without_the_flag(report) -> None:
    tables, _ = build_tables(report.runs)
    assert not any(row.paper for t in tables for b in t.blocks for row in b.rows)
    assert "(paper)" not in to_markdown(tables[0])


def test_packaged_paper_table_matches_shared_copy() -> None:
    if not SHARED_PAPER.is_file():
        pytest.skip(f"shared paper table not found at {SHARED_PAPER}")
    packaged = resources.files("bench.report").joinpath("paper_tables.csv").read_text(encoding="utf-8")
    assert packaged == SHARED_PAPER.read_text(encoding="utf-8")
    frame = pd.read_csv(io.StringIO(packaged), dtype=str, keep_default_na=False)
    assert list(frame.columns) == ["table", "dataset", "method", "metric", "sequence", "value"]
