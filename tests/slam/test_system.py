import math

import pytest
import torch

from bench.datasets.synthetic import open_sequence
from bench.errors import TrackingLost
from bench.slam.se3 import se3_exp
from bench.slam.system import SlamConfig, System
from bench.strategy import Strategy


@pytest.fixture(scope="module")
def seq():
    return open_sequence({"width": 48, "height": 32, "n_frames": 3, "supersample": 1})


def _system(seq, **kw) -> System:
    cfg = SlamConfig(**{"tracking_iters": 3, "tracking_iters_first": 3, "mapping_iters": 2, **kw})
    return System(cfg, seq.K, seq.height, seq.width, Strategy(), 0.4, torch.device("cpu"))


def test_turned_away_from_the_map_is_lost_not_a_crash(seq):
    s = _system(seq)
    s.process(seq[0])
    away = se3_exp(torch.tensor([0.0, 0.0, 0.0, 0.0, math.pi, 0.0])) @ s.poses[0]  # looking backwards
    with pytest.raises(TrackingLost, match="no Gaussian of the map is in view"):
        s._track(1, seq[1].rgb, seq[1].depth_m, init=away)


def test_second_frame_gets_its_own_iteration_count(seq, monkeypatch):
    s = _system(seq, tracking_iters_first=7)
    calls = []
    real = s.render
    monkeypatch.setattr(s, "render", lambda *a, **k: calls.append(1) or real(*a, **k))
    s.process(seq[0])
    n0 = len(calls)
    s.process(seq[1])  # no velocity yet: tracking_iters_first
    n1 = len(calls) - n0
    s.process(seq[2])  # constant velocity: tracking_iters
    n2 = len(calls) - n0 - n1
    kf1 = s.keyframes[-1].index == 1
    kf2 = s.keyframes[-1].index == 2
    # a keyframe adds one render for densification, mapping_iters for mapping and one for pruning
    assert n1 - (1 + 2 + 1) * kf1 == 7
    assert n2 - (1 + 2 + 1) * kf2 == 3


def _keyframe_l1(s: System) -> float:
    with torch.no_grad():
        return sum(float((s.render(kf.w2c).color - kf.rgb).abs().mean()) for kf in s.keyframes) / len(s.keyframes)


def test_refine_fits_the_keyframes_better_without_adding_gaussians(seq):
    s = _system(seq, kf_every=1, mapping_iters=1)
    for i in range(3):
        s.process(seq[i])
    n, before = len(s.map), _keyframe_l1(s)
    s.refine(30)
    assert len(s.map) == n
    assert _keyframe_l1(s) < 0.9 * before, (before, _keyframe_l1(s))
    s.refine(0)  # a no-op, not an error
