"""LaTeX output: escaping, booktabs structure, and that it really compiles where pdflatex exists."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

from bench.report.render import tex_escape


def test_special_characters_are_escaped() -> None:
    assert tex_escape("50% a_b & c #1 $x {y} ~^\\") == (
        r"50\% a\_b \& c \#1 \$x \{y\} \textasciitilde{}\textasciicircum{}\textbackslash{}"
    )
    assert tex_escape("0.1 ± 0.2") == r"0.1 $\pm$ 0.2"


def test_tables_are_booktabs_floats_in_ascii(report) -> None:
    names = sorted(p.name for p in report.out.glob("*.tex"))
    assert names == ["accuracy_euroc.tex", "accuracy_kitti.tex", "performance_euroc.tex", "performance_kitti.tex"]
    for path in report.out.glob("*.tex"):
        text = path.read_text(encoding="utf-8")
        text.encode("ascii")  # any inputenc setting can read it
        for needle in (r"\begin{table}", r"\begin{tabular}", r"\toprule", r"\midrule", r"\bottomrule", r"\end{table}"):
            assert needle in text, (path.name, needle)
        assert "\\documentclass" not in text  # includable with \input
    kitti = (report.out / "accuracy_kitti.tex").read_text()
    assert r"my\_prune" in kitti and "my_prune" not in kitti
    assert r"\label{tab:accuracy_kitti}" in kitti


def test_latex_compiles(report, tmp_path: Path) -> None:
    pdflatex = shutil.which("pdflatex")
    if pdflatex is None:
        pytest.skip("pdflatex not on PATH (apt: texlive-latex-base texlive-latex-recommended)")
    inputs = "\n".join(rf"\input{{{p.as_posix()}}}" for p in sorted(report.out.glob("*.tex")))
    doc = tmp_path / "doc.tex"
    doc.write_text(
        "\\documentclass{article}\n\\usepackage{booktabs}\n\\begin{document}\n" + inputs + "\n\\end{document}\n"
    )
    proc = subprocess.run(
        [pdflatex, "-interaction=nonstopmode", "-halt-on-error", doc.name],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=60,
    )
    errors = [line for line in proc.stdout.splitlines() if line.startswith("!")]
    assert proc.returncode == 0, errors or proc.stdout[-2000:]
    assert (tmp_path / "doc.pdf").stat().st_size > 0
