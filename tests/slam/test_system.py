import io

import pytest
import torch

from bench.datasets.base import Frame
from bench.datasets.synthetic import open_sequence
from bench.errors import ConfigError, TrackingLost
from bench.slam.config import SlamConfig
from bench.slam.strategy import Strategy
from bench.slam.system import System


@pytest.fixture(scope="module")
def seq():
    return open_sequence({"width": 48, "height": 32, "n_frames": 3, "supersample": 1})


def _system(seq, **kw) -> System:
    cfg = SlamConfig(**{"tracking_iters": 3, "tracking_iters_first": 3, "mapping_iters": 2, **kw})
    return System(cfg, seq.K, seq.height, seq.width, Strategy(), 0.4, torch.device("cpu"))


def test_a_frame_the_map_cannot_explain_is_lost_not_a_crash(seq):
    s = _system(seq, tracking_init="velocity", lost_patience=1, lost_check="color")
    s.step(seq[0])
    s.step(seq[1])  # the true next frame is tracked
    inverted = seq[2]
    with pytest.raises(TrackingLost, match="colour residual"):
        s.step(Frame(inverted.index, inverted.timestamp_s, 1 - inverted.rgb, inverted.depth_m, None))


def _frame1_error_m(seq, **kw) -> float:
    s = _system(seq, tracking_init="velocity", **kw)
    s.step(seq[0])
    s.step(seq[1])
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
        s.step(seq[i])
    n, before = len(s.map), _keyframe_l1(s)
    s.mapping.refine(30)
    assert len(s.map) == n
    assert _keyframe_l1(s) < 0.9 * before, (before, _keyframe_l1(s))
    s.mapping.refine(0)  # a no-op, not an error


def test_refine_decays_every_rate_to_its_final_fraction_and_restores_mapping_s(seq, monkeypatch):
    s = _system(seq, kf_every=1, mapping_iters=1, refine_lr_final=0.01)
    for i in range(2):
        s.step(seq[i])
    opt = s.map.optimizer
    base = {g["name"]: g["lr"] for g in opt.param_groups}
    seen: list[dict[str, float]] = []
    step = opt.step

    def spy(*a, **k):
        seen.append({g["name"]: g["lr"] for g in opt.param_groups})
        return step(*a, **k)

    monkeypatch.setattr(opt, "step", spy)
    s.mapping.refine(5)
    assert len(seen) == 5
    for name, lr in base.items():
        assert seen[0][name] == pytest.approx(lr)
        assert seen[-1][name] == pytest.approx(0.01 * lr)
        assert seen[2][name] == pytest.approx(0.1 * lr)  # exponential: halfway in log
    assert {g["name"]: g["lr"] for g in opt.param_groups} == base


class _DropAll(Strategy):
    def after_mapping(self, ctx):
        return torch.zeros(len(ctx.gaussians), dtype=torch.bool, device=ctx.candidates.device)


def test_new_gaussians_survive_a_strategy_that_drops_everything(seq):
    """The core exempts the Gaussians a keyframe added, whatever the strategy's keep mask says."""
    s = System(
        SlamConfig(tracking_iters=2, tracking_iters_first=2, mapping_iters=1, kf_every=1),
        seq.K,
        seq.height,
        seq.width,
        _DropAll(),
        0.4,
        torch.device("cpu"),
    )
    first = s.step(seq[0])
    assert first.n_added > 0 and len(s.map) == first.n_added  # all new: nothing pruned
    second = s.step(seq[1])
    assert second.is_keyframe and len(s.map) == second.n_added > 0  # only this keyframe's additions remain


@pytest.fixture(scope="module")
def mapped_drive():
    """A system that tracked and mapped frames 0-6 of the straight street at 128x80 (keyframes 0, 3, 6), and the
    sequence; frame 11 is five frames past the last keyframe, so its far street end is not mapped yet."""
    seq = open_sequence({"width": 128, "height": 80, "n_frames": 12, "supersample": 1})
    cfg = SlamConfig(
        tracking_iters=20,
        tracking_iters_first=100,
        mapping_iters=60,
        lost_patience=1,
        tracking_init="velocity",
        lost_check="depth",
    )
    s = System(cfg, seq.K, seq.height, seq.width, Strategy(), 0.4, torch.device("cpu"))
    for i in range(7):
        s.step(seq[i])
    return s, seq


def _track_from(s: System, seq, j: int, kick_m: float) -> float:
    """Track frame ``j`` from its true pose moved sideways by ``kick_m``; the depth check's state is restored.
    Returns the colour L1 the old check (lost_check=color) would have read."""
    gt = (torch.from_numpy(seq.poses[0]).inverse() @ torch.from_numpy(seq.poses[j])).inverse().float()  # w2c
    kick = torch.eye(4)
    kick[0, 3] = kick_m
    rgb, depth = s.observe(seq[j])
    lost = s.tracking.lost
    recent, bad = list(lost.depth_recent), lost.bad_frames
    try:
        s.tracking.track(j, rgb, depth, s.poses, init=kick @ gt)
    finally:
        lost.depth_recent, lost.bad_frames = recent, bad
    return s.tracking.track_log[-1][1]


def test_depth_check_reads_a_metre_well_above_new_street(mapped_drive):
    s, seq = mapped_drive
    gt = (torch.from_numpy(seq.poses[0]).inverse() @ torch.from_numpy(seq.poses[11])).inverse().float()
    _, depth = s.observe(seq[11])
    unmapped = float(((s.render(gt).alpha < 0.5) & (depth > 0)).float().mean())
    assert unmapped > 0.02, unmapped  # the frame does show street the map has not seen
    # at the true pose: ideally quiet, but it reads just above its threshold, so not asserted (docs/architecture.md)
    try:
        _track_from(s, seq, 11, 0.0)
    except TrackingLost:
        pass
    log = s.tracking.track_log
    true_l1 = log[-1][3]
    for kick_m in (1.0, -1.0):
        with pytest.raises(TrackingLost, match="depth residual"):
            _track_from(s, seq, 11, kick_m)
        assert log[-1][3] > 1.5 * true_l1, (log[-1], true_l1)  # a metre reads well above new street
        # why not the colour check: a metre sideways leaves the colour L1 far below its threshold
        assert log[-1][1] < s.cfg.lost_residual / 2, log[-1]


def test_lost_check_is_a_checked_option():
    with pytest.raises(ConfigError, match="slam.lost_check"):
        SlamConfig(lost_check="colour")
    with pytest.raises(ConfigError, match="slam.lost_depth_ratio"):
        SlamConfig(lost_depth_ratio=1.0)


def test_checkpoint_state_carries_the_lost_detector(mapped_drive):
    """A resumed run judges its next frame against the same baseline and bad-frame count as the run that stopped."""
    s, seq = mapped_drive
    buf = io.BytesIO()
    torch.save(s.state_dict(), buf)
    buf.seek(0)
    back = System(s.cfg, seq.K, seq.height, seq.width, Strategy(), 0.4, torch.device("cpu"))
    back.load_state_dict(torch.load(buf, weights_only=True), seq.__getitem__)
    lost, back_lost = s.tracking.lost, back.tracking.lost
    assert len(lost.depth_recent) == 6
    assert back_lost.depth_recent == lost.depth_recent and back_lost.bad_frames == lost.bad_frames
    assert back.tracking.track_log == s.tracking.track_log and back_lost.depth_threshold_m() == lost.depth_threshold_m()


def test_the_system_is_made_of_parts_that_hold_what_they_read_not_the_system(seq):
    """``System`` is no mixin: tracking, mapping and the prune diagnostics are objects of their own, which hold
    the map, keyframe store, renderer and config they read; the one way back to the system is the prune
    context mapping asks for at the cap (``Mapping.prune_context``), a bound method passed in."""
    s = _system(seq)
    assert System.__mro__ == (System, object)
    parts = {"renderer": s.renderer, "tracking": s.tracking, "mapping": s.mapping, "diagnostics": s.diagnostics}
    for name, part in parts.items():
        held = vars(part)
        assert not any(value is s for value in held.values()), name
        assert held.get("map", s.map) is s.map and held.get("keyframes", s.keyframes) is s.keyframes, name
        assert held.get("renderer", s.renderer) is s.renderer and held.get("cfg", s.cfg) is s.cfg, name
    back = {
        (name, key)
        for name, part in parts.items()
        for key, v in vars(part).items()
        if getattr(v, "__self__", None) is s
    }
    assert back == {("mapping", "prune_context")}
    assert s.mapping.diagnostics is s.diagnostics and s.tracking.lost is not None
