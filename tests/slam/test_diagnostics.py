"""Per-keyframe diagnostics (keyframes.csv): what pruning saw and removed, what came back, and the
memory parts that add up to the window's peak."""

from __future__ import annotations

import csv
import math

import pytest
import torch

from bench import schema
from bench.cli.entry import compose
from bench.datasets.synthetic import open_sequence
from bench.run.lifecycle import run
from bench.slam.config import SlamConfig
from bench.slam.prune_diagnostics import REDUNDANT_WEIGHT
from bench.slam.strategy import PruneContext, Strategy, load_strategy
from bench.slam.system import FrameResult, System


@pytest.fixture(scope="module")
def seq():
    return open_sequence({"width": 48, "height": 32, "n_frames": 5, "supersample": 1})


def _run(seq, strategy: Strategy, keep: float = 0.4) -> tuple[list[FrameResult], list[PruneContext]]:
    seen: list[PruneContext] = []
    decide = strategy.after_mapping

    def recorded(ctx: PruneContext):
        seen.append(ctx)
        return decide(ctx)

    strategy.after_mapping = recorded
    cfg = SlamConfig(
        tracking_iters=3, tracking_iters_first=5, mapping_iters=3, kf_every=1, lost_min_silhouette_frac=0.0
    )
    system = System(cfg, seq.K, seq.height, seq.width, strategy, keep, torch.device("cpu"))
    return [system.step(seq[i]) for i in range(len(seq))], seen


def test_candidate_statistics_match_the_context_the_strategy_saw(seq):
    results, seen = _run(seq, load_strategy("area", {}))
    for res, ctx in zip(results[1:], seen[1:], strict=True):
        cand = ctx.candidates
        w, cov = ctx.raster.max_weight[cand], ctx.raster.coverage[cand]
        assert res.diag["n_redundant"] == int((w <= REDUNDANT_WEIGHT).sum())
        assert res.diag["cand_w_q2"] == pytest.approx(float(torch.quantile(w.float(), 0.5)))
        q = [res.diag[f"cand_cov_q{k}"] for k in (1, 2, 3)]
        assert q == sorted(q) and q[0] >= float(cov.min()) and q[2] <= float(cov.max())
        assert 0 <= res.diag["n_pruned_redundant"] <= res.diag["n_redundant"] <= res.n_candidates
        assert res.n_pruned > 0 and res.diag["n_hole_px"] > 0  # area pruning of 60% opens pixels
        assert 0 <= res.diag["n_reseeded_holes"] <= res.n_added
    assert sum(r.diag["n_reseeded_holes"] for r in results) > 0  # the default rule refills what was opened


def test_nothing_pruned_opens_no_hole_and_reseeds_nothing(seq):
    results, _ = _run(seq, load_strategy("none", {}))
    assert all(r.n_pruned == 0 and r.diag["n_hole_px"] == 0 and r.diag["n_pruned_redundant"] == 0 for r in results)
    assert all(r.diag["n_reseeded_holes"] == 0 for r in results)


class _PruneEverything(Strategy):
    def after_mapping(self, ctx: PruneContext) -> torch.Tensor:
        return ~ctx.candidates


def test_removing_every_old_gaussian_opens_the_pixels_it_covered(seq):
    results, _ = _run(seq, _PruneEverything())
    res = results[1]
    assert res.n_pruned == res.n_candidates > 0
    assert res.diag["n_pruned_redundant"] == res.diag["n_redundant"]
    assert res.diag["n_hole_px"] > 0.3 * seq.height * seq.width


@pytest.mark.slow
def test_memory_parts_add_up_to_the_peak(tmp_path):
    cfg = compose(
        [
            "+strategy=pocket",
            "dataset.width=48",
            "dataset.height=32",
            "dataset.n_frames=7",
            "slam.tracking_iters=4",
            "slam.mapping_iters=4",
            "slam.refine_iters=0",
            "eval.lpips=false",
            "progress=false",
            "threads=1",
        ]
    )
    result = run(cfg, out_dir=tmp_path)
    assert result.status == "ok", result.error
    rows = list(csv.DictReader(open(tmp_path / schema.KEYFRAMES_FILE)))
    assert list(rows[0]) == schema.KEYFRAME_COLUMNS
    for row in rows:
        parts = [float(row[c]) for c in schema.MEMORY_PART_COLUMNS]
        assert math.isclose(sum(parts), float(row["torch_live_peak_mib"]), abs_tol=0.003)
        assert all(p >= 0 for p in parts)
        assert float(row["mem_state_mib"]) >= float(row["state_mib"])  # at its largest, before the prune
    assert any(int(r["n_hole_px"]) > 0 for r in rows) and any(int(r["n_reseeded_holes"]) > 0 for r in rows)
