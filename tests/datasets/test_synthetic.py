"""The embedded default dataset: deterministic from its seed, exact depth, a smooth drive."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from bench.datasets.synthetic import open_sequence
from bench.errors import ConfigError

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
