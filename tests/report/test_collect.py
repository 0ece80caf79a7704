"""Finding run dirs and reading metrics.json: tidy rows, malformed runs skipped, not fatal."""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd
import pytest

from bench.errors import BenchError
from bench.names import method_name, paper_sequence
from bench.report.collect import ReportError, collect, find_run_dirs, read_run


def test_runs_csv_has_one_row_per_usable_run(report, n_usable: int) -> None:
    runs = pd.read_csv(report.out / "runs.csv", dtype={"seq": str})
    assert len(runs) == n_usable
    for column in ("strategy", "dataset", "seq", "seed", "keep_ratio", "status", "peak_mem_mib", "fps", "path"):
        assert column in runs.columns
    assert runs.columns[-1] == "path"
    assert set(runs["status"]) == {"ok", "lost", "failed", "running"}
    assert "00" in set(runs["seq"])
    text = (report.out / "runs.csv").read_text()
    assert ",20,25.0," in text  # integer counts stay integers (ate_num_poses), floats stay floats


def test_malformed_run_is_skipped_and_named(report) -> None:
    assert len(report.skipped) == 1
    path, reason = report.skipped[0]
    assert path.parts[-2:] == ("broken", "0")
    assert "invalid json" in reason
    assert any("broken" in w and "skipped malformed run" in w for w in report.warnings)
    assert any("still running" in w for w in report.warnings)


def test_report_error_is_a_bench_error() -> None:
    assert issubclass(ReportError, BenchError)


def test_nested_dirs_are_found_once(tmp_path: Path, make_run) -> None:
    make_run(tmp_path / "a" / "b" / "0", strategy="none", seq="00")
    make_run(tmp_path / "c" / "1", strategy="pocket", seq="00")
    found = find_run_dirs([tmp_path, tmp_path / "a"])  # overlapping roots
    assert [p.name for p in found] == ["0", "1"]


def test_duplicate_runs_are_warned(tmp_path: Path, make_run) -> None:
    make_run(tmp_path / "a" / "0", strategy="none", seq="00", seed=3)
    make_run(tmp_path / "b" / "0", strategy="none", seq="00", seed=3)
    collection = collect([tmp_path])
    assert len(collection.runs) == 2
    assert any(w.startswith("duplicate run") and "seed" in w for w in collection.warnings)


def test_no_run_dirs_is_one_line_error(tmp_path: Path) -> None:
    with pytest.raises(ReportError, match="no run dirs found") as info:
        collect([tmp_path])
    assert "\n" not in str(info.value)


def test_missing_root_is_an_error(tmp_path: Path) -> None:
    with pytest.raises(ReportError, match="sweep dir not found"):
        collect([tmp_path / "nope"])


def test_only_malformed_runs_is_an_error(tmp_path: Path) -> None:
    (tmp_path / "0").mkdir()
    (tmp_path / "0" / "metrics.json").write_text("[1, 2]")
    with pytest.raises(ReportError, match="all malformed") as info:
        collect([tmp_path])
    assert "expected a json object" in str(info.value)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"status": "done"}, "expected status one of ok|lost|failed|running"),
        ({"run": {"strategy": "none", "seq": "00"}}, r"expected run.strategy and run.dataset"),
        ({"metrics": "oops"}, "expected a 'metrics' object"),
        ({"metrics": {"fps": "fast"}}, "expected a number or null for 'fps', found 'fast'"),
        ({"run": {"strategy": "none", "dataset": "kitti", "seq": "00", "seed": "zero"}}, "integer run.seed"),
    ],
)
def test_malformed_metrics_json_says_expected_and_found(tmp_path: Path, make_run, change: dict, message: str) -> None:
    run_dir = make_run(tmp_path / "0", strategy="none", seq="00")
    doc = json.loads((run_dir / "metrics.json").read_text())
    doc.update(change)
    (run_dir / "metrics.json").write_text(json.dumps(doc))
    with pytest.raises(ReportError, match=message):
        read_run(run_dir)


def test_failed_run_with_empty_metrics_is_a_row(tmp_path: Path, make_run) -> None:
    run_dir = make_run(tmp_path / "0", strategy="mask", seq="05", status="failed")
    row = read_run(run_dir)
    assert row["status"] == "failed"
    assert row["ate_rmse_m"] is None and row["peak_mem_mib"] is None
    assert row["error"] == "cuda out of memory"
    assert row["method"] == "MaskGaussian"


def test_harness_extras_are_kept_flat(tmp_path: Path, make_run) -> None:
    row = read_run(make_run(tmp_path / "0", strategy="pocket", seq="00"))
    assert row["phase_s.track"] == 10.0 and row["memory_method.torch_live"] is True
    assert (row["ate_first_frame"], row["ate_last_frame"]) == (0, 19) and row["peak_mem_source"] == "torch_live"
    assert row["keep_ratio"] == 0.4 and "metrics.keep_ratio" not in row  # same value as run.keep_ratio


def test_null_seq_is_the_default_sequence(tmp_path: Path, make_run) -> None:
    run_dir = make_run(tmp_path / "0", strategy="none", seq="00", dataset="synthetic")
    doc = json.loads((run_dir / "metrics.json").read_text())
    doc["run"]["seq"] = None
    (run_dir / "metrics.json").write_text(json.dumps(doc))
    assert read_run(run_dir)["seq"] == "default"


def test_method_names_follow_the_paper() -> None:
    assert method_name("none") == "LSG-SLAM baseline"
    assert method_name("pocket") == "Ours (w/ Tile Budget)"
    assert method_name("area") == "Ours (w/o Tile Budget)"
    assert method_name("opacity") == "LightGaussian"
    assert method_name("gradient") == "LP-3DGS"
    assert method_name("mask") == "MaskGaussian"
    assert method_name("third_party") == "third_party"


@pytest.mark.parametrize(
    ("dataset", "seq", "paper"),
    [
        ("kitti", "6", "06"),
        ("kitti", "06", "06"),
        ("euroc", "MH_01_easy", "MH01"),
        ("euroc", "MH01", "MH01"),
        ("euroc", "V1_01_micro", "V101"),
        ("tum", "fr2_desk", "fr2_desk"),
    ],
)
def test_sequences_map_to_the_paper_spelling(dataset: str, seq: str, paper: str) -> None:
    assert paper_sequence(dataset, seq) == paper
