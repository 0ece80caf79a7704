"""``slam.mapping_schedule=first`` (the released code's control flow): mapping iterations on the first
keyframe only; later keyframes densify and prune, and the map's old Gaussians are left as they are."""

from __future__ import annotations

import dataclasses

import pytest
import torch

from bench.cli.entry import compose
from bench.datasets.synthetic import open_sequence
from bench.errors import ConfigError
from bench.run.config import to_run_config
from bench.slam.config import SlamConfig
from bench.slam.strategy import PruneConfig, load_strategy
from bench.slam.system import System


def _system(schedule: str) -> tuple[System, object]:
    seq = open_sequence({"width": 48, "height": 32, "n_frames": 4, "supersample": 1})
    cfg = SlamConfig(
        tracking_iters=3,
        tracking_iters_first=5,
        mapping_iters=3,
        kf_every=1,
        lost_min_silhouette_frac=0.0,
        mapping_schedule=schedule,
    )
    prune = PruneConfig(target="absolute", n_target=200, every="frame")
    return System(cfg, seq.K, seq.height, seq.width, load_strategy("area", {}), prune, torch.device("cpu")), seq


@pytest.mark.parametrize("schedule", ["keyframes", "first"])
def test_mapping_runs_on_the_first_keyframe_only_when_asked(schedule, monkeypatch):
    system, seq = _system(schedule)
    calls: list[int] = []
    mapper = system.mapping
    optimize = mapper._optimize
    monkeypatch.setattr(mapper, "_optimize", lambda kf, iters, pick: (calls.append(kf), optimize(kf, iters, pick)))
    results = [system.step(seq[i]) for i in range(len(seq))]
    assert all(r.is_keyframe for r in results)
    assert calls == ([0] if schedule == "first" else [0, 1, 2, 3])
    assert all(r.n_added > 0 for r in results)  # densification goes on at every frame
    assert sum(r.n_pruned for r in results[1:]) > 0  # and so does pruning to the absolute target


def test_without_mapping_the_surviving_gaussians_keep_their_values():
    system, seq = _system("first")
    system.step(seq[0])
    before = {k: v.detach().clone() for k, v in system.map.params.items()}
    n0 = len(system.map)
    system.step(seq[1])
    old = system.map.birth_kf == 0
    assert 0 < int(old.sum()) <= n0
    kept = torch.nonzero(old).squeeze(1)
    # which of the first keyframe's Gaussians survived: the ones pruning kept, in order
    first = before["means"]
    assert all(
        torch.equal(system.map.params[k][kept], before[k][_survivors(first, system.map.params["means"][kept])])
        for k in before
    )


def _survivors(first: torch.Tensor, kept_means: torch.Tensor) -> torch.Tensor:
    """Rows of ``first`` [N, 3] equal to each row of ``kept_means`` [M, 3] (unchanged values)."""
    eq = (first[None] == kept_means[:, None]).all(-1)  # [M, N]
    assert bool(eq.any(1).all())
    return eq.float().argmax(1)


def test_released_experiment_uses_it_and_bad_values_are_refused():
    cfg = to_run_config(compose(["+experiment=released"]))
    assert cfg.slam.mapping_schedule == "first" and cfg.slam.kf_every == 1
    assert cfg.prune.target == "absolute" and cfg.prune.every == "frame"
    with pytest.raises(ConfigError, match="slam.mapping_schedule: expected one of keyframes, first, found 'never'"):
        SlamConfig(mapping_schedule="never")


@pytest.mark.parametrize("draw", ["alternate", "uniform"])
def test_mapping_draw_decides_the_newest_keyframes_share(draw, monkeypatch):
    """``slam.mapping_draw``: ``alternate`` fits the newest keyframe at every even iteration; ``uniform`` draws
    each iteration from the whole window, the newest one of them, as SplaTAM's mapping loop does."""
    seq = open_sequence({"width": 48, "height": 32, "n_frames": 4, "supersample": 1})
    cfg = SlamConfig(
        tracking_iters=2, tracking_iters_first=3, mapping_iters=1, kf_every=1, lost_min_silhouette_frac=0.0
    )
    system = System(cfg, seq.K, seq.height, seq.width, load_strategy("none", {}), 1.0, torch.device("cpu"))
    for i in range(4):
        system.step(seq[i])
    mapper = system.mapping
    mapper.cfg = dataclasses.replace(system.cfg, mapping_draw=draw, mapping_iters=400)
    drawn: list[int] = []
    monkeypatch.setattr(mapper, "_optimize", lambda kf, iters, pick: drawn.extend(pick(it).kf for it in range(iters)))
    mapper.map_keyframe(3)
    newest = sum(k == 3 for k in drawn) / len(drawn)
    if draw == "alternate":
        assert newest == 0.5 and drawn[0::2] == [3] * 200
    else:
        assert 0.18 < newest < 0.32 and set(drawn) == {0, 1, 2, 3}  # 1/4 of 400 draws, within 3 std
