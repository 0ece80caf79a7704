"""ATE/RPE through evo: a published outside figure, known-answer cases, TUM I/O and errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from evo.core import lie_algebra
from evo.core.transformations import quaternion_from_matrix, quaternion_matrix

from bench.errors import MetricError
from bench.metrics.trajectory import Trajectory, aligned_positions, ate, drift_components, read_tum, rpe, write_tum


def _helix(n: int = 60, seed: int = 0) -> Trajectory:
    """A non-degenerate 3D path with varying orientation, 30 Hz."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / 30.0
    pos = np.stack([np.cos(t * 2), np.sin(t * 2), 0.3 * t], axis=1) + 0.01 * rng.standard_normal((n, 3))
    quats = []
    for i in range(n):
        r = lie_algebra.so3_exp(np.array([0.1 * i / n, 0.5 * t[i], 0.05]))
        m = np.eye(4)
        m[:3, :3] = r
        quats.append(quaternion_from_matrix(m))
    return Trajectory(1000.0 + t, pos, np.array(quats))


def _transform(traj: Trajectory, t_world: np.ndarray, scale: float = 1.0) -> Trajectory:
    """Apply x -> T * (s * x) to every pose (a change of world frame, plus a scale)."""
    out_pos, out_q = [], []
    for p, q in zip(traj.positions_m, traj.quat_wxyz, strict=True):
        pose = quaternion_matrix(q)
        pose[:3, 3] = scale * p
        new = t_world @ pose
        out_pos.append(new[:3, 3])
        out_q.append(quaternion_from_matrix(new))
    return Trajectory(traj.timestamps_s.copy(), np.array(out_pos), np.array(out_q))


def test_peer_fr2_desk_matches_published_evo_figure(shared: Path) -> None:
    peer = shared / "data" / "peer" / "tum_fr2_desk"
    gt = read_tum(peer / "fr2_desk_groundtruth.txt", allow_duplicates=True)  # the published file repeats one stamp
    est = read_tum(peer / "fr2_desk_ORB.txt")
    res = ate(est, gt, align="se3", max_diff_s=0.01)
    assert res["ate_num_poses"] == 2174
    assert res["ate_rmse_m"] == pytest.approx(0.008119, abs=1e-5)
    assert res["ate_alignment"] == "se3" and res["ate_max_diff_s"] == 0.01
    assert res["ate_mean_m"] <= res["ate_rmse_m"] <= res["ate_max_m"]


def test_rigid_transform_gives_zero_ate_with_se3() -> None:
    gt = _helix()
    t_world = lie_algebra.se3(lie_algebra.so3_exp(np.array([0.3, -0.2, 1.1])), np.array([2.0, -1.0, 0.5]))
    est = _transform(gt, t_world)
    assert ate(est, gt, align="se3")["ate_rmse_m"] < 1e-9
    assert ate(est, gt, align="none")["ate_rmse_m"] > 0.5  # unaligned, the offset shows
    r = rpe(est, gt)
    assert r["rpe_trans_rmse_m"] < 1e-9 and r["rpe_rot_rmse_deg"] < 1e-6


def test_scaled_trajectory_needs_sim3() -> None:
    gt = _helix()
    t_world = lie_algebra.se3(lie_algebra.so3_exp(np.array([0.0, 0.4, 0.2])), np.array([0.1, 0.2, 0.3]))
    est = _transform(gt, t_world, scale=0.5)
    assert ate(est, gt, align="se3")["ate_rmse_m"] > 0.05
    res = ate(est, gt, align="sim3")
    assert res["ate_rmse_m"] < 1e-9 and res["ate_alignment"] == "sim3"


def test_known_offset_error() -> None:
    """A constant 3 cm offset on alternate poses along one axis: the unaligned RMSE is exact."""
    gt = _helix(40)
    pos = gt.positions_m.copy()
    pos[::2, 0] += 0.03
    res = ate(Trajectory(gt.timestamps_s, pos, gt.quat_wxyz), gt, align="none")
    assert res["ate_rmse_m"] == pytest.approx(0.03 / np.sqrt(2), rel=1e-12)
    assert res["ate_max_m"] == pytest.approx(0.03, rel=1e-12)
    assert res["ate_num_poses"] == 40


def test_association_respects_max_diff() -> None:
    gt = _helix(40)
    shifted = Trajectory(gt.timestamps_s + 0.005, gt.positions_m, gt.quat_wxyz)
    assert ate(shifted, gt, max_diff_s=0.01)["ate_num_poses"] == 40
    with pytest.raises(MetricError, match=r"too few associated poses: expected at least 3, found 0 .*0\.001"):
        ate(shifted, gt, max_diff_s=0.001)
    two = Trajectory(gt.timestamps_s[:2], gt.positions_m[:2], gt.quat_wxyz[:2])
    with pytest.raises(MetricError, match="found 2"):
        ate(two, gt)


def test_bad_alignment_name() -> None:
    gt = _helix(10)
    with pytest.raises(MetricError, match="unknown alignment"):
        ate(gt, gt, align="umeyama")


def test_tum_round_trip(tmp_path: Path) -> None:
    traj = _helix(25)
    write_tum(tmp_path / "t.txt", traj)
    back = read_tum(tmp_path / "t.txt")
    np.testing.assert_allclose(back.timestamps_s, traj.timestamps_s, atol=1e-9)
    np.testing.assert_array_equal(back.positions_m, traj.positions_m)
    np.testing.assert_array_equal(back.quat_wxyz, traj.quat_wxyz)


def test_tum_file_order_is_xyzw(tmp_path: Path) -> None:
    (tmp_path / "t.txt").write_text("# c\n\n1.0 1 2 3 0.1 0.2 0.3 0.9\n")
    traj = read_tum(tmp_path / "t.txt")
    np.testing.assert_array_equal(traj.quat_wxyz[0], [0.9, 0.1, 0.2, 0.3])
    np.testing.assert_array_equal(traj.positions_m[0], [1, 2, 3])


@pytest.mark.parametrize(
    ("line", "pattern"),
    [
        ("2.0 1 2 3 0 0 0", "t.txt:3: expected 8 fields .* found 7"),
        ("2.0 1 2 x 0 0 0 1", "t.txt:3: expected 8 numbers"),
        ("2.0 1 nan 3 0 0 0 1", "t.txt:3: expected finite numbers"),
        ("2.0 1 2 3 0 0 0 inf", "t.txt:3: expected finite numbers"),
        ("2.0 1 2 3 0 0 0 0", "t.txt:3: expected a unit quaternion"),
    ],
)
def test_malformed_tum_lines(tmp_path: Path, line: str, pattern: str) -> None:
    (tmp_path / "t.txt").write_text(f"# header\n1.0 0 0 0 0 0 0 1\n{line}\n")
    with pytest.raises(MetricError, match=pattern) as err:
        read_tum(tmp_path / "t.txt")
    assert "\n" not in str(err.value) and str(err.value) == str(err.value).lower()


def test_missing_and_empty_files(tmp_path: Path) -> None:
    with pytest.raises(MetricError, match="cannot read trajectory"):
        read_tum(tmp_path / "nope.txt")
    (tmp_path / "e.txt").write_text("# only a comment\n")
    with pytest.raises(MetricError, match="found none"):
        read_tum(tmp_path / "e.txt")


def test_trajectory_validates_shapes_and_finiteness() -> None:
    with pytest.raises(MetricError, match="shapes disagree"):
        Trajectory(np.zeros(3), np.zeros((2, 3)), np.zeros((3, 4)))
    pos = np.zeros((3, 3))
    pos[1, 2] = np.nan
    with pytest.raises(MetricError, match="non-finite value at pose 1"):
        Trajectory(np.arange(3.0), pos, np.tile([1.0, 0, 0, 0], (3, 1)))


def test_from_c2w_matches_quaternions() -> None:
    traj = _helix(5)
    mats = np.stack([quaternion_matrix(q) for q in traj.quat_wxyz])  # [N, 4, 4]
    mats[:, :3, 3] = traj.positions_m
    back = Trajectory.from_c2w(traj.timestamps_s, mats)
    assert ate(back, traj, align="none")["ate_rmse_m"] < 1e-12
    dots = np.abs(np.sum(back.quat_wxyz * traj.quat_wxyz, axis=1))
    np.testing.assert_allclose(dots, 1.0, atol=1e-12)


def _rot(axis: np.ndarray, angle: float) -> np.ndarray:
    axis = axis / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


@pytest.mark.parametrize("align", ["se3", "sim3"])
def test_every_estimated_position_is_aligned_onto_ground_truth(align):
    t = np.arange(25) * 0.1
    gt_xyz = np.column_stack([t, np.sin(t), 0.3 * t**2])  # [25, 3]
    quat = np.tile([1.0, 0.0, 0.0, 0.0], (25, 1))
    gt = Trajectory(t, gt_xyz, quat)
    scale = 2.0 if align == "sim3" else 1.0
    est_xyz = scale * gt_xyz[::2] @ _rot(np.array([0.0, 1.0, 0.0]), 1.0).T + 3.0  # fewer poses than the ground truth
    est = Trajectory(t[::2] + 0.005, est_xyz, quat[::2])  # stamps within the association window
    np.testing.assert_allclose(aligned_positions(est, gt, align), gt_xyz[::2], atol=1e-9)
    np.testing.assert_allclose(aligned_positions(est, gt, "none"), est_xyz)


@pytest.mark.parametrize(
    ("rows", "line", "says"),
    [
        (["1.0", "2.0", "2.0"], 4, "found 2.000000000 again (duplicate of line 3)"),
        (["1.0", "3.0", "2.0"], 4, "found 2.000000000 after 3.000000000 (line 3)"),
    ],
)
def test_read_tum_rejects_duplicate_and_unsorted_stamps(tmp_path, rows, line, says) -> None:
    path = tmp_path / "t.txt"
    path.write_text("# t x y z qx qy qz qw\n" + "".join(f"{t} 0 0 0 0 0 0 1\n" for t in rows))
    with pytest.raises(MetricError) as exc:
        read_tum(path)
    assert str(exc.value) == f"{path}:{line}: expected strictly increasing timestamps, {says}"
    if "again" in says:
        assert len(read_tum(path, allow_duplicates=True)) == 3
    else:
        with pytest.raises(MetricError):
            read_tum(path, allow_duplicates=True)


def test_appended_trajectory_matches_write_tum(tmp_path) -> None:
    from bench.metrics.trajectory import TumAppender

    traj = _helix()
    c2w = np.tile(np.eye(4), (len(traj), 1, 1))
    c2w[:, :3, 3] = traj.positions_m
    full = Trajectory.from_c2w(traj.timestamps_s, c2w)
    write_tum(tmp_path / "a.txt", full)
    with TumAppender(tmp_path / "b.txt") as app:
        for t, m in zip(traj.timestamps_s, c2w, strict=True):
            app.append(t, m)
    assert (tmp_path / "a.txt").read_text() == (tmp_path / "b.txt").read_text()


def test_drift_components_split_a_climb_from_an_in_plane_slip() -> None:
    """A flat drive (a quarter circle in x-z, y vertical) whose estimate climbs 2 cm a frame and slips
    a fixed 0.3 m sideways in the plane: the SE(3)-aligned ATE tilts much of the climb away, the split
    does not."""
    n = 50
    a = np.linspace(0.0, np.pi / 2, n)
    gt_pos = np.stack([20 * np.sin(a), np.zeros(n), 20 * (1 - np.cos(a))], axis=1)  # [N, 3]
    est_pos = gt_pos + np.stack([np.full(n, 0.3), 0.02 * np.arange(n), np.zeros(n)], axis=1)
    q = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))
    t = np.arange(n) / 10.0
    gt, est = Trajectory(t, gt_pos, q), Trajectory(t, est_pos, q)
    got = drift_components(est, gt)
    np.testing.assert_allclose(got["off_plane_err_m"], 0.02 * np.arange(n), atol=1e-9)
    np.testing.assert_allclose(got["in_plane_err_m"], 0.3, atol=1e-9)
    np.testing.assert_allclose(got["path_length_m"][-1], 20 * np.pi / 2, rtol=1e-3)
    assert got["path_length_m"][0] == 0.0
    assert ate(est, gt)["ate_rmse_m"] < 0.5 * float(np.sqrt(np.mean(got["off_plane_err_m"] ** 2 + 0.09)))
