"""Both regimes beside every comparison with the paper (bench/report/regime.py)."""

from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest

from bench.report import make_report, regime
from bench.report.blocks import get_block

REPO = Path(__file__).resolve().parents[2]


def test_the_paper_rows_come_with_both_regimes(report):
    text = (report.out / "tables.md").read_text()
    block = get_block(text, regime.BLOCK)
    assert block is not None and text.index(block) < text.index("(paper)")
    kitti = block[block.index("**kitti**") :]
    assert "| image | colour | grayscale (image_0/1" in kitti
    assert "| device | NVIDIA RTX A6000 (GPU) | cpu |" in kitti
    assert "| memory measure | torch.cuda.max_memory_allocated (CUDA allocator peak) |" in kitti
    assert (
        "| frames / keyframes | whole sequences | 20 frames / 4 keyframes (a clip, not the whole sequence) |" in kitti
    )
    assert "| pruning target | absolute N_tar (Gaussians kept per prune) | keep ratio 0.2, 0.4" in kitti
    assert "**euroc**" in block and "| resolution | full (752x480) |" in block  # the paper's EuRoC regime


def test_no_paper_rows_no_regime(sweep_dir, tmp_path):
    out = make_report([sweep_dir], tmp_path / "out").out
    assert get_block((out / "tables.md").read_text(), regime.BLOCK) is None


def test_our_regime_reads_the_runs():
    runs = pd.DataFrame(
        {
            "dataset": ["synthetic"] * 2,
            "eval_protocol": ["full", "full"],
            "dataset.width": [160, 160],
            "dataset.height": [96, 96],
            "num_frames": [400, 120],
            "num_keyframes": [134, 40],
            "device": ["cuda", "cuda"],
            "peak_mem_source": ["cuda_alloc", "cuda_alloc"],
            "slam_preset": ["default", "default"],
            "prune.target": ["absolute", "absolute"],
            "prune.n_target": [15000.0, 15000.0],
            "keep_ratio": [None, None],
        }
    )
    ours = regime.our_regime(runs)
    assert ours["resolution"] == "160x96"
    assert ours["frames / keyframes"] == "120-400 frames / 40-134 keyframes"
    assert ours["memory measure"] == "CUDA allocator peak (torch.cuda.max_memory_allocated)"
    assert ours["pruning target"] == "absolute N_tar 15000"
    assert "(the paper has no rows on it: its KITTI regime)" in regime.regime_markdown(runs)
    per_mpx = runs.assign(**{"prune.n_target": [None, None], "prune.n_target_per_mpx": [176359.0, 176359.0]})
    assert regime.our_regime(per_mpx)["pruning target"] == "absolute N_tar 176359 per Mpx"


COMMITTED = sorted(p.parent for p in (REPO / "reports").glob("*/runs.csv"))


@pytest.mark.parametrize("folder", COMMITTED, ids=lambda p: p.name)
def test_every_committed_comparison_with_the_paper_prints_both_regimes(folder, monkeypatch):
    monkeypatch.chdir(REPO)
    expected = regime.regime_markdown(pd.read_csv(folder / "runs.csv", low_memory=False)).rstrip()
    files = [folder / "scale.md"] if (folder / "scale.md").is_file() else []
    files += [folder / "tables.md"] if regime.paper_study(folder) else []
    for path in files:
        assert get_block(path.read_text(), regime.BLOCK) == expected, f"run: python -m bench.report.committed {folder}"


def test_committed_refresh_needs_a_folder_with_runs(tmp_path, capsys):
    from bench.report.committed import main

    assert main([]) == 2
    assert main([str(tmp_path)]) == 2
    assert capsys.readouterr().err.splitlines()[-1].startswith("error: expected a report folder with runs.csv")
