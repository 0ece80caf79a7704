"""map.ply: the standard 3DGS layout, read back bit for bit; per-keyframe snapshots and their CLI."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from hydra import compose, initialize_config_dir
from plyfile import PlyData

from bench.cli.entry import CONF_DIR  # importing bench.cli.entry registers the config schemas
from bench.run.export import C0, PROPERTIES, export_keyframe, main, map_arrays, read_ply, save_snapshot, write_map
from bench.run.lifecycle import run
from bench.slam.gaussians import GaussianMap

TINY = [
    "dataset.width=48",
    "dataset.height=32",
    "dataset.n_frames=7",
    "slam.tracking_iters=4",
    "slam.mapping_iters=4",
    "eval.lpips=false",
    "progress=false",
    "threads=1",
]


def random_map(n: int = 257) -> GaussianMap:
    g = torch.Generator().manual_seed(0)
    gmap = GaussianMap(torch.device("cpu"))
    gmap.add(
        {
            "means": torch.randn(n, 3, generator=g) * 20,
            "log_scales": torch.randn(n, 3, generator=g) - 3,
            "quats": torch.randn(n, 4, generator=g),
            "opacity_logits": torch.randn(n, generator=g) * 4,
            "colors": torch.rand(n, 3, generator=g),
        },
        keyframe=0,
    )
    return gmap


def test_ply_has_the_standard_layout_and_round_trips_exactly(tmp_path):
    gmap = random_map()
    path = write_map(tmp_path / "map.ply", gmap)
    ply = PlyData.read(str(path))
    assert [e.name for e in ply.elements] == ["vertex"] and ply.byte_order == "<" and not ply.text
    names = [p.name for p in ply["vertex"].properties]
    assert names == list(PROPERTIES)
    assert names[:9] == ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
    assert names[-8:] == ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    assert sum(n.startswith("f_rest_") for n in names) == 45
    assert all(p.val_dtype in ("f4", "<f4", "float32", "float") for p in ply["vertex"].properties)
    v = ply["vertex"].data
    assert len(v) == len(gmap)
    for name in ["nx", "ny", "nz", *(f"f_rest_{i}" for i in range(45))]:
        assert not v[name].any()
    back, params = read_ply(path), gmap.params
    for key in ("means", "log_scales", "quats", "opacity_logits"):  # stored as they are: bit for bit
        assert np.array_equal(back[key], params[key].detach().numpy()), key
    expected_dc = ((params["colors"].detach() - 0.5) / C0).numpy()
    assert np.array_equal(back["f_dc"], expected_dc)
    # decoded the way viewers do, the colours come back to float32 rounding
    np.testing.assert_allclose(back["colors"], params["colors"].detach().numpy(), rtol=0, atol=1e-6)


def test_keyframe_snapshot_exports_the_same_map(tmp_path):
    gmap = random_map(31)
    save_snapshot(tmp_path, 4, gmap)
    path = export_keyframe(tmp_path, 4)
    assert path == tmp_path / "map_kf004.ply"
    back = read_ply(path)
    for key, value in map_arrays(gmap).items():
        if key != "colors":
            assert np.array_equal(back[key], value), key


def test_export_cli_bad_input_is_one_line(tmp_path, capsys):
    assert main([str(tmp_path / "missing"), "--keyframe", "3"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: expected a run dir") and err.count("\n") == 1
    save_snapshot(tmp_path, 2, random_map(5))
    assert main([str(tmp_path), "--keyframe", "3"]) == 2
    err = capsys.readouterr().err
    assert "keyframe 3" in err and "found snapshots of keyframes 2" in err and err.count("\n") == 1
    assert main([str(tmp_path), "--keyframe", "2", "--out", str(tmp_path / "two.ply")]) == 0
    assert (tmp_path / "two.ply").is_file()


@pytest.mark.slow
def test_run_writes_map_ply_and_snapshots(tmp_path):
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        cfg = compose(config_name="config", overrides=[*TINY, "save_maps=every_keyframe", "slam.refine_iters=0"])
    result = run(cfg, out_dir=tmp_path)
    assert result.status == "ok", result.error
    metrics = json.loads((tmp_path / "metrics.json").read_text())["metrics"]
    ply = PlyData.read(str(tmp_path / "map.ply"))
    assert len(ply["vertex"].data) == metrics["gaussians_final"]
    snapshots = sorted((tmp_path / "maps").glob("kf_*.npz"))
    assert len(snapshots) == metrics["num_keyframes"]
    last = np.load(snapshots[-1])
    assert np.array_equal(last["means"], read_ply(tmp_path / "map.ply")["means"])  # no refinement: same map
