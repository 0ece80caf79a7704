"""Microsoft 7-Scenes loader on the shared 1,000 real frames (../shared/data/sevenscenes/seq).

Bad-input cases break a copy in tmp_path (images linked, text files copied; a broken file replaces
its link), never the shared data.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from bench.datasets import canonical_seq, sevenscenes
from bench.errors import DatasetError

N_COPY = 6  # frames in a tmp copy


@pytest.fixture(scope="module")
def real(request: pytest.FixtureRequest) -> Path:
    """The shared sequence folder; skipped where it is absent."""
    shared = request.getfixturevalue("shared")
    seq = shared / "data" / "sevenscenes" / "seq"
    if not (seq / "frame-000000.pose.txt").is_file():
        pytest.skip(f"7-Scenes frames not found at {seq}")
    return seq


@pytest.fixture(scope="module")
def full(real: Path) -> sevenscenes.SevenScenesSequence:
    return sevenscenes.open_sequence({"root": str(real.parent), "seq": "seq", "downscale": 1})


@pytest.fixture
def copy(real: Path, tmp_path: Path) -> Path:
    """A writable root ``tmp/7s`` with ``seq/`` holding the first N_COPY frames (images linked)."""
    seq = tmp_path / "7s" / "seq"
    seq.mkdir(parents=True)
    shutil.copy(real / "camera-intrinsics.txt", seq)
    for n in range(N_COPY):
        for suffix in ("color.jpg", "depth.png"):
            (seq / f"frame-{n:06d}.{suffix}").symlink_to(real / f"frame-{n:06d}.{suffix}")
        shutil.copy(real / f"frame-{n:06d}.pose.txt", seq)
    return tmp_path / "7s"


def _open(root: Path, seq: str = "seq", **kw) -> sevenscenes.SevenScenesSequence:
    return sevenscenes.open_sequence({"root": str(root), "seq": seq, **kw})


def _own(path: Path) -> Path:
    """``path`` as a file of the test's own (a link is replaced by a copy of its target)."""
    if path.is_symlink():
        target = path.resolve()
        path.unlink()
        shutil.copy(target, path)
    return path


def _one_line(exc: pytest.ExceptionInfo[DatasetError], *parts: str) -> str:
    msg = str(exc.value)
    assert "\n" not in msg and msg.startswith("sevenscenes") and "expected" in msg and "found" in msg, msg
    for part in parts:
        assert part in msg, msg
    return msg


# --------------------------------------------------------------------------- the real frames
def test_shapes_intrinsics_and_timestamps(full, real):
    assert full.name == "sevenscenes/seq" and len(full) == 1000 and full.has_gt
    assert (full.width, full.height) == (640, 480)
    np.testing.assert_allclose(full.K.numpy(), [[585, 0, 320], [0, 585, 240], [0, 0, 1]])
    np.testing.assert_allclose(full.timestamps_s[[0, 1, 999]], [0.0, 1 / 30, 999 / 30])
    frame = full[0]
    assert frame.rgb.shape == (480, 640, 3) and frame.rgb.dtype == torch.float32
    assert 0.0 <= frame.rgb.min() and frame.rgb.max() <= 1.0
    assert frame.depth_m.shape == (480, 640) and frame.depth_m.dtype == torch.float32
    quarter = _open(real.parent, downscale=4)
    assert (quarter.width, quarter.height) == (160, 120) and quarter[0].depth_m.shape == (120, 160)
    np.testing.assert_allclose(quarter.K.numpy(), [[146.25, 0, 79.625], [0, 146.25, 59.625], [0, 0, 1]])
    bgr = cv2.imread(str(real / "frame-000000.color.jpg"))
    np.testing.assert_allclose(frame.rgb[7, 9].numpy(), bgr[7, 9, ::-1] / 255.0, atol=1e-6)  # BGR file -> RGB


def test_depth_is_metres_from_millimetres(full, real):
    raw = cv2.imread(str(real / "frame-000500.depth.png"), cv2.IMREAD_UNCHANGED)
    depth = full[500].depth_m.numpy()
    valid = (raw > 0) & (raw != 65535)
    np.testing.assert_allclose(depth[valid], raw[valid] / 1000.0, rtol=1e-6)
    assert (depth[~valid] == 0).all()
    assert 0.3 < np.median(depth[valid]) < 4.0  # an indoor Kinect v1 scene, in metres


def test_pose_round_trip(full, real):
    """The loader's pose is the file's 4x4 (within its ~1e-4 non-orthogonality), snapped to a rotation."""
    gt = full.gt_poses.numpy()
    assert gt.shape == (1000, 4, 4) and gt.dtype == np.float64
    for i in (0, 1, 333, 999):
        file_pose = np.loadtxt(real / f"frame-{i:06d}.pose.txt")
        np.testing.assert_allclose(gt[i], file_pose, atol=1e-3)
        np.testing.assert_allclose(gt[i][:3, 3], file_pose[:3, 3], atol=1e-12)  # translation untouched, metres
        np.testing.assert_array_equal(full[i].gt_c2w.numpy(), gt[i])
    R = gt[:, :3, :3]
    np.testing.assert_allclose(np.einsum("nji,njk->nik", R, R), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
    path = np.linalg.norm(np.diff(gt[:, :3, 3], axis=0), axis=1).sum()
    assert 7.0 < path < 8.0  # ../shared/data/README.md's 7.4 m


def test_invalid_depth_is_zero_at_every_scale(copy):
    depth_png = _own(copy / "seq" / "frame-000001.depth.png")
    raw = cv2.imread(str(depth_png), cv2.IMREAD_UNCHANGED)
    raw[:8, :8] = 65535  # no reading (the release's marker)
    raw[:8, 8:16] = 0  # no reading
    raw[:8, 16:24] = 11000  # 11 m: beyond max_depth_m
    raw[8:16, :24] = 1500
    cv2.imwrite(str(depth_png), raw)
    full = _open(copy, downscale=1)[1].depth_m
    assert (full[:8, :24] == 0).all() and torch.allclose(full[8:16, :24], torch.tensor(1.5))
    eighth = _open(copy, downscale=8)[1].depth_m  # one 8x8 block per marker
    assert eighth[0, :3].tolist() == [0.0, 0.0, 0.0]
    assert _open(copy, downscale=1, max_depth_m=None)[1].depth_m[0, 16].item() == pytest.approx(11.0)


def test_frame_selection_and_names(copy):
    picked = _open(copy, first=1, last=5, stride=2, downscale=1)
    assert len(picked) == 3
    np.testing.assert_allclose(picked.timestamps_s, [1 / 30, 3 / 30, 5 / 30])
    assert [p.name for p in picked.depth_paths] == [f"frame-00000{n}.depth.png" for n in (1, 3, 5)]
    (copy / "seq").rename(copy / "seq-01")  # the official layout's name, reached by its number
    for given in ("seq-01", "01", "1"):
        assert _open(copy, given).name == "sevenscenes/seq-01"
        assert canonical_seq("sevenscenes", given) == "seq-01"
    assert canonical_seq("sevenscenes", "seq") == "seq"


def test_png_colour_and_default_intrinsics(copy, real):
    """The official release's .color.png reads like the JPEG copy; without camera-intrinsics.txt, 585/320/240."""
    seq = copy / "seq"
    for n in range(N_COPY):
        jpg = seq / f"frame-{n:06d}.color.jpg"
        cv2.imwrite(str(seq / f"frame-{n:06d}.color.png"), cv2.imread(str(jpg)))
        jpg.unlink()
    (seq / "camera-intrinsics.txt").unlink()
    opened = _open(copy, downscale=2)
    assert opened.rgb_paths[0].name == "frame-000000.color.png"
    np.testing.assert_allclose(opened.K.numpy(), [[292.5, 0, 159.75], [0, 292.5, 119.75], [0, 0, 1]])
    jpg_seq = _open(real.parent, downscale=2)
    torch.testing.assert_close(opened[2].rgb, jpg_seq[2].rgb)
    (copy / "camera-intrinsics.txt").write_text("500 0 300\n0 510 250\n0 0 1\n")  # a root-level file counts too
    np.testing.assert_allclose(_open(copy, downscale=1).K.numpy(), [[500, 0, 300], [0, 510, 250], [0, 0, 1]])


# --------------------------------------------------------------------------- bad input: one line each
def _no_depth(seq: Path) -> None:
    (seq / "frame-000003.depth.png").unlink()


def _no_pose(seq: Path) -> None:
    (seq / "frame-000004.pose.txt").unlink()


def _no_colour(seq: Path) -> None:
    (seq / "frame-000002.color.jpg").unlink()


def _scaled_pose(seq: Path) -> None:
    pose = np.loadtxt(seq / "frame-000002.pose.txt")
    pose[:3, :3] *= 1.1  # a similarity, not a rigid transform
    np.savetxt(seq / "frame-000002.pose.txt", pose)


def _text_pose(seq: Path) -> None:
    (seq / "frame-000002.pose.txt").write_text("1 0 0 0\n0 1 0 0\n0 0 1 0\n")


def _resize(path: Path, size: tuple[int, int]) -> None:
    img = cv2.imread(str(_own(path)), cv2.IMREAD_UNCHANGED)
    cv2.imwrite(str(path), cv2.resize(img, size, interpolation=cv2.INTER_NEAREST))


def _depth_size(seq: Path) -> None:
    _resize(seq / "frame-000000.depth.png", (320, 240))


def _later_colour_size(seq: Path) -> None:
    _resize(seq / "frame-000003.color.jpg", (320, 240))


def _later_depth_size(seq: Path) -> None:
    _resize(seq / "frame-000005.depth.png", (640, 240))


def _empty(seq: Path) -> None:
    for path in seq.iterdir():
        path.unlink()


BAD = {
    # name: (breakage of the sequence folder, parts of the error line)
    "missing-depth": (
        _no_depth,
        [
            "frame 000003",
            "expected frame-000003.depth.png beside",
            "frame-000003.color.jpg, frame-000003.pose.txt, found none",
        ],
    ),
    "missing-pose": (_no_pose, ["frame 000004", "expected frame-000004.pose.txt beside", "found none"]),
    "missing-colour": (_no_colour, ["expected frame-000002.color.png or .color.jpg beside", "found none"]),
    "non-rigid-pose": (_scaled_pose, ["frame-000002.pose.txt: expected a rigid transform", "det R = 1.33"]),
    "pose-not-4x4": (_text_pose, ["frame-000002.pose.txt: expected 16 numbers (a 4x4 matrix), found 12"]),
    "depth-vs-colour-size": (_depth_size, ["depth image", "frame-000000.depth.png: expected 640x480", "found 320x240"]),
    "later-colour-size": (
        _later_colour_size,
        ["colour image", "frame-000003.color.jpg: expected 640x480 (the first frame's colour image), found 320x240"],
    ),
    "later-depth-size": (_later_depth_size, ["frame-000005.depth.png: expected 640x480", "found 640x240"]),
    "no-frames": (
        _empty,
        ["expected frame-NNNNNN.color.png (or .jpg), .depth.png and .pose.txt files", "found (empty)"],
    ),
}


@pytest.mark.parametrize("name", sorted(BAD))
def test_bad_input_is_one_line_at_open(name, copy):
    breakage, parts = BAD[name]
    _open(copy)  # intact: opens
    breakage(copy / "seq")
    with pytest.raises(DatasetError) as exc:
        _open(copy)
    _one_line(exc, *parts)


def test_missing_root_and_sequence(copy, tmp_path):
    with pytest.raises(DatasetError) as exc:
        _open(tmp_path / "nowhere")
    _one_line(exc, "sevenscenes root not found", str(tmp_path / "nowhere"), "see datasets/sevenscenes/README.md")
    with pytest.raises(DatasetError) as exc:
        _open(copy, "seq-02")
    _one_line(exc, "sevenscenes sequence 'seq-02' not found", f"expected a folder {copy.resolve()}/seq-02", "has: seq;")
    with pytest.raises(DatasetError) as exc:
        _open(copy, "3")
    _one_line(exc, "sequence '3' not found", "seq-03")


def test_bad_intrinsics_file(copy):
    (copy / "seq" / "camera-intrinsics.txt").write_text("585 0 320\n0 585 240\n")
    with pytest.raises(DatasetError) as exc:
        _open(copy)
    _one_line(exc, "camera-intrinsics.txt: expected a 3x3 matrix (9 finite numbers)")


def test_bad_input_through_the_cli(copy, tmp_path):
    """What a user sees: exit 2, one ``error:`` line, no traceback, a failed record, no SLAM work."""
    from tests.test_bad_input import run_cli

    _no_pose(copy / "seq")
    run_dir = tmp_path / "run"
    res = run_cli(["dataset=sevenscenes", f"dataset.root={copy}", "seq=seq", f"hydra.run.dir={run_dir}"])
    assert res.code == 2, res.stderr
    assert "expected frame-000004.pose.txt beside" in res.error_line
    record = json.loads((run_dir / "metrics.json").read_text())
    assert record["status"] == "failed" and not (run_dir / "keyframes.csv").exists()


# --------------------------------------------------------------------------- end to end
@pytest.mark.slow
def test_a_short_run_through_the_cli(copy, tmp_path):
    """Five real frames at 80x60 with +experiment=tiny's iteration counts end ok with every metric."""
    from tests.test_bad_input import run_cli

    run_dir = tmp_path / "run"
    res = run_cli(
        [
            "dataset=sevenscenes",
            f"dataset.root={copy}",
            "seq=seq",
            "dataset.downscale=8",
            "max_frames=5",
            "slam.tracking_iters=15",
            "slam.mapping_iters=30",
            "slam.refine_iters=30",
            "eval.every=2",
            "eval.lpips=false",
            "progress=false",
            "threads=1",
            f"hydra.run.dir={run_dir}",
        ]
    )
    assert res.code == 0, res.stderr
    record = json.loads((run_dir / "metrics.json").read_text())
    assert record["status"] == "ok", record.get("error")
    assert record["run"]["dataset"] == "sevenscenes" and record["run"]["seq"] == "seq"
    m = record["metrics"]
    assert m["num_frames"] == 5 and m["ate_num_poses"] == 5
    assert m["ate_rmse_m"] < 0.05, m  # 5 frames (0.17 s) of a hand-held camera
    assert m["psnr_db"] > 12, m
    assert any("images (" in k for k in record["run"]["inputs"])  # the frames are fingerprinted
