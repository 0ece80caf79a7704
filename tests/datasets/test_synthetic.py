"""The embedded default dataset: deterministic from its seed, exact depth, a smooth drive."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from bench.datasets.synthetic import open_sequence
from bench.errors import ConfigError, DatasetError

SMALL = {"width": 64, "height": 48, "n_frames": 6, "supersample": 1}


def test_deterministic_from_seed():
    a, b = open_sequence({**SMALL, "seed": 3}), open_sequence({**SMALL, "seed": 3})
    c = open_sequence({**SMALL, "seed": 4})
    assert torch.equal(a[2].rgb, b[2].rgb) and torch.equal(a[2].depth_m, b[2].depth_m)
    assert not torch.equal(a[2].rgb, c[2].rgb)


def test_frames_and_depth_are_consistent_with_the_camera():
    seq = open_sequence(SMALL)
    f = seq[0]
    assert f.rgb.shape == (48, 64, 3) and f.depth_m.shape == (48, 64)
    assert 0 <= float(f.rgb.min()) and float(f.rgb.max()) <= 1
    assert (f.depth_m > 0).all()
    # the bottom row sees the road: z = h * fy / (v - cy) for a flat ground plane 1.6 m below
    K = seq.K
    v = 47
    z_expected = 1.6 * K[1, 1] / (v - K[1, 2])
    assert float(f.depth_m[v].median()) == pytest.approx(float(z_expected), rel=0.05)
    poses = np.stack([seq[i].gt_c2w.numpy() for i in range(len(seq))])
    steps = np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1)
    assert np.allclose(steps, 0.5, atol=0.05)  # speed_m_per_frame


def test_bad_size_is_a_config_error():
    with pytest.raises(ConfigError, match="dataset.width: expected an integer >= 16, found 8"):
        open_sequence({"width": 8})


# ---------------------------------------------------------------- routes and the culled cast
FIXTURE = Path(__file__).parent / "data" / "synthetic_default_80x48.npz"
KITTI06 = Path("data") / "trajectories" / "kitti" / "06.txt"  # under the shared fixture
TINY = {"width": 40, "height": 24, "supersample": 1}


def test_default_street_keeps_its_pixels():
    """Frames 0 and 39 of the default drive, rendered at 80x48 by the caster before routes and
    culling existed (brute force over all boxes), stored as float32: they must come out identical."""
    ref = np.load(FIXTURE)
    seq = open_sequence({"width": 80, "height": 48})
    for i in (0, 39):
        rgb, depth = seq.load(i)
        assert np.array_equal(rgb.numpy(), ref[f"rgb{i}"]) and np.array_equal(depth.numpy(), ref[f"depth{i}"])


@pytest.mark.parametrize(
    "cfg",
    [{"n_frames": 200}, {"n_frames": 200, "route": "grid"}, {"n_frames": 120, "route_file": KITTI06}],
    ids=["straight", "grid", "kitti06"],
)
def test_culled_cast_has_the_pixels_of_the_brute_force_cast(cfg, request):
    if "route_file" in cfg:
        cfg = {**cfg, "route_file": str(request.getfixturevalue("shared") / KITTI06)}
    seq = open_sequence({**TINY, **cfg})
    for i in (0, cfg["n_frames"] // 2, cfg["n_frames"] - 1):
        culled, brute = seq.render(seq.poses[i]), seq.render(seq.poses[i], brute_force=True)
        assert np.array_equal(culled[0], brute[0]) and np.array_equal(culled[1], brute[1])


def test_culled_cast_costs_the_same_however_long_the_drive():
    """Work (ray-box slab tests) per frame, not time: a frame of an 1,100-frame drive does about what
    a frame of a 40-frame drive does, where the brute-force cast does 8x more."""
    work = {}
    for n in (40, 1100):
        seq = open_sequence({**TINY, "n_frames": n})
        seq.render(seq.poses[20])
        work[n] = seq.slab_tests
        seq.slab_tests = 0
        seq.render(seq.poses[20], brute_force=True)
        work[n, "brute"] = seq.slab_tests
    assert work[1100, "brute"] > 5 * work[40, "brute"]
    assert work[1100] < 1.3 * work[40]


def test_grid_route_turns_and_revisits_its_first_street():
    seq = open_sequence({**TINY, "route": "grid", "n_frames": 400})
    pos = seq.poses[:, [0, 2], 3]  # [n, 2]
    fwd = seq.poses[:, [0, 2], 2]
    yaw = np.unwrap(np.arctan2(fwd[:, 0], fwd[:, 1]))
    assert abs(yaw[-1] - yaw[0]) > np.radians(300)  # round a block
    steps = np.linalg.norm(np.diff(pos, axis=0), axis=1)
    assert np.allclose(steps, 0.5, atol=0.15)  # 0.5 m along the centre line; swaying on a bend shifts it
    # a late frame stands where an early one stood, looking the same way: the revisit
    late, early = pos[350:], pos[:100]
    gap = np.linalg.norm(late[:, None] - early[None], axis=2)
    j, i = np.unravel_index(gap.argmin(), gap.shape)
    assert gap[j, i] < 1.0 and float(fwd[350 + j] @ fwd[i]) > 0.9
    # no box stands on a street or in the camera's way
    assert (seq.render(seq.poses[0])[1] > 2.0).all() and (seq.render(seq.poses[200])[1] > 2.0).all()


def test_grid_route_is_a_function_of_the_scene_seed():
    a, b, c = (open_sequence({**TINY, "route": "grid", "n_frames": 400, "seed": s}) for s in (1, 1, 2))
    assert np.array_equal(a.poses, b.poses) and np.array_equal(a.render(a.poses[300])[0], b.render(b.poses[300])[0])
    assert not np.array_equal(a.render(a.poses[30])[1], c.render(c.poses[30])[1])


def test_route_file_is_followed_on_the_ground(shared):
    path = shared / KITTI06
    seq = open_sequence({**TINY, "route_file": str(path), "n_frames": 50})
    gt = np.loadtxt(path, max_rows=50).reshape(-1, 3, 4)
    assert len(seq) == 50 and np.allclose(seq.poses[:, [0, 2], 3], gt[:, [0, 2], 3])
    assert np.allclose(seq.poses[:, 1, 3], 0.0)  # height dropped: the ground is a plane
    assert seq.source_files == (path,)
    assert (seq[10].depth_m > 0).all()


@pytest.mark.parametrize(
    "text,match",
    [
        ("1 0 0 0 0 1 0 0 0 0 1\n", "expected 12 finite numbers per line"),
        ("1 0 0 0 0 1 0 0 0 0 1 nan\n", "expected 12 finite numbers per line"),
        ("1 0 0 0 0 1 0 0 0 0 1 0\n" * 3, "expected at least n_frames=5 poses, found 3"),
    ],
)
def test_bad_route_file_is_a_one_line_dataset_error(tmp_path, text, match):
    path = tmp_path / "poses.txt"
    path.write_text(text)
    with pytest.raises(DatasetError, match=match) as err:
        open_sequence({**TINY, "route_file": str(path), "n_frames": 5})
    assert "\n" not in str(err.value)
    # a missing file is refused with the settings, before any dataset is opened
    with pytest.raises(ConfigError, match="dataset.route_file: expected an existing file, found no file"):
        open_sequence({**TINY, "route_file": str(tmp_path / "missing.txt"), "n_frames": 5})


def test_unknown_route_is_a_config_error():
    with pytest.raises(ConfigError, match="expected one of straight, grid, found 'loop'"):
        open_sequence({"route": "loop"})
