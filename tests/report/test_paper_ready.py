"""Paper-ready output: figure formats and dpi, names and metrics from --labels, human axis labels,
footnotes only for what occurs, readable one-sequence headers, and a compiled, rendered table page."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest
import yaml

from bench.names import METHOD_NAMES
from bench.report.__main__ import main
from bench.report.build import load_labels, make_report
from bench.report.collect import ReportError

PDF, SVG, PNG = b"%PDF-", b"<?xml", b"\x89PNG\r\n\x1a\n"
REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def one_seq(tmp_path_factory, make_run) -> Path:
    """A synthetic sweep of one scene: baseline and pocket, both ok, one seed."""
    root = tmp_path_factory.mktemp("one_seq")
    make_run(root / "0", strategy="none", seq="0", dataset="synthetic", keep_ratio=None, peak_mem_mib=100.0)
    make_run(root / "1", strategy="pocket", seq="0", dataset="synthetic", peak_mem_mib=80.0, ate_rmse_m=0.2)
    return root


def test_default_labels_file_holds_the_paper_names():
    labels = load_labels(REPO / "bench" / "report" / "labels.yaml")
    assert labels.methods == METHOD_NAMES
    assert labels.metrics is not None and "ate_rmse_m" in labels.metrics


def test_figures_in_every_format_and_dpi(one_seq, tmp_path):
    assert main([str(one_seq), "--out", str(tmp_path), "--format", "png,pdf,svg", "--dpi", "200"]) == 0
    for name in ("memory_per_keyframe_synthetic_0", "pareto_synthetic"):
        assert (tmp_path / f"{name}.pdf").read_bytes()[:5] == PDF
        assert (tmp_path / f"{name}.svg").read_bytes()[:5] == SVG
        assert (tmp_path / f"{name}.png").read_bytes()[:8] == PNG
    from matplotlib.image import imread

    low = make_report([one_seq], tmp_path / "low", dpi=50).out / "pareto_synthetic.png"
    assert imread(tmp_path / "pareto_synthetic.png").shape[1] == 4 * imread(low).shape[1]


def test_bad_format_is_one_line(one_seq, tmp_path, capsys):
    assert main([str(one_seq), "--out", str(tmp_path), "--format", "png,jpeg"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "expected figure formats among png, pdf, svg, found png, jpeg" in err


def test_one_sequence_header_and_only_occurring_footnotes(one_seq, tmp_path):
    md = make_report([one_seq], tmp_path).out / "tables.md"
    text = md.read_text()
    assert "| Metric | Method | scene 0 | Avg |" in text
    assert "tracking lost" not in text and "not run" not in text and "std" not in text and "k/n seqs" not in text
    assert "Bold: best measured value." in text
    assert "peak_mem_mib" not in text  # no internal field names in the notes


def test_lost_and_unavailable_cases_keep_their_footnotes(report):
    text = (report.out / "tables.md").read_text()
    assert "'-': tracking lost" in text and "'n/a': metric unavailable" in text and "sample std" in text


def test_labels_rename_methods_and_select_metrics(one_seq, tmp_path):
    labels = tmp_path / "labels.yaml"
    labels.write_text(yaml.safe_dump({"methods": {"pocket": "Pocket (ours)"}, "metrics": ["ate_rmse_m", "fps"]}))
    out = tmp_path / "out"
    assert main([str(one_seq), "--out", str(out), "--labels", str(labels)]) == 0
    text = (out / "tables.md").read_text()
    assert "Pocket (ours)" in text and "LSG-SLAM baseline" in text  # unnamed ones keep the paper's name
    blocks = {ln.split("|")[1].strip() for ln in text.splitlines() if ln.startswith("| ")} - {"", "Metric"}
    assert blocks == {"ATE [m] ↓", "FPS ↑", "FPS vs baseline"}, blocks
    assert "Ours (w/ Tile Budget)" not in text
    bad = tmp_path / "bad.yaml"
    bad.write_text("metrics: [ate, fps]\n")
    with pytest.raises(ReportError, match="expected metrics among .* found ate"):
        load_labels(bad)


def test_axis_labels_and_legends_are_human(one_seq, tmp_path):
    import matplotlib

    with matplotlib.rc_context({"svg.fonttype": "none"}):  # text as <text>, readable here
        make_report([one_seq], tmp_path, formats=("svg",))
    svg = (tmp_path / "memory_per_keyframe_synthetic_0.svg").read_text()
    assert "live torch tensors" in svg and "[MiB]" in svg and "torch_live_peak_mib" not in svg
    assert "map state [MiB]" in svg and "right axis" not in svg  # one y axis per panel, one quantity per row
    pareto = (tmp_path / "pareto_synthetic.svg").read_text()
    assert "peak memory [MiB]" in pareto and "dashed: Pareto front" in pareto  # both points are on the front
    assert "hollow" not in pareto  # explained only when a method misses a sequence


def test_rendered_table_page(report, tmp_path):
    """pdflatex compiles the tables and the rendered page holds the table's words."""
    pdflatex, pdftotext = shutil.which("pdflatex"), shutil.which("pdftotext")
    if pdflatex is None or pdftotext is None:
        pytest.skip("pdflatex/pdftotext not on PATH (apt: texlive-latex-base texlive-latex-recommended poppler-utils)")
    doc = tmp_path / "doc.tex"
    table = (report.out / "accuracy_kitti.tex").as_posix()
    doc.write_text(
        "\\documentclass{article}\n\\usepackage{booktabs}\n\\begin{document}\n"
        f"\\input{{{table}}}\n\\end{{document}}\n"
    )
    proc = subprocess.run(
        [pdflatex, "-interaction=nonstopmode", "-halt-on-error", doc.name],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0, [ln for ln in proc.stdout.splitlines() if ln.startswith("!")] or proc.stdout[-2000:]
    text = subprocess.run(
        [pdftotext, "-layout", "-f", "1", "-l", "1", "doc.pdf", "-"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=60,
    ).stdout
    for word in ("ATE", "PSNR", "LSG-SLAM baseline", "Ours (w/ Tile Budget)", "Avg", "tracking lost"):
        assert word in text, (word, text[:2000])
    assert "\\" not in text  # no unrendered LaTeX on the page


def test_a_pareto_per_sequence_keeps_each_routes_own_points(make_run, tmp_path):
    """Routes whose baselines differ: the per-route front holds that route's runs alone, the pooled one the means."""
    from unittest import mock

    from bench.report.collect import collect
    from bench.report.figures import pareto

    root = tmp_path / "runs"
    make_run(root / "0", strategy="none", seq="0", dataset="synthetic", keep_ratio=None, peak_mem_mib=100.0)
    make_run(root / "1", strategy="pocket", seq="0", dataset="synthetic", peak_mem_mib=80.0, ate_rmse_m=0.2)
    make_run(root / "2", strategy="none", seq="1", dataset="synthetic", keep_ratio=None, peak_mem_mib=300.0)
    make_run(root / "3", strategy="pocket", seq="1", dataset="synthetic", peak_mem_mib=200.0, ate_rmse_m=0.2)
    runs = collect([root]).runs
    low: list[float] = []  # each figure's memory axis, lower limit
    real_save = pareto.save_figure

    def keep(fig, path):
        low.append(fig.axes[0].get_xlim()[0])
        return real_save(fig, path)

    with mock.patch.object(pareto, "save_figure", keep):
        per_route = pareto.plot_pareto(runs, "synthetic", tmp_path, seq="1")
        pooled = pareto.plot_pareto(runs, "synthetic", tmp_path)
    assert per_route is not None and per_route.name == "pareto_synthetic_1.png"
    assert pooled is not None and pooled.name == "pareto_synthetic.png"
    assert low[0] > 150 > low[1]  # route 1's own points (200, 300) against the means over routes (140, 200)
