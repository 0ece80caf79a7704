"""The keyframe store's policies (slam.keyframes.*): rounding of compact precision, the window, disk residency."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from bench.datasets.synthetic import open_sequence
from bench.errors import ConfigError
from bench.slam.config import SlamConfig
from bench.slam.keyframes import KeyframeStore, KeyframeStoreConfig, compact, expand
from bench.slam.strategy import Strategy
from bench.slam.system import System

H, W = 8, 12
POSE_BYTES = 16 * 4  # a float32 [4, 4] pose per keyframe stays in memory under every policy


def images(seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    depth = torch.rand(H, W, generator=g) * 150
    depth[0] = 0  # no depth
    return torch.rand(H, W, 3, generator=g), depth


def test_compact_round_trip_is_within_the_stated_rounding() -> None:
    rgb, depth = images(0)
    back_rgb, back_depth = expand(*compact(rgb, depth))
    assert back_rgb.dtype == back_depth.dtype == torch.float32
    assert float((back_rgb - rgb).abs().max()) <= 0.5 / 255 + 1e-7
    rel = (back_depth - depth).abs() / depth.clamp_min(1e-6)
    assert float(rel[depth > 0].max()) <= 2**-11
    assert bool((back_depth[depth == 0] == 0).all())


def test_float32_images_come_back_as_the_same_tensors() -> None:
    rgb, depth = images(1)
    kf = KeyframeStore(KeyframeStoreConfig()).add(0, rgb, depth, torch.eye(4))
    got = kf.images()
    assert got[0] is rgb and got[1] is depth


def test_a_window_keeps_exactly_the_k_newest(tmp_path: Path) -> None:
    store = KeyframeStore(KeyframeStoreConfig(window=3, residency="disk"), tmp_path / "store")
    for i in range(7):
        store.add(10 * i, *images(i), torch.eye(4))
    assert [kf.kf for kf in store] == [4, 5, 6] and [kf.index for kf in store] == [40, 50, 60]
    assert len(store) == 3 and store.n_made == 7
    assert sorted(p.name for p in (tmp_path / "store").iterdir()) == ["kf_00004.pt", "kf_00005.pt", "kf_00006.pt"]


@pytest.mark.parametrize("precision", ["float32", "compact"])
def test_disk_residency_reads_back_identical_tensors(precision: str, tmp_path: Path) -> None:
    mem = KeyframeStore(KeyframeStoreConfig(precision=precision))
    disk = KeyframeStore(KeyframeStoreConfig(precision=precision, residency="disk"), tmp_path / "store")
    for i in range(3):
        for store in (mem, disk):
            store.add(i, *images(i), torch.eye(4))
    for a, b in zip(mem, disk, strict=True):
        assert b.rgb_stored is None and b.depth_stored is None  # only the pose and index stay in memory
        for x, y in zip(a.images(), b.images(), strict=True):
            assert x.dtype == y.dtype == torch.float32 and torch.equal(x, y)
    assert disk.memory_bytes() == 3 * POSE_BYTES
    assert disk.disk_bytes() == sum(p.stat().st_size for p in (tmp_path / "store").iterdir()) > 0
    assert mem.disk_bytes() == 0
    disk.close()
    assert not (tmp_path / "store").exists()


def test_compact_holds_five_of_sixteen_bytes_a_pixel() -> None:
    stores = {p: KeyframeStore(KeyframeStoreConfig(precision=p)) for p in ("float32", "compact")}
    for store in stores.values():
        store.add(0, *images(0), torch.eye(4))
    assert stores["float32"].memory_bytes() == 16 * H * W + POSE_BYTES
    assert stores["compact"].memory_bytes() == 5 * H * W + POSE_BYTES


def test_disk_residency_without_a_folder_is_one_line() -> None:
    with pytest.raises(ConfigError, match=r"^slam.keyframes.residency=disk: expected a folder .*, found none$"):
        KeyframeStore(KeyframeStoreConfig(residency="disk"))


@pytest.mark.parametrize(
    ("setting", "message"),
    [
        ({"precision": "half"}, "slam.keyframes.precision: expected one of float32, compact, found 'half'"),
        ({"window": 0}, "slam.keyframes.window: expected an integer >= 1 or null, found 0"),
        ({"residency": "tape"}, "slam.keyframes.residency: expected one of memory, disk, found 'tape'"),
    ],
)
def test_bad_store_settings_are_one_line(setting: dict, message: str) -> None:
    with pytest.raises(ConfigError) as err:
        SlamConfig(keyframes=setting)
    assert str(err.value) == message


def test_a_system_with_a_window_maps_refines_and_scores_over_the_keyframes_it_holds(tmp_path: Path) -> None:
    seq = open_sequence({"width": 48, "height": 32, "n_frames": 4, "supersample": 1})
    cfg = SlamConfig(
        tracking_iters=2,
        tracking_iters_first=2,
        mapping_iters=2,
        kf_every=1,
        keyframes={"window": 2, "residency": "disk", "precision": "compact"},
    )
    s = System(cfg, seq.K, seq.height, seq.width, Strategy(), 0.4, torch.device("cpu"), keyframe_dir=tmp_path / "kfs")
    results = [s.step(seq[i]) for i in range(4)]
    assert [r.keyframe_index for r in results] == [0, 1, 2, 3]  # numbered over the drive, not by what is held
    assert [kf.kf for kf in s.keyframes] == [2, 3] and s.keyframes.n_made == 4
    assert [i for i, _ in s.score_views("held_keyframes", frozenset())] == [2, 3]
    s.mapping.refine(2)
    assert s.disk_bytes() == {"state": 0, "keyframes": s.keyframes.disk_bytes()}
    assert s.keyframe_store_bytes() == 2 * POSE_BYTES


def pose_at(x_m: float, yaw_deg: float = 0.0) -> torch.Tensor:
    """w2c of a camera at (x_m, 0, 0) turned by ``yaw_deg`` about its y axis."""
    a = torch.tensor(yaw_deg).deg2rad()
    c2w = torch.eye(4)
    c2w[0, 0], c2w[0, 2], c2w[2, 0], c2w[2, 2] = a.cos(), a.sin(), -a.sin(), a.cos()
    c2w[0, 3] = x_m
    return torch.linalg.inv(c2w)


def test_a_new_submap_clears_the_store_past_its_distance_or_turn(tmp_path: Path) -> None:
    cfg = KeyframeStoreConfig(submap_reset_m=1.0, submap_reset_deg=30.0, residency="disk")
    store = KeyframeStore(cfg, tmp_path / "store")
    held = []
    for i, (x, yaw) in enumerate([(0, 0), (0.5, 0), (0.9, 20), (1.2, 0), (1.5, 0), (1.5, 40)]):
        store.add(i, *images(i), pose_at(x, yaw))
        held.append([kf.kf for kf in store])
    # 1.2 m from the first is a new submap; 40 degrees from the submap's first (at 1.2 m) another
    assert held == [[0], [0, 1], [0, 1, 2], [3], [3, 4], [5]]
    assert len(list((tmp_path / "store").iterdir())) == 1 and store.n_made == 6
