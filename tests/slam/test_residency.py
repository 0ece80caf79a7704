"""Map residency (bench/slam/residency.py): Gaussians far from the camera go to disk whole (parameters, Adam
moments, state) and come back whole, in a fixed order; a checkpoint carries them."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from bench.datasets.synthetic import open_sequence
from bench.errors import ConfigError
from bench.metrics.image import psnr_db
from bench.slam.config import SlamConfig
from bench.slam.gaussians import GaussianMap, ParamSpec
from bench.slam.residency import MapResidency, ResidencyConfig, ResidencyError
from bench.slam.se3 import inverse
from bench.slam.strategy import Strategy
from bench.slam.system import System


def at(z: float) -> torch.Tensor:
    """World-to-camera [4, 4] of a camera at (0, 0, z)."""
    w2c = torch.eye(4)
    w2c[2, 3] = -z
    return w2c


def make_map(per_kf: int = 4, n_kf: int = 3) -> GaussianMap:
    """A map of ``n_kf`` anchors, ``per_kf`` Gaussians each, after one Adam step (so moments exist)."""
    g = GaussianMap(
        torch.device("cpu"), extra={"mask_logits": ParamSpec(init=2.0, lr=0.1)}, state_dtypes={"score": torch.float32}
    )
    for kf in range(n_kf):
        ar = torch.arange(per_kf, dtype=torch.float32) + 10 * kf
        g.add(
            {
                "means": ar[:, None].repeat(1, 3),
                "log_scales": -ar[:, None].repeat(1, 3) / 100,
                "quats": torch.tensor([1.0, 0, 0, 0]).repeat(per_kf, 1),
                "opacity_logits": ar / 10,
                "colors": (ar[:, None].repeat(1, 3) / 40).clamp(0, 1),
            },
            keyframe=kf,
        )
    g.state["score"] += torch.arange(len(g), dtype=torch.float32)
    g.optimizer.zero_grad()
    sum((p * p).sum() for p in g.params.values()).backward()
    g.optimizer.step()
    return g


def snapshot(g: GaussianMap) -> dict[str, torch.Tensor]:
    out = {f"p.{k}": p.detach().clone() for k, p in g.params.items()}
    for k, p in g.params.items():
        for m in ("exp_avg", "exp_avg_sq"):
            out[f"{m}.{k}"] = g.optimizer.state[p][m].clone()
    out["birth_kf"] = g.birth_kf.clone()
    out["score"] = g.state["score"].clone()
    return out


def residency(tmp_path: Path, distance_m: float = 5.0, **kw) -> MapResidency:
    res = MapResidency(ResidencyConfig(policy="distance", distance_m=distance_m, **kw), tmp_path / "map_store")
    for kf in range(3):
        res.note_keyframe(kf, at(4.0 * kf))  # anchors at z = 0, 4, 8 m
    return res


def test_far_anchors_go_to_disk_and_come_back_whole_in_anchor_order(tmp_path: Path) -> None:
    g = make_map()
    before = snapshot(g)
    res = residency(tmp_path)
    assert res.check(g, at(8.0)) == (0, 4)  # anchor 0 is 8 m away: out; anchor 1 at 4 m stays
    assert g.birth_kf.tolist() == [1] * 4 + [2] * 4 and res.n_evicted() == 4
    assert res.disk_bytes() == (tmp_path / "map_store" / "kf000000.pt").stat().st_size > 0
    assert res.check(g, at(20.0)) == (0, 8)  # all three anchors are far now
    assert len(g) == 0 and res.n_evicted() == 12
    restored, written = res.check(g, at(0.0))  # anchors 0 and 1 are near again; 2 at 8 m goes nowhere
    assert (restored, written) == (8, 0)
    assert res.restore_all(g) == 4 and res.n_evicted() == 0 and res.disk_bytes() == 0
    assert not list((tmp_path / "map_store").glob("*.pt"))
    # ascending anchors, each in its original order: the map the run had, bit for bit, moments included
    after = snapshot(g)
    for k, v in before.items():
        assert torch.equal(after[k], v), k
    g.optimizer.zero_grad()
    sum((p * p).sum() for p in g.params.values()).backward()
    g.optimizer.step()  # Adam goes on over the restored rows


def test_hysteresis_keeps_an_anchor_on_disk_until_the_camera_is_nearer(tmp_path: Path) -> None:
    g = make_map()
    res = residency(tmp_path, distance_m=5.0, hysteresis_m=2.0)
    assert res.check(g, at(9.0)) == (0, 4)  # anchor 0 (9 m) goes; anchor 1 at 5 m is not farther than 5 m
    assert sorted(res.on_disk) == [0]
    assert res.check(g, at(4.0)) == (0, 0)  # anchor 0 at 4 m: within 5 m but not within 5 - 2 m
    assert res.check(g, at(2.5)) == (4, 4)  # anchor 0 back (2.5 m); anchor 2 at 5.5 m goes


def test_keep_in_view_holds_back_what_the_camera_sees(tmp_path: Path) -> None:
    """Anchor 0's Gaussians sit at z = 0-3 m: a camera at z = -1 m looking down +z sees those on its axis."""
    g = make_map()
    g.params["means"].data[:, :2] = 0.0  # every centre on the camera's axis
    g.params["means"].data[1, 0] = 50.0  # ... but one, far off to the side
    res = residency(tmp_path, distance_m=0.5)
    K = torch.tensor([[50.0, 0, 32], [0, 50.0, 24], [0, 0, 1]])
    restored, written = res.check(g, at(-1.0), K, (48, 64))
    assert (restored, written) == (0, 1) and res.n_evicted() == 1  # the one out of the image
    assert 1.0 not in g.params["means"][:, 2].tolist()  # it was Gaussian 1 (z = 1)
    res_all = MapResidency(ResidencyConfig(policy="distance", distance_m=0.5, keep_in_view=False), tmp_path / "b")
    for kf in range(3):
        res_all.note_keyframe(kf, at(4.0 * kf))
    n = len(g)
    assert res_all.check(g, at(-1.0), K, (48, 64)) == (0, n) and len(g) == 0


def test_a_checkpoint_holds_the_gaussians_on_disk_and_rewrites_them(tmp_path: Path) -> None:
    g = make_map()
    res = residency(tmp_path)
    res.check(g, at(8.0))
    sd = res.state_dict()
    # the store moves on after the checkpoint (anchor 0 comes back): the checkpoint still has it
    res.check(g, at(0.0))
    other = MapResidency(res.cfg, tmp_path / "resumed")
    other.load_state_dict(sd)
    assert other.n_evicted() == 4 and len(other.centres) == 3
    assert other.disk_bytes() == (tmp_path / "resumed" / "kf000000.pt").stat().st_size
    h = make_map()
    h.remove(h.birth_kf != 0)
    assert other.restore_all(h) == 4 and h.birth_kf.tolist() == [1] * 4 + [2] * 4 + [0] * 4


def test_the_whole_map_is_the_restored_map_and_leaves_the_live_one_alone(tmp_path: Path) -> None:
    """What a milestone scores under residency: the live map plus the store, in restore order, as a copy."""
    g = make_map()
    res = residency(tmp_path)
    res.check(g, at(20.0))  # all three anchors are far
    res.check(g, at(0.0))  # 0 and 1 come back, 2 (8 m away) stays on disk
    assert res.n_evicted() == 4
    live = snapshot(g)
    whole = res.whole_map(g)
    assert len(whole) == len(g) + 4 and res.n_evicted() == 4  # the store keeps its Gaussians
    for k, v in snapshot(g).items():
        assert torch.equal(v, live[k]), k  # the live map did not move
    res.restore_all(g)
    for k, p in g.params.items():
        assert torch.equal(whole.params[k].detach(), p.detach()), k
    assert torch.equal(whole.birth_kf, g.birth_kf) and torch.equal(whole.state["score"], g.state["score"])


def test_a_missing_store_file_is_one_line(tmp_path: Path) -> None:
    g = make_map()
    res = residency(tmp_path)
    res.check(g, at(8.0))
    (tmp_path / "map_store" / "kf000000.pt").unlink()
    with pytest.raises(ResidencyError, match=r"^map residency: expected the Gaussians of keyframe 0 in .*kf000000\.pt"):
        res.restore_all(g)


def test_settings_are_checked() -> None:
    with pytest.raises(ConfigError, match="slam.residency.policy: expected one of off, distance, found 'lru'"):
        SlamConfig(residency={"policy": "lru"})
    with pytest.raises(ConfigError, match="slam.residency.hysteresis_m: expected less than distance_m=5"):
        SlamConfig(residency={"policy": "distance", "distance_m": 5.0, "hysteresis_m": 5.0})
    assert SlamConfig().residency.policy == "off"


# ------------------------------------------------------------------------------------- a drive away and back
OUT_FRAMES = 16  # the straight street at 0.5 m a frame: 7.5 m out, then the same frames back to the start
DISTANCE_M = 6.0  # anchors 6 m behind go to disk: the first keyframes' Gaussians leave on the way out


@pytest.fixture(scope="module")
def drives(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[System, list, object]]:
    """The same drive with residency off and on. Tracking is replaced by the true pose, so that what differs
    between the two is the map alone; the way back replays the way out's frames in reverse order."""
    seq = open_sequence({"width": 64, "height": 48, "n_frames": OUT_FRAMES, "supersample": 1})
    c2w0 = seq[0].gt_c2w.float()
    order = [*range(OUT_FRAMES), *range(OUT_FRAMES - 2, -1, -1)]
    out = {}
    for policy in ("off", "distance"):
        cfg = SlamConfig(mapping_iters=15, residency={"policy": policy, "distance_m": DISTANCE_M})
        s = System(cfg, seq.K, seq.height, seq.width, Strategy(), 1.0, torch.device("cpu"))
        s.use_run_dir(tmp_path_factory.mktemp(policy))

        def true_pose(frame_index: int, *_args) -> tuple[torch.Tensor, float]:
            return inverse(inverse(c2w0) @ seq[frame_index].gt_c2w.float()), 0.0

        s.tracking.track = true_pose  # type: ignore[method-assign]
        results = [s.step(seq[i]) for i in order]
        out[policy] = (s, results, seq)
    return out


def test_a_milestone_renders_the_whole_map_and_the_run_goes_on_unchanged(drives) -> None:
    """``System.whole_map``: inside, the map holds the Gaussians on disk too (in restore order: the unit test
    above); after, the live map is the same object with the same tensors, so a milestone changes nothing."""
    s, _, _ = drives["distance"]
    assert s.n_evicted() > 0
    live, n_live = s.map, len(s.map)
    means = s.map.means.detach().clone()
    with torch.no_grad():
        alone = s.render(torch.eye(4)).color
        with s.whole_map():
            assert len(s.map) == n_live + s.n_evicted()
            whole = s.render(torch.eye(4)).color
    assert s.map is live and torch.equal(s.map.means.detach(), means)
    assert not torch.equal(whole, alone)  # the start's Gaussians are on disk: the live map alone lacks them


def test_a_drive_away_and_back_evicts_then_restores(drives) -> None:
    s, results, _ = drives["distance"]
    restored = [r.n_restored for r in results]
    assert max(r.n_restored for r in results[:OUT_FRAMES]) == 0
    assert sum(restored) > 0, "the way back brings the first keyframes' Gaussians back"
    assert s.n_evicted() > 0  # the far end of the drive is on disk when the drive ends at its start
    n_live = len(s.map)
    assert s.restore_all() == s.n_evicted() + (len(s.map) - n_live) and s.n_evicted() == 0


def test_the_revisited_start_renders_within_noise_of_a_run_without_residency(drives) -> None:
    """The start, seen again at the end of the drive, from the map of each run (the whole map, as the
    final evaluation renders it), scored against the true image. The two maps are not the same map (while
    its Gaussians were on disk the way out mapped without them), so their fidelity is compared, within the
    noise: the 0.3 dB tolerance is the spread of this PSNR over seeds 0-2 without residency (the figures, and
    each seed's difference with residency at 6 m, are in issue 44's closing note, not here, where they would drift)."""
    scores = {}
    for policy, (s, _, seq) in drives.items():
        s.restore_all()
        frame = seq[0]
        with torch.no_grad():
            out = s.render(torch.eye(4))  # frame 0's pose is the world's origin
        scores[policy] = psnr_db(out.color.clamp(0, 1), frame.rgb)
    assert abs(scores["distance"] - scores["off"]) < 0.3, scores
