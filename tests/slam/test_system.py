import pytest
import torch

from bench.datasets.base import Frame
from bench.datasets.synthetic import open_sequence
from bench.errors import TrackingLost
from bench.slam.system import SlamConfig, System
from bench.strategy import Strategy


@pytest.fixture(scope="module")
def seq():
    return open_sequence({"width": 48, "height": 32, "n_frames": 3, "supersample": 1})


def _system(seq, **kw) -> System:
    cfg = SlamConfig(**{"tracking_iters": 3, "tracking_iters_first": 3, "mapping_iters": 2, **kw})
    return System(cfg, seq.K, seq.height, seq.width, Strategy(), 0.4, torch.device("cpu"))


def test_a_frame_the_map_cannot_explain_is_lost_not_a_crash(seq):
    s = _system(seq, tracking_init="velocity", lost_patience=1)
    s.process(seq[0])
    s.process(seq[1])  # the true next frame is tracked
    inverted = seq[2]
    with pytest.raises(TrackingLost, match="colour residual"):
        s.process(Frame(inverted.index, inverted.timestamp_s, 1 - inverted.rgb, inverted.depth_m, None))


def _frame1_error_m(seq, **kw) -> float:
    s = _system(seq, tracking_init="velocity", **kw)
    s.process(seq[0])
    s.process(seq[1])
    gt = torch.from_numpy(seq.poses[0]).inverse() @ torch.from_numpy(seq.poses[1])  # frame 1 in frame 0's camera
    est = s.poses[1].double().inverse()
    return float((est[:3, 3] - gt[:3, 3]).norm())


def test_second_frame_is_tracked_with_its_own_iteration_count(seq):
    """The second frame has no velocity to extrapolate, so only tracking_iters_first moves it."""
    few, many = _frame1_error_m(seq, tracking_iters_first=1), _frame1_error_m(seq, tracking_iters_first=40)
    assert many < 0.5 * few, (few, many)
    assert _frame1_error_m(seq, tracking_iters_first=1, tracking_iters=40) == pytest.approx(few)


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


class _DropAll(Strategy):
    def after_mapping(self, ctx):
        return torch.zeros(len(ctx.gaussians), dtype=torch.bool, device=ctx.candidates.device)


def test_new_gaussians_survive_a_strategy_that_drops_everything(seq):
    """The core exempts the Gaussians a keyframe added, whatever the strategy's keep mask says."""
    s = System(SlamConfig(tracking_iters=2, tracking_iters_first=2, mapping_iters=1, kf_every=1), seq.K, seq.height,
               seq.width, _DropAll(), 0.4, torch.device("cpu"))
    first = s.process(seq[0])
    assert first.n_added > 0 and len(s.map) == first.n_added  # all new: nothing pruned
    second = s.process(seq[1])
    assert second.is_keyframe and len(s.map) == second.n_added > 0  # only this keyframe's additions remain
