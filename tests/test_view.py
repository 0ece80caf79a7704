"""pocketbench view: a run dir read into splats, trajectories and keyframes (no viser needed), the
command's bad input, and the viser server on a tiny real run, checked through viser's own scene handles."""

from __future__ import annotations

import json
import shutil
import signal
import socket
import subprocess
import sys
import urllib.request

import numpy as np
import pytest
import torch
from plyfile import PlyData

from bench.errors import ConfigError
from bench.run.export import save_snapshot, write_map
from bench.run.figures.pruned_run import unproject
from bench.slam.raster import project
from bench.viewer import cli
from bench.viewer.scene import find_runs, read_run, splats_from_arrays
from tests.test_export import random_map
from tests.test_viz import run_tiny


def fake_run(path, strategy="none", with_map=True):
    """A run dir as far as the viewer reads it: metrics.json, and map.ply unless ``with_map`` is False."""
    path.mkdir(parents=True)
    (path / "metrics.json").write_text(json.dumps({"status": "ok", "run": {"strategy": strategy, "seq": "0"}}))
    if with_map:
        write_map(path / "map.ply", random_map(9))
    return path


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_splats_take_covariance_from_scales_and_quaternion_and_opacity_through_a_sigmoid():
    half = np.sqrt(0.5)
    arrays = {
        "means": np.array([[1, 2, 3], [0, 0, 0]], np.float32),
        "log_scales": np.log(np.array([[1, 2, 3], [1, 2, 3]], np.float32)),
        # identity, and 90 degrees about z (unnormalised: the map stores it as optimised)
        "quats": np.array([[2, 0, 0, 0], [half, 0, 0, half]], np.float32),
        "opacity_logits": np.array([0.0, np.log(3.0)], np.float32),
        "colors": np.array([[0.5, 1.2, -0.1], [0.1, 0.2, 0.3]], np.float32),
    }
    s = splats_from_arrays(arrays)
    np.testing.assert_allclose(s.covariances[0], np.diag([1, 4, 9]), atol=1e-5)
    np.testing.assert_allclose(s.covariances[1], np.diag([4, 1, 9]), atol=1e-5)  # x and y swap under the turn
    np.testing.assert_allclose(s.opacities[:, 0], [0.5, 0.75], atol=1e-6)
    np.testing.assert_array_equal(s.rgbs[0], [0.5, 1.0, 0.0])
    assert s.centers.shape == (2, 3) and s.opacities.shape == (2, 1)


def test_unproject_finds_the_world_point_the_rasterizer_projected():
    g = torch.Generator().manual_seed(1)
    angle = 0.3
    w2c = torch.eye(4)
    w2c[:3, :3] = torch.tensor(
        [[np.cos(angle), 0, np.sin(angle)], [0, 1, 0], [-np.sin(angle), 0, np.cos(angle)]], dtype=torch.float32
    )
    w2c[:3, 3] = torch.tensor([0.5, -0.2, 1.0])
    K = torch.tensor([[60.0, 0, 24.0], [0, 55.0, 16.0], [0, 0, 1]])
    means = torch.randn(50, 3, generator=g) + torch.tensor([0.0, 0.0, 8.0])
    uv, _, z = project(means, torch.eye(3).expand(50, 3, 3), w2c, K, 48, 32)
    np.testing.assert_allclose(unproject(uv, z, w2c, K).numpy(), means.numpy(), atol=1e-4)


def test_bad_input_is_one_line_and_exit_2(tmp_path, capsys, monkeypatch):
    fake_run(tmp_path / "nomap", with_map=False)
    (tmp_path / "empty").mkdir()
    cases = {
        str(tmp_path / "missing"): "expected a run dir or a sweep dir, found no directory",
        str(tmp_path / "empty"): "expected a run dir (metrics.json) or a sweep dir holding runs, found neither",
        str(tmp_path / "nomap"): "expected a map in",
    }
    for arg, expected in cases.items():
        assert cli.main([arg, "--port", "0"]) == 2
        err = capsys.readouterr().err
        assert err.startswith(f"error: {expected}") and err.count("\n") == 1, err
    good = str(fake_run(tmp_path / "good"))
    assert cli.main([good, "--keyframe", "3", "--port", "0"]) == 2  # no snapshot, no pruning record
    err = capsys.readouterr().err
    assert err.startswith("error: --keyframe: expected no keyframe steps (") and err.endswith("found 3\n"), err
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        assert cli.main([good, "--port", str(port)]) == 2
    err = capsys.readouterr().err
    assert err == f"error: --port: expected a free port, found {port} in use on 127.0.0.1\n"
    monkeypatch.setitem(sys.modules, "viser", None)  # import viser raises ImportError, as where it is not installed
    assert cli.main([good, "--port", "0"]) == 2
    err = capsys.readouterr().err
    assert err == 'error: the viewer needs viser, found it not installed: install it with pip install -e ".[view]"\n'


def test_pocketbench_view_dispatches_to_the_viewer(tmp_path):
    out = subprocess.run(
        [sys.executable, "-m", "bench", "view", str(tmp_path / "missing")], capture_output=True, text=True, timeout=120
    )
    assert out.returncode == 2
    assert out.stderr == f"error: expected a run dir or a sweep dir, found no directory at '{tmp_path / 'missing'}'\n"
    assert not list(tmp_path.iterdir())  # no run dir made: Hydra never ran


def test_a_sweep_lists_its_runs_and_run_picks_one(tmp_path, capsys):
    sweep = tmp_path / "multirun" / "s"
    a = fake_run(sweep / "+strategy=none", "none")
    b = fake_run(sweep / "+strategy=pocket", "pocket")
    assert find_runs(sweep) == [a, b]  # sorted by path
    [(runs, root, pick)] = cli.plan([sweep], ["pocket"])
    assert (runs, root, pick) == ([a, b], sweep, 1)
    out = capsys.readouterr().out.splitlines()
    assert out[0] == f"{sweep}: 2 runs (pick one on the page, or with --run N)"
    assert out[1:] == ["     0  +strategy=none: none seq=0", "  *  1  +strategy=pocket: pocket seq=0"]
    assert cli.plan([sweep], ["0"])[0][2] == 0
    bad = {"2": "expected a number from 0 to 1, found 2", "strategy": "holds 'strategy', found 2 runs"}
    for choice, expected in bad.items():
        with pytest.raises(ConfigError, match=f"^--run: .*{expected}$"):
            cli.plan([sweep], [choice])


@pytest.mark.slow
def _sigint_ignored() -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)


@pytest.mark.parametrize("inherited", ["default", "ignored"])
def test_ctrl_c_stops_the_viewer_cleanly(tiny_run, inherited):
    """Also when started with SIGINT ignored, as a shell without job control starts a background command (the
    full suite run in the background once timed out here: Python then raises no KeyboardInterrupt by itself)."""
    pytest.importorskip("viser")
    proc = subprocess.Popen(
        [sys.executable, "-m", "bench.view", str(tiny_run), "--port", "0"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=_sigint_ignored if inherited == "ignored" else None,
    )
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()
        while line and not line.startswith("serving"):  # viser's own banner comes first
            line = proc.stdout.readline()
        assert line.startswith("serving pocket") and "http://127.0.0.1:" in line, line
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=120)
    finally:
        proc.kill()
    assert proc.returncode == 0 and "Traceback" not in err, err


def test_a_run_does_not_import_the_viewer():
    code = (
        "import sys, bench.run.lifecycle, bench.cli.entry; "
        "print(sorted(m for m in sys.modules if m.startswith('bench.viewer') or m.split('.')[0] == 'viser'))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True)
    assert out.stdout.strip() == "[]"


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    """A tiny pocket run that keeps its map per keyframe and records its prunes."""
    return run_tiny(
        tmp_path_factory.mktemp("view"), "run", ["save_maps=every_keyframe", "viz.pruning=true", "viz.every=1"]
    )


@pytest.mark.slow
def test_scene_of_a_real_run(tiny_run):
    metrics = json.loads((tiny_run / "metrics.json").read_text())["metrics"]
    scene = read_run(tiny_run)
    n_ply = len(PlyData.read(str(tiny_run / "map.ply"))["vertex"].data)
    assert len(scene.splats) == n_ply == metrics["gaussians_final"]
    assert len(scene.traj_est) == len(scene.traj_gt) == metrics["num_frames"]
    assert [c.kf for c in scene.cameras] == list(range(metrics["num_keyframes"]))
    assert sorted(scene.snapshots) == list(range(metrics["num_keyframes"]))
    assert sorted(scene.pruned) == list(range(1, metrics["num_keyframes"]))
    assert all(c.image is not None and c.image.shape == (32, 48, 3) for c in scene.cameras[1:])
    for path in scene.pruned.values():
        with np.load(path) as r:
            assert r["xyz"].shape == (len(r["uv"]), 3)


@pytest.mark.slow
def test_viewer_serves_the_run(tiny_run):
    from bench.viewer.serve import Viewer

    pytest.importorskip("viser")
    metrics = json.loads((tiny_run / "metrics.json").read_text())["metrics"]
    port = free_port()
    viewer = Viewer([([tiny_run], tiny_run, 0)], host="127.0.0.1", port=port)
    try:
        assert viewer.port == port
        with urllib.request.urlopen(viewer.url, timeout=30) as page:  # the client, from the installed wheel
            assert page.status == 200 and b"<html" in page.read(2000).lower()
        nodes = viewer.slots[0].nodes
        # the splats viser holds for the page: one 32-byte record per Gaussian of the map
        assert nodes["map"].buffer.shape == (metrics["gaussians_final"], 8)
        assert len(nodes["traj_est"].points) + 1 == metrics["num_frames"]  # one segment between each two frames
        assert len(nodes["traj_gt"].points) + 1 == metrics["num_frames"]
        assert sum(name.startswith("kf_") for name in nodes) == metrics["num_keyframes"]
        assert "pruned" not in nodes  # the final map: no prune to show
        kf = max(viewer.steps)
        viewer.show(kf)
        with np.load(tiny_run / "maps" / f"kf_{kf:03d}.npz") as snap:
            assert nodes["map"].buffer.shape[0] == len(snap["means"])
        with np.load(tiny_run / f"pruned_kf{kf:03d}.npz") as record:
            assert len(nodes["pruned"].points) == len(record["xyz"]) > 0
            np.testing.assert_array_equal(nodes["pruned"].points, record["xyz"])
        viewer.show(None)
        assert nodes["map"].buffer.shape[0] == metrics["gaussians_final"] and "pruned" not in nodes
        with pytest.raises(ConfigError, match=r"^--keyframe: expected one of the keyframes 0, 1, .*found 99$"):
            viewer.show(99)
    finally:
        viewer.stop()


@pytest.mark.slow
def test_two_runs_side_by_side(tiny_run, tmp_path):
    from bench.viewer.serve import Viewer

    pytest.importorskip("viser")
    other = fake_run(tmp_path / "other")
    viewer = Viewer([([tiny_run], tiny_run, 0), ([other], other, 0)], port=0)
    try:
        a, b = viewer.slots
        assert a.nodes["map"].buffer.shape[0] == len(a.scene.splats) and b.nodes["map"].buffer.shape[0] == 9
        assert b.nodes["frame"].position[0] > 0 and not a.nodes["frame"].position.any()
        viewer.layout.value = "B only"
        assert not a.nodes["frame"].visible and b.nodes["frame"].visible and not b.nodes["frame"].position.any()
    finally:
        viewer.stop()


def test_a_snapshot_only_run_shows_its_last_snapshot(tmp_path):
    run_dir = fake_run(tmp_path / "r", with_map=False)
    save_snapshot(run_dir, 0, random_map(4))
    save_snapshot(run_dir, 1, random_map(6))
    scene = read_run(run_dir)
    assert len(scene.splats) == 6 and scene.steps == [0, 1] and scene.cameras == []


@pytest.mark.slow
def test_the_page_shows_the_map(tiny_run, tmp_path):
    """Headless Chromium draws the served page: the map is there (pixels off the white background)."""
    pytest.importorskip("viser")
    from matplotlib.image import imread

    from bench.viewer.screenshot import find_browser, screenshot
    from bench.viewer.serve import Viewer

    if find_browser() is None:
        pytest.skip("no Chromium on PATH (apt-get install chromium): the page is not screenshotted")
    viewer = Viewer([([tiny_run], tiny_run, 0)], port=0)
    try:
        png = screenshot(viewer.url, tmp_path / "page.png", wait_s=20.0, size=(1200, 800))
    finally:
        viewer.stop()
    pixels = imread(png)[..., :3]  # [H, W, 3] in [0, 1]
    scene = pixels[100:-100, 100:800]  # left of the GUI panel, clear of the corner axes
    drawn = (scene < 0.9).any(axis=-1).mean()
    assert drawn > 0.005, f"{drawn:.4f} of the scene's pixels off the background"


@pytest.mark.slow
def test_the_run_menu_switches_a_sweeps_run(tiny_run, tmp_path):
    pytest.importorskip("viser")
    from bench.viewer.serve import Viewer

    sweep = tmp_path / "multirun" / "s"
    fake_run(sweep / "0_failed", "none", with_map=False)
    fake_run(sweep / "a", "none")
    shutil.copytree(tiny_run, sweep / "b")
    [(runs, root, pick)] = cli.plan([sweep], None)
    assert pick == 1  # the first run with a map
    viewer = Viewer([(runs, root, pick)], port=0)
    try:
        slot, picker = viewer.slots[0], viewer.pickers["A"]
        assert slot.nodes["map"].buffer.shape[0] == 9 and viewer.steps == [] and picker.value == "a: none seq=0"
        picker.value = "0_failed: none seq=0"
        assert slot.scene.run_dir == sweep / "a" and "**error:** expected a map in" in viewer.legend.content
        picker.value = "b: pocket keep=0.4 seq=0"  # what picking it on the page does
        n_final = json.loads((sweep / "b" / "metrics.json").read_text())["metrics"]["gaussians_final"]
        assert slot.scene.run_dir == sweep / "b" and slot.nodes["map"].buffer.shape[0] == n_final
        assert viewer.steps and "traj_est" in slot.nodes
    finally:
        viewer.stop()


@pytest.mark.slow
def test_a_corrupt_snapshot_is_one_line_at_start_and_a_note_on_the_page(tiny_run, tmp_path, capsys):
    pytest.importorskip("viser")
    from bench.viewer.serve import Viewer

    broken = tmp_path / "broken"
    shutil.copytree(tiny_run, broken)
    (broken / "maps" / "kf_001.npz").write_bytes(b"not an npz")
    assert cli.main([str(broken), "--keyframe", "1", "--port", "0"]) == 2
    err = capsys.readouterr().err
    assert (
        err.startswith(f"error: expected '{broken / 'maps' / 'kf_001.npz'}' to hold the arrays")
        and err.count("\n") == 1
    )
    viewer = Viewer([([broken], broken, 0)], port=0)
    try:
        viewer.step_slider.value = viewer.steps.index(1)  # moved on the page
        assert "**error:** expected" in viewer.legend.content and "kf_001.npz" in viewer.legend.content
    finally:
        viewer.stop()
