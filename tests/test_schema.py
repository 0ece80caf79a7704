"""The run-directory schema: one source for the writer, the report reader and the docs' run-directory page."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from bench import schema
from bench.report.figures.runs import peak_column

PAGE = Path(__file__).resolve().parents[1] / "docs" / "run-directory.md"
BEGIN, END = "<!-- run-dir-schema:begin (python -m bench.schema) -->", "<!-- run-dir-schema:end -->"


def test_docs_tables_are_the_schema():
    text = PAGE.read_text()
    assert BEGIN in text and END in text, "docs/run-directory.md lacks the generated run-directory block"
    block = text.split(BEGIN, 1)[1].split(END, 1)[0].strip()
    assert block == schema.markdown().strip(), "docs/run-directory.md tables are stale: run python -m bench.schema"


def test_report_columns_are_schema_fields():
    from bench.report.collect import METRIC_KEYS

    assert set(METRIC_KEYS) <= set(schema.METRIC_NAMES)


def test_field_names_carry_units():
    for field in schema.METRIC_FIELDS + schema.KEYFRAME_FIELDS:
        suffix = {"m": "_m", "MiB": "_mib", "s": "_s", "dB": "_db", "deg": "_deg", "B": "_bytes"}.get(field.unit)
        if suffix:
            assert field.name.endswith(suffix), field


def test_headline_memory_prefers_the_device_figure():
    windows = [
        {
            "n_gaussians": 10,
            "state_mib": 1.0,
            "cpu_rss_peak_mib": 300.0,
            "torch_live_peak_mib": 50.0,
            "cuda_alloc_peak_mib": None,
            "cuda_reserved_peak_mib": None,
        },
        {
            "n_gaussians": 20,
            "state_mib": 2.0,
            "cpu_rss_peak_mib": 310.0,
            "torch_live_peak_mib": 60.0,
            "cuda_alloc_peak_mib": None,
            "cuda_reserved_peak_mib": None,
        },
    ]
    cpu = schema.memory_summary(windows, "cpu")
    assert (cpu["peak_mem_mib"], cpu["peak_mem_source"]) == (60.0, "torch_live")
    assert cpu["gaussians_peak"] == 20 and cpu["cpu_rss_peak_mib"] == 310.0
    no_live = [{**w, "torch_live_peak_mib": None} for w in windows]
    assert schema.memory_summary(no_live, "cpu")["peak_mem_source"] == "cpu_rss"
    on_cuda = [{**w, "cuda_alloc_peak_mib": 7.0, "torch_live_peak_mib": None} for w in windows]
    assert schema.memory_summary(on_cuda, "cuda")["peak_mem_source"] == "cuda_alloc"


def test_report_reads_the_column_the_writer_named():
    kf = pd.DataFrame(
        {
            "frame": [0, 3],
            "state_mib": [1.0, 2.0],
            "cpu_rss_peak_mib": [300.0, 310.0],
            "torch_live_peak_mib": [50.0, 60.0],
        }
    )
    for source, column in schema.PEAK_SOURCES.items():
        run = pd.Series({"peak_mem_source": source})
        assert peak_column(run, kf) == (column if column in kf.columns else None)
    assert peak_column(pd.Series({"peak_mem_source": None}), kf) is None


def test_score_view_columns_are_keyframe_fields():
    from bench.slam.system import index_ranges

    assert set(schema.SCORE_VIEW_COLUMNS) <= set(schema.KEYFRAME_COLUMNS)
    kinds = {f.name: f.kind for f in schema.KEYFRAME_FIELDS}
    assert kinds["n_score_views"] == "number" and kinds["score_views"] == "text"
    assert index_ranges([0, 1, 2, 3, 5, 7, 8, 9]) == "0-3;5;7-9" and index_ranges([4]) == "4"


def test_regime_descriptors_come_from_the_windows():
    rows = [
        {"n_added": 300, "n_gaussians": 300, "state_bytes": 300 * 248, "n_kf_held": 1, "torch_live_peak_mib": 10.0,
         "mem_state_mib": 2.0, "mem_keyframes_mib": 1.0, "mem_work_mib": 5.0},
        {"n_added": 100, "n_gaussians": 250, "state_bytes": 250 * 248, "n_kf_held": 2, "torch_live_peak_mib": 12.0,
         "mem_state_mib": 3.0, "mem_keyframes_mib": 2.0, "mem_work_mib": 6.0},
    ]  # fmt: skip
    d = schema.regime_summary(rows, (500, 1000), "torch_live")
    assert d["gaussians_added_per_kf_mpx"] == 400 / 2 / 0.5
    assert d["state_per_gaussian_bytes"] == 248.0  # at the largest map
    assert d["store_per_keyframe_bytes"] == 2.0 * schema.MIB / 2  # at the last window
    assert d["gaussian_share_of_peak"] == round((3.0 + 6.0) / 12.0, 4)
    assert schema.regime_summary(rows, (500, 1000), "cpu_rss")["gaussian_share_of_peak"] is None  # no parts there
    assert set(schema.regime_summary([], (1, 1), None)) == set(schema.REGIME_FIELDS)
